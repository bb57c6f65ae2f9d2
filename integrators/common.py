"""Small variant-agnostic helpers shared by the integrators.

In JIT variants (``llvm_*``, ``cuda_*``) masks protect virtual calls on pointer arrays; in
scalar variants a miss gives ``None`` pointers (and ``si.bsdf()`` on a miss crashes), so the
helpers below guard those cases once, here, instead of in every integrator.
"""
from __future__ import annotations

import functools
import weakref

import drjit as dr
import mitsuba as mi
import numpy as np


def is_jit() -> bool:
    return dr.is_jit_v(mi.Float)


def host_view(x) -> np.ndarray:
    """The array ``x`` as numpy sees it, without a copy where it can (a Dr.Jit array on the LLVM
    backend: a read-only view of its memory, which it keeps alive).  Through DLPack: ``np.array``
    of a Dr.Jit array (Dr.Jit 1.5) leaves the thread's upper AVX register state dirty, and until
    some AVX code clears it every legacy-SSE instruction after it pays for it (measured: numpy's
    ``sum(axis=0)`` over a 4096 x 4 array 0.07 ms clean, 0.7-1.0 ms after a conversion; this
    alone took EARS's learning between passes from 3.1 to 2.4 ms on Veach's MIS scene and from
    4.9 to 2.9 ms in the indirect room, 96 px); the DLPack export does not."""
    if dr.is_jit_v(x) and dr.backend_v(x) == dr.JitBackend.LLVM:
        dr.eval(x)
        return np.from_dlpack(x)
    return np.asarray(x)


def host(x, dtype=np.float64) -> np.ndarray:
    """A numpy copy of the array ``x`` as ``dtype`` (what the learners read back between
    passes; see :func:`host_view`)."""
    return np.array(host_view(x), dtype=dtype)


def record_once(fn):
    """Decorator for a function that records a symbolic loop whose body holds virtual calls
    over the scene's emitters, shapes or BSDFs.  Dr.Jit's loop optimisation
    (``JitFlag.OptimizeLoops``) records such a loop twice whenever a state variable comes out
    of the body unchanged or as the same literal constant (it records, drops those variables,
    records again), and each recording traces every virtual call over every instance: at
    thousands of emitting shapes that tracing costs seconds per render call, more than the
    kernel.  Without the optimisation (for the duration of the call, nested loops included)
    Dr.Jit keeps such variables in the loop state (a few registers; the compiler folds the
    constants anyway) and records once, provided each loop-invariant state variable is as
    wide as the loop (:func:`widen`, or leave it out with ``dr.hint(..., exclude=[...])``): a
    narrower one is dropped, and the loop recorded again, whatever the flag."""
    @functools.wraps(fn)
    def recorded_once(*args, **kwargs):
        with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
            return fn(*args, **kwargs)
    return recorded_once


def widen(x, like):
    """``x`` as wide as ``like`` (a loop-invariant loop state variable, see
    :func:`record_once`)."""
    if not is_jit():
        return x
    if dr.is_mask_v(x):
        return x | dr.zeros(type(x), dr.width(like))
    return x + dr.zeros(type(x), dr.width(like))


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


def emitter_table(scene):
    """``scene``'s table from a shape's registry id to its area emitter's registry id (0:
    none); at 0 (no shape: a miss) the environment emitter's.  Built once per scene by
    :meth:`IntegratorTemplate.prepare <integrators.plugins.base.IntegratorTemplate.prepare>`
    and bound for the render with :func:`bind_emitters`."""
    def rid(ptr):
        return int(dr.reinterpret_array(mi.UInt32, ptr)[0])
    ids = [(rid(mi.ShapePtr(sh)), sh.emitter()) for sh in scene.shapes()]
    table = [0] * (max((i for i, _ in ids), default=0) + 1)
    for i, em in ids:
        if em is not None:
            table[i] = rid(mi.EmitterPtr(em))
    if scene.environment() is not None:
        table[0] = rid(mi.EmitterPtr(scene.environment()))
    return mi.UInt32(table)


#: (the integrator that bound a table, the id of the scene it bound it for, its
#: :func:`emitter_table`), replaced as one tuple.  The integrator is held weakly and the
#: scene not at all: a scene kept alive after its last use puts its shapes and emitters into
#: every later kernel's virtual calls (two alike constant environments made the LLVM module
#: invalid: "invalid redefinition of function").  While the integrator lives it holds its
#: scene (``_prepared``), so the identity check in :func:`emitter_at` is exact; a binding
#: whose integrator is gone, or that another thread replaced with another scene's, is not used
#: (the virtual call instead).
_BOUND = (None, None, None)
#: each integrator's table, kept outside the integrator: an array attribute of ``self`` becomes
#: state of every symbolic loop whose body reads ``self``, and one narrower than the loop makes
#: Dr.Jit record that loop twice (:func:`record_once`)
_TABLES = weakref.WeakKeyDictionary()


def bind_emitters(integrator, scene, table=None):
    """Bind ``scene``'s :func:`emitter_table` for ``integrator``'s render: ``table`` when
    given (a new scene), else the one bound last by this integrator."""
    global _BOUND
    if table is None:
        table = _TABLES[integrator]
    else:
        _TABLES[integrator] = table
    _BOUND = (weakref.ref(integrator), id(scene), table)


def _bound_table(scene):
    ref, bound_id, table = _BOUND
    if ref is None or bound_id != id(scene):
        return None
    integ = ref()
    if integ is None or getattr(integ, "_prepared", None) is not scene:
        return None
    return table


def emitter_at(scene, si, active=True):
    """The emitter of ``si`` (``si.emitter(scene)``: the shape's area emitter, the
    environment on a miss).  During our integrators' renders (JIT variants) it is read from
    the scene's :func:`emitter_table` by the shape's registry id instead of a virtual call
    on the shapes: each trace of a virtual call traces every shape instance, which on a
    scene of thousands of emitting shapes costs more per render call than the kernel."""
    table = _bound_table(scene) if is_jit() else None
    if table is None:
        return si.emitter(scene)
    sid = dr.select(si.is_valid(), dr.reinterpret_array(mi.UInt32, si.shape), 0)
    # (a shape outside the table, e.g. inside an instanced group, has no emitter)
    idx = dr.gather(mi.UInt32, table, sid, active & (sid < dr.width(table)))
    return dr.reinterpret_array(mi.EmitterPtr, idx)


def direction_sample(scene, si, ref):
    """``mi.DirectionSample3f(scene, si, ref)`` (the direction from ``ref`` to the emitter
    surface or environment found at ``si``) with the emitter from :func:`emitter_at`, not
    from a virtual call on the shapes."""
    if not is_jit():
        return mi.DirectionSample3f(scene, si, ref)
    ds = dr.zeros(mi.DirectionSample3f, dr.width(si.p))
    ds.p, ds.n, ds.uv, ds.time = mi.Point3f(si.p), mi.Normal3f(si.sh_frame.n), \
        mi.Point2f(si.uv), mi.Float(si.time)
    rel = si.p - ref.p
    ds.dist = dr.norm(rel)
    ds.d = dr.select(si.is_valid(), rel / ds.dist, -si.wi)
    ds.emitter = emitter_at(scene, si)
    return ds


def emitted(scene, si, active):
    """Radiance emitted towards ``-ray.d`` at ``si`` (the environment on a miss)."""
    em = emitter_at(scene, si, active)
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

