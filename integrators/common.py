"""Small variant-agnostic helpers shared by the integrators.

In JIT variants (``llvm_*``, ``cuda_*``) masks protect virtual calls on pointer arrays; in
scalar variants a miss gives ``None`` pointers (and ``si.bsdf()`` on a miss crashes), so the
helpers below guard those cases once, here, instead of in every integrator.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


def is_jit() -> bool:
    return dr.is_jit_v(mi.Float)


def depth_limit(max_depth: int):
    """Mitsuba's convention: -1 means unlimited."""
    return mi.UInt32(0xFFFFFFFF if max_depth < 0 else max_depth)


def bsdf_at(si, ray, active):
    """BSDF pointer at ``si`` (None in scalar variants where there is no surface)."""
    if not is_jit() and not (active and si.is_valid()):
        return None
    return si.bsdf(ray)


def bsdf_flags(bsdf):
    if bsdf is None:
        return mi.UInt32(0)
    return bsdf.flags()


def any_flag(flags, mask):
    """True where ``flags`` has any of the bits of ``mask`` (a combination of BSDFFlags)."""
    return (flags & int(mask)) != 0


def emitted(scene, si, active):
    """Radiance emitted towards ``-ray.d`` at ``si`` (the environment on a miss)."""
    em = si.emitter(scene)
    if not is_jit() and (em is None or not active):
        return mi.Spectrum(0.0)
    return em.eval(si, active)


def lnot(mask):
    """Logical not that also works on the Python bools of scalar variants (~True == -2)."""
    return (not mask) if isinstance(mask, bool) else ~mask


def safe_div(a, b):
    """a / b where b != 0, else 0."""
    nz = b != 0
    return dr.select(nz, a / dr.select(nz, b, 1.0), 0.0)


def luminance(spec):
    """Luminance of a Spectrum (the mean over channels in spectral variants)."""
    s = mi.unpolarized_spectrum(spec)
    if mi.is_rgb:
        return mi.luminance(s)
    return dr.mean(s, axis=0)


def channel_mean(spec):
    """Mean over the spectral channels of a Spectrum (one Float per lane)."""
    s = mi.unpolarized_spectrum(spec)
    return dr.mean(s, axis=0)

