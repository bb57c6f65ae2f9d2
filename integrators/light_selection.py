r"""Light selection: a discrete pdf over the scene's emitters, shared by every integrator.

``uniform``  p(j) = 1 / number of emitters.
``power``    p(j) proportional to the emitted power Phi_j.

Power is measured with Mitsuba's own sampling routines over a fixed low-discrepancy point set:
area lights by uniform positions on their shape, every other emitter by ``sample_ray`` (the
weight of an emitted ray is Phi / pdf, so its mean is Phi).  This gives the closed forms of the
plugins Mitsuba ships, with no per-type code here:

* area light: pi * \int L_e dA by uniform points on its shape (a textured emitter: pi * area *
  mean radiance),
* point light: 4 pi I; spot light: I integrated over its cone, falloff included,
* infinite emitters (``constant``, ``envmap``, ``directional``): power through the scene's
  bounding sphere (pi * L * 4 pi r^2 for a constant environment, pi r^2 E for a directional).

Spectral power is averaged over the channels.  Emitters of zero power get probability zero (they
contribute nothing, so this stays unbiased); if every emitter has zero power, selection falls back
to uniform.  The selection probability enters both the estimator (division by p(j)) and the MIS
densities (``pdf_direction`` returns p(j) * p_j(omega)), so it can never bias the result.

Selection tables are per scene, built once and cached by the integrator (``for_scene``).  In JIT
variants an emitter pointer is mapped to its index through its registry id
(``dr.reinterpret_array(UInt32, ptr)``), so looking up p(j) for an emitter hit by a BSDF ray is a
single gather.
"""
from __future__ import annotations

import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from .common import channel_mean, is_jit
from .params import Param

MODES = ("uniform", "power")

PARAM = Param("light_selection", "choice", "power", choices=MODES,
              doc="Discrete pdf for choosing the light of a light sample.")

POWER_SAMPLES_JIT = 1 << 14
POWER_SAMPLES_SCALAR = 256


def _r2(n: int, dim: int, offset: int = 0) -> np.ndarray:
    """Points of the R_d low-discrepancy sequence in [0,1)^dim (deterministic)."""
    phi = 2.0
    for _ in range(30):
        phi = (1 + phi) ** (1.0 / (dim + 1))
    alpha = np.array([(1.0 / phi) ** (k + 1) for k in range(dim)])
    i = np.arange(offset + 1, offset + n + 1, dtype=np.float64)[:, None]
    return np.mod(0.5 + i * alpha[None, :], 1.0)


def _u(n: int, dim: int):
    """n low-discrepancy points in [0,1)^dim as a list of columns (JIT arrays or floats)."""
    u = np.minimum(_r2(n, dim).astype(np.float32), np.float32(1 - 2**-24))
    return [mi.Float(u[:, k]) for k in range(dim)] if is_jit() else u


def _mean(fn, n: int) -> float:
    """Mean of the per-sample Float values returned by ``fn(columns)``."""
    if is_jit():
        vals = np.array(fn(_u(n, 5)), dtype=np.float64).ravel()
    else:
        u = _u(n, 5)
        vals = np.array([float(fn([float(c) for c in row])) for row in u])
    vals = vals[np.isfinite(vals)]
    return float(np.mean(vals)) if vals.size else 0.0


def emitter_power(emitter, n: int | None = None) -> float:
    """Emitted power of one emitter, averaged over spectral channels."""
    n = n or (POWER_SAMPLES_JIT if is_jit() else POWER_SAMPLES_SCALAR)
    shape = emitter.get_shape()
    if shape is not None:
        # area light: Phi = pi * int L_e dA (Lambertian emission), by uniform points on the
        # shape; works for textured radiance too, which cannot always sample_ray
        def area_sample(u):
            ps = shape.sample_position(0.0, mi.Point2f(u[0], u[1]))
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.p, si.n, si.uv, si.time = ps.p, ps.n, ps.uv, ps.time
            si.sh_frame = mi.Frame3f(ps.n)
            si.wi = mi.Vector3f(0.0, 0.0, 1.0)
            if mi.is_spectral:
                si.wavelengths, _ = mi.sample_rgb_spectrum(mi.sample_shifted(u[2]))
            le = emitter.eval(si, True)
            inv = dr.select(ps.pdf > 0, dr.rcp(ps.pdf), 0.0)
            return channel_mean(le) * inv * dr.pi
        return _mean(area_sample, n)

    # other emitters: the weight of an emitted ray is Phi / pdf
    def ray_sample(u):
        _, w = emitter.sample_ray(0.0, u[0], mi.Point2f(u[1], u[2]), mi.Point2f(u[3], u[4]), True)
        return channel_mean(w)
    return _mean(ray_sample, n)


def selection_pmf(scene, mode: str) -> np.ndarray:
    """Normalised selection probabilities of ``scene.emitters()`` (numpy, float64)."""
    emitters = scene.emitters()
    n = len(emitters)
    if n == 0:
        return np.zeros(0)
    if mode == "uniform":
        return np.full(n, 1.0 / n)
    if mode != "power":
        raise ValueError(f"light_selection: unknown mode {mode!r}; allowed: {', '.join(MODES)}")
    power = np.array([max(emitter_power(e), 0.0) for e in emitters])
    total = power.sum()
    if not (total > 0 and math.isfinite(total)):
        return np.full(n, 1.0 / n)
    return power / total


class LightSelection:
    """Per-scene light selection: sampling an emitter and the pmf of a given emitter."""

    def __init__(self, scene, mode: str = "power"):
        self.scene, self.mode = scene, mode
        self.emitters = scene.emitters()
        self.count = len(self.emitters)
        self.pmf_np = selection_pmf(scene, mode)
        if self.count == 0:
            warnings.warn("scene has no emitters: light sampling is disabled and the image "
                          "will be black", RuntimeWarning, stacklevel=3)
            return
        self.distr = mi.DiscreteDistribution(self.pmf_np.astype(np.float32))
        if is_jit():
            self.emitters_dr = scene.emitters_dr()
            ids = np.array(dr.reinterpret_array(mi.UInt32, self.emitters_dr), dtype=np.int64)
            table = np.zeros(int(ids.max()) + 1, dtype=np.float32)
            table[ids] = self.pmf_np
            self.pmf_by_id = mi.Float(table)
        else:
            self.pmf_by_ptr = {e.ptr: float(p) for e, p in zip(self.emitters, self.pmf_np)}

    # ------------------------------------------------------------------------------------
    def pmf(self, emitter, active=True):
        """Selection probability of ``emitter`` (an EmitterPtr; 0 for null entries)."""
        if self.count == 0:
            return mi.Float(0.0)
        if is_jit():
            ids = dr.reinterpret_array(mi.UInt32, emitter)
            return dr.gather(mi.Float, self.pmf_by_id, ids, active)
        if emitter is None or not active:
            return 0.0
        return self.pmf_by_ptr.get(emitter.ptr, 0.0)

    def sample(self, sample1, active=True):
        """Pick an emitter: returns (EmitterPtr, selection probability)."""
        idx, pmf = self.distr.sample_pmf(sample1, active)
        if is_jit():
            return dr.gather(mi.EmitterPtr, self.emitters_dr, idx, active), pmf
        return self.emitters[int(idx)], pmf

    def sample_direction(self, si, sample1, sample2, active=True):
        """Light sample in solid-angle form, selection included.

        Returns (ds, weight) with ``ds.pdf = p(j) p_j(omega)`` (for a delta emitter
        ``ds.delta`` is set and ``ds.pdf`` is meaningless for MIS) and
        ``weight = L_e G / (p(j) p_j)`` as Mitsuba's ``Emitter.sample_direction`` defines it
        (no visibility test)."""
        if self.count == 0:
            return dr.zeros(mi.DirectionSample3f), mi.Spectrum(0.0)
        emitter, sel = self.sample(sample1, active)
        active = active & (sel > 0)
        if not is_jit() and not active:
            return dr.zeros(mi.DirectionSample3f), mi.Spectrum(0.0)
        ds, weight = emitter.sample_direction(si, sample2, active)
        ds.emitter = emitter
        ds.pdf = ds.pdf * sel
        weight = dr.select(active & (sel > 0), weight / dr.select(sel > 0, sel, 1.0), 0.0)
        return ds, weight

    def pdf_direction(self, si_from, si_hit, active=True):
        """Solid-angle density with which light sampling from ``si_from`` produces the
        direction to the emitter surface (or environment) found at ``si_hit``."""
        if self.count == 0:
            return mi.Float(0.0)
        emitter = si_hit.emitter(self.scene)
        if not is_jit() and (emitter is None or not active):
            return 0.0
        ds = mi.DirectionSample3f(self.scene, si_hit, si_from)
        sel = self.pmf(emitter, active)
        pdf = emitter.pdf_direction(si_from, ds, active & (sel > 0))
        return dr.select(active & (sel > 0), pdf * sel, 0.0)


class SelectionCache:
    """Keeps the LightSelection of the scene an integrator last rendered."""

    def __init__(self, mode: str):
        self.mode, self._scene, self._sel = mode, None, None

    def __call__(self, scene) -> LightSelection:
        if self._scene is not scene:
            self._sel = LightSelection(scene, self.mode)
            self._scene = scene
        return self._sel
