"""Mitsuba 3 integrators for the lecture "Sampling Strategies for Solving the Rendering Equation".

``import integrators`` makes Dr.Jit's LLVM backend usable (points ``DRJIT_LIBLLVM_PATH`` at an
LLVM >= 16 unless the user set it), selects a Mitsuba variant if none is active (``llvm_ad_rgb``,
or ``$INTEGRATORS_VARIANT``), and registers every plugin (see :mod:`integrators.registry`).
``set_variant(name)`` switches variant and registers again.
"""
from __future__ import annotations

import os as _os

from . import _llvm

LLVM_PATH = _llvm.configure()

import drjit as dr  # noqa: E402,F401  (imported after the LLVM configuration, on purpose)
import mitsuba as mi  # noqa: E402

DEFAULT_VARIANT = "llvm_ad_rgb"

from . import registry  # noqa: E402
from .params import ParameterError  # noqa: E402,F401


def set_variant(name: str) -> None:
    """Activate Mitsuba variant ``name`` and register our plugins for it."""
    if name.startswith("llvm_") and LLVM_PATH is None:
        raise RuntimeError(
            f"variant {name!r} needs libLLVM >= {_llvm.MIN_VERSION}, and none was found "
            "(Debian: apt-get install libllvm19; or set DRJIT_LIBLLVM_PATH to a libLLVM.so)")
    if name not in mi.variants():
        raise ValueError(f"unknown Mitsuba variant {name!r}; available: {', '.join(mi.variants())}")
    mi.set_variant(name)
    registry.register_all()


if mi.variant() is None:
    set_variant(_os.environ.get("INTEGRATORS_VARIANT", DEFAULT_VARIANT))
else:
    registry.register_all()

__all__ = ["set_variant", "DEFAULT_VARIANT", "LLVM_PATH", "ParameterError", "registry"]
