"""The public test kit (statistics, closed forms, test scenes)."""
from .stats import *  # noqa: F401,F403
from .stats import CHECKS, DEFAULT_ALPHA  # noqa: F401
