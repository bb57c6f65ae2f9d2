"""Mitsuba 3 integrators for the lecture "Sampling Strategies for Solving the Rendering Equation".

``import integrators`` makes Dr.Jit's LLVM backend usable (points ``DRJIT_LIBLLVM_PATH`` at an
LLVM >= 16 unless the user set it), selects a Mitsuba variant if none is active (``llvm_ad_rgb``,
or ``$INTEGRATORS_VARIANT``), and registers every plugin for the active variant and for every
variant activated later with ``mi.set_variant`` (Mitsuba's variant-change callback), in either
order of import and ``mi.set_variant``.  ``set_variant(name)`` is ``mi.set_variant`` with a
one-line error for a variant that cannot work here.

Layout (the lecture's concepts, one place each):

* :mod:`integrators.sampling` - MIS heuristics, light selection, Russian roulette and splitting,
  and the per-vertex estimator every integrator calls;
* :mod:`integrators.plugins` - one module per integrator or BSDF (``phong``, ``bsdf_path``,
  ``direct_mis``, ``nee_path``, ``mis3``);
* :mod:`integrators.app` - the command line, progressive rendering, image files, the run record;
* :mod:`integrators.testing` - the public test kit (statistics, closed forms, test scenes,
  ``assert_unbiased``, a pytest plugin).
"""
from __future__ import annotations

import os as _os

from .app import interrupt as _interrupt

_interrupt.early()   # python -m integrators: SIGINT/SIGTERM are one line from here on, not tracebacks

from . import _llvm  # noqa: E402

LLVM_PATH = _llvm.configure()

import drjit as dr  # noqa: E402,F401  (imported after the LLVM configuration, on purpose)
import mitsuba as mi  # noqa: E402

DEFAULT_VARIANT = "llvm_ad_rgb"

from . import registry  # noqa: E402
from .params import ParameterError  # noqa: E402,F401


def check_variant(name: str) -> None:
    """Raise ValueError (one line) if Mitsuba variant ``name`` cannot run here."""
    if name not in mi.variants():
        raise ValueError(f"variant {name!r} is not available; allowed: {', '.join(mi.variants())}")
    if name.startswith("llvm_") and LLVM_PATH is None:
        raise ValueError(
            f"variant {name!r} needs libLLVM >= {_llvm.MIN_VERSION}, and none was found "
            "(Debian: apt-get install libllvm19; or set DRJIT_LIBLLVM_PATH to a libLLVM.so)")


def set_variant(name: str) -> None:
    """Activate Mitsuba variant ``name`` (our plugins are registered by the variant callback)."""
    check_variant(name)
    mi.set_variant(name)
    _interrupt.prime_mitsuba()    # command line: Mitsuba's Ctrl-C start-up race closed


if mi.variant() is None:
    set_variant(_os.environ.get("INTEGRATORS_VARIANT", DEFAULT_VARIANT))

from . import plugins  # noqa: E402,F401  (declares every plugin with the registry)

_interrupt.prime_mitsuba()   # (idempotent: the variant may have been set before the import)
_interrupt.release()   # command line: SIGINT was held through the imports and priming

registry.install()

__all__ = ["set_variant", "check_variant", "DEFAULT_VARIANT", "LLVM_PATH", "ParameterError",
           "registry"]
