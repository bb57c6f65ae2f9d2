"""The plugins, one module each: importing this package declares them with the registry."""
from . import phong, bsdf_path, direct_mis, nee_path, mis3  # noqa: F401
from . import bdpt  # noqa: F401
from . import pssmlt  # noqa: F401

__all__ = ["phong", "bsdf_path", "direct_mis", "nee_path", "mis3"]
