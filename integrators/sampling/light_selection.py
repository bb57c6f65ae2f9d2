r"""Light selection: a discrete pdf over the scene's emitters, shared by every integrator.

``uniform``  p(j) = 1 / number of emitters.
``power``    p(j) proportional to the emitted power Phi_j.
``adaptive`` p(j | x) proportional to a bound on light j's irradiance at the shading point x
             (:class:`AdaptiveLightSelection`), with 5 % of the power pmf mixed in.
``bvh``      a light tree (:mod:`.light_tree`): p(j | x) the product of the importance ratios on
             the way from the root to light j, O(log N) per shading point.
``ris``      resampled importance sampling (ReSTIR's first stage): ``light_candidates``
             (default 4) light samples, their lights from that tree, one kept in proportion
             to its unshadowed contribution f L_e (:class:`.light_tree.ResampledTreeSelection`).

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

The cumulative pmf that a choice inverts runs along a Morton curve of the lights
(:func:`spatial_order`), not in Mitsuba's emitter order, which changes between processes: the
same uniform picks the same light in every process, and the strata of several light samples
at a vertex are regions of space.

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

from ..common import channel_mean, direction_sample, is_jit, safe_div
from ..params import Param

MODES = ("uniform", "power", "adaptive", "bvh", "ris")

PARAM = Param("light_selection", "choice", "power", choices=MODES,
              doc="Discrete pdf for choosing the light of a light sample (adaptive: per "
                  "shading point, from power, distance and orientation, O(N); bvh: the same "
                  "kind of bound traversed in a light tree, O(log N); ris: light_candidates "
                  "light samples from that tree, one kept by its unshadowed contribution).")

#: candidates per light sample of light_selection=ris
CANDIDATES = 4
CANDIDATES_PARAM = Param("light_candidates", "int", CANDIDATES, min=1, max=64,
                         doc="light_selection=ris: lights drawn from the light tree per light "
                             "sample, one kept by resampling (1: the tree's own choice).")

ONE_MINUS_EPS = 1.0 - 2.0 ** -24
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


def _area_power_sample(emitter, shape, u):
    """One sample of an area light's power pi * int L_e dA (Lambertian emission) from a uniform
    point on its shape (``u``: at least 3 uniforms); works for textured radiance too, which
    cannot always ``sample_ray``.  ``emitter`` and ``shape`` may be pointer arrays."""
    ps = shape.sample_position(0.0, mi.Point2f(u[0], u[1]))
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.p, si.n, si.uv, si.time = ps.p, ps.n, ps.uv, ps.time
    si.sh_frame = mi.Frame3f(ps.n)
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    if mi.is_spectral:
        si.wavelengths, _ = mi.sample_rgb_spectrum(mi.sample_shifted(u[2]))
    le = emitter.eval(si, True)
    return channel_mean(le) * dr.select(ps.pdf > 0, dr.rcp(ps.pdf), 0.0) * dr.pi


def emitter_power(emitter, n: int | None = None) -> float:
    """Emitted power of one emitter, averaged over spectral channels."""
    n = n or (POWER_SAMPLES_JIT if is_jit() else POWER_SAMPLES_SCALAR)
    shape = emitter.get_shape()
    if shape is not None:
        # area light: Phi = pi * int L_e dA (Lambertian emission), by uniform points on the
        # shape; works for textured radiance too, which cannot always sample_ray
        return _mean(lambda u: _area_power_sample(emitter, shape, u), n)

    # other emitters: the weight of an emitted ray is Phi / pdf
    def ray_sample(u):
        _, w = emitter.sample_ray(0.0, u[0], mi.Point2f(u[1], u[2]), mi.Point2f(u[3], u[4]), True)
        return channel_mean(w)
    return _mean(ray_sample, n)


POWER_LANES = 1 << 20     # lanes of the one vectorised power kernel (samples x emitters)
POWER_SAMPLES_MIN = 64


def _finite_mean(vals: np.ndarray) -> np.ndarray:
    """Row means of (emitters, samples) over the finite entries (0 for none)."""
    ok = np.isfinite(vals)
    count = ok.sum(1)
    return np.where(count > 0, np.where(ok, vals, 0.0).sum(1) / np.maximum(count, 1), 0.0)


def emitter_powers(scene, emitters=None, normals: bool = False):
    """Powers of all ``scene.emitters()`` (numpy float64), as :func:`emitter_power` defines
    them.  In JIT variants one vectorised kernel per kind (area lights, other emitters) instead
    of one per emitter: every emitter gets the same K low-discrepancy points, K = 2^14 for few
    emitters and down to 64 for many (2^20 lanes in all; exact for constant radiance either
    way).  ``normals``: also return the surface normal of every area light at its first sample
    point ((N, 3), zeros for other emitters)."""
    emitters = scene.emitters() if emitters is None else emitters
    n = len(emitters)
    power = np.zeros(n)
    first_n = np.zeros((n, 3))
    if not is_jit() or n == 0:
        power[:] = [emitter_power(e) for e in emitters]
        if normals:
            for j, e in enumerate(emitters):
                shape = e.get_shape()
                if shape is not None:
                    u = _r2(1, 2)[0]
                    ps = shape.sample_position(0.0, mi.Point2f(float(u[0]), float(u[1])))
                    first_n[j] = np.array(ps.n, float).ravel()[:3]
        return (power, first_n) if normals else power
    ptrs = scene.emitters_dr()
    has_shape = np.array([e.get_shape() is not None for e in emitters])
    for area in (True, False):
        idx = np.nonzero(has_shape == area)[0]
        if not len(idx):
            continue
        k = int(min(POWER_SAMPLES_JIT, max(POWER_SAMPLES_MIN, POWER_LANES // len(idx))))
        u = np.minimum(_r2(k, 5).astype(np.float32), np.float32(1 - 2**-24))
        uu = [mi.Float(np.tile(u[:, c], len(idx))) for c in range(5)]
        em = dr.gather(mi.EmitterPtr, ptrs, mi.UInt32(np.repeat(idx, k).astype(np.uint32)))
        if area:
            val = _area_power_sample(em, em.get_shape(), uu)
        else:
            _, w = em.sample_ray(0.0, uu[0], mi.Point2f(uu[1], uu[2]), mi.Point2f(uu[3], uu[4]),
                                 True)
            val = channel_mean(w)
        power[idx] = _finite_mean(np.array(val, dtype=np.float64).reshape(len(idx), k))
        if normals and area:   # the normal at the first point of every shape
            sub = dr.gather(mi.EmitterPtr, ptrs, mi.UInt32(idx.astype(np.uint32))).get_shape()
            ps = sub.sample_position(0.0, mi.Point2f(float(u[0, 0]), float(u[0, 1])))
            first_n[idx] = np.array(ps.n, dtype=np.float64).reshape(3, -1).T
    return (power, first_n) if normals else power


def selection_pmf(scene, mode: str) -> np.ndarray:
    """Normalised selection probabilities of ``scene.emitters()`` (numpy, float64)."""
    emitters = scene.emitters()
    n = len(emitters)
    if n == 0:
        return np.zeros(0)
    if mode == "uniform":
        return np.full(n, 1.0 / n)
    if mode not in MODES or mode == "uniform":
        raise ValueError(f"light_selection: unknown mode {mode!r}; allowed: {', '.join(MODES)}")
    return power_pmf(emitter_powers(scene, emitters))


def power_pmf(power: np.ndarray) -> np.ndarray:
    """Normalised power (negative powers count as 0; uniform if no power at all)."""
    n = len(power)
    if n == 0:
        return np.zeros(0)
    power = np.maximum(np.nan_to_num(np.asarray(power, float), nan=0.0), 0.0)
    total = power.sum()
    if not (total > 0 and math.isfinite(total)):
        return np.full(n, 1.0 / n)
    return power / total


#: step of the R2 low-discrepancy sequence in 2-D: successive rotations of a light-point sample
R2_STEP = (0.7548776662466927, 0.5698402909980532)


def rotated(u, k, m):
    """Stratum k of m of a uniform: u + k/m modulo 1 (a Cranley-Patterson rotation: uniform for
    every k, the m together stratified); ``m`` may differ per lane."""
    uk = u + mi.Float(k) * (1.0 / m)
    return dr.minimum(dr.select(uk >= 1.0, uk - 1.0, uk), ONE_MINUS_EPS)


def rotated_2d(s, k):
    """Point k of a 2-D uniform: s + k times the R2 sequence's step, modulo 1 (uniform for every
    k, successive k spread over the square as the R2 sequence is)."""
    sk = mi.Point2f(s) + mi.Float(k) * mi.Vector2f(R2_STEP)
    return dr.minimum(sk - dr.floor(sk), ONE_MINUS_EPS)


def spatial_order(emitters, pmf: np.ndarray) -> np.ndarray:
    """The order of the cumulative pmf that a light choice inverts: emitters without a
    position (infinite ones) first, by probability, then the others along a Morton curve of
    their bounding boxes' centres (ties by probability).  Mitsuba's ``scene.emitters()`` order
    changes between processes (plugins are instantiated in parallel); a fixed spatial order
    makes the choice for a given uniform the same in every process, and the strata of
    several light samples (:meth:`LightSelection.stratum`) regions of space, which is where
    stratifying pays."""
    n = len(emitters)
    centres = np.zeros((n, 3))
    placed = np.zeros(n, bool)
    for j, e in enumerate(emitters):
        b = e.bbox()
        if b.valid():
            centres[j] = np.array(b.center(), dtype=np.float64).ravel()[:3]
            placed[j] = True
    code = np.zeros(n, np.int64)
    if placed.any():
        lo, hi = centres[placed].min(0), centres[placed].max(0)
        q = np.floor((centres - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).clip(0, 1023)
        q = q.astype(np.int64)
        for bit in range(10):
            for axis in range(3):
                code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.lexsort((-pmf, code, placed.astype(np.int64)))


def _no_direction_sample():
    """An empty direction sample (``dr.zeros`` cannot build one in scalar variants: its
    emitter pointer)."""
    return dr.zeros(mi.DirectionSample3f) if is_jit() else mi.DirectionSample3f()


class LightSelection:
    """Per-scene light selection: sampling an emitter and the pmf of a given emitter."""

    #: dimensions of the ``sample1`` that :meth:`choose` and :meth:`sample_direction` read (a
    #: Float for 1, a Point2f for 2: ``sample_1d`` draws it)
    SAMPLE_DIMS = 1

    def __init__(self, scene, mode: str = "power"):
        self.scene, self.mode = scene, mode
        self.emitters = scene.emitters()
        self.count = len(self.emitters)
        self.power = None if mode == "uniform" else self._measure_power(scene)
        self.pmf_np = (selection_pmf(scene, mode) if self.power is None
                       else power_pmf(self.power))
        if self.count == 0:
            warnings.warn("scene has no emitters: light sampling is disabled and the image "
                          "will be black", RuntimeWarning, stacklevel=3)
            return
        #: slot k of the cumulative pmf holds emitter order[k] (:func:`spatial_order`)
        self.order = spatial_order(self.emitters, self.pmf_np)
        self.distr = mi.DiscreteDistribution(self.pmf_np[self.order].astype(np.float32))
        if is_jit():
            self.order_dr = mi.UInt32(self.order.astype(np.uint32))
            dr.make_opaque(self.order_dr)
            self.emitters_dr = scene.emitters_dr()
            ids = np.array(dr.reinterpret_array(mi.UInt32, self.emitters_dr), dtype=np.int64)
            table = np.zeros(int(ids.max()) + 1, dtype=np.float32)
            table[ids] = self.pmf_np
            self.pmf_by_id = mi.Float(table)
        else:
            self.pmf_by_ptr = {e.ptr: float(p) for e, p in zip(self.emitters, self.pmf_np)}

    def _measure_power(self, scene):
        return emitter_powers(scene, self.emitters)

    # ------------------------------------------------------------------------------------
    def pmf(self, emitter, active=True):
        """Selection probability of ``emitter`` (an EmitterPtr; 0 for null entries)."""
        if self.count == 0:
            return mi.Float(0.0)
        if self.mode == "uniform":  # no table lookup: 1/n for every emitter
            if is_jit():
                return dr.select(active & (dr.reinterpret_array(mi.UInt32, emitter) != 0),
                                 1.0 / self.count, 0.0)
            return 1.0 / self.count if (emitter is not None and active) else 0.0
        if is_jit():
            ids = dr.reinterpret_array(mi.UInt32, emitter)
            return dr.gather(mi.Float, self.pmf_by_id, ids, active)
        if emitter is None or not active:
            return 0.0
        return self.pmf_by_ptr.get(emitter.ptr, 0.0)

    def _emitter(self, idx, active):
        if is_jit():
            return dr.gather(mi.EmitterPtr, self.emitters_dr, idx, active)
        return self.emitters[int(idx)]

    def _slot_emitter(self, slot, active=True):
        """Index of the emitter in slot ``slot`` of the cumulative pmf."""
        if is_jit():
            return dr.gather(mi.UInt32, self.order_dr, slot, active)
        return int(self.order[int(slot)])

    def sample_1d(self, sampler, active=True):
        """The ``sample1`` of a light choice from ``sampler`` (:attr:`SAMPLE_DIMS` numbers)."""
        return sampler.next_2d(active) if self.SAMPLE_DIMS == 2 else sampler.next_1d(active)

    def stratum(self, sample1, k, m):
        """The choice sample of light sample k of m at one vertex, from the first one's
        ``sample1``: rotated by k/m, so each is uniform (every light sample is distributed as
        one alone, which is all the multi-sample estimator needs to stay unbiased) and the m
        together are stratified over the selection's cumulative pmf."""
        return rotated(sample1, k, m)

    def choose(self, si, sample1, active=True):
        """Pick the emitter of a light sample at ``si``: (EmitterPtr, p(j | si), norm).

        ``norm`` is whatever :meth:`pmf_at` needs to evaluate p(. | si) again at the same point
        without redoing the work (the adaptive pmf's normaliser); None for a fixed pmf."""
        emitter, pmf = self.sample(sample1, active)
        return emitter, pmf, None

    def pmf_at(self, si, emitter, active=True, norm=None):
        """p(j | si) of ``emitter`` (the same for every point unless adaptive); ``norm``: the
        value :meth:`choose` returned at this ``si``, if any."""
        return self.pmf(emitter, active)

    def sample(self, sample1, active=True):
        """Pick an emitter: returns (EmitterPtr, selection probability)."""
        if self.mode == "uniform":  # direct index, no search
            slot = dr.minimum(mi.UInt32(sample1 * self.count), self.count - 1)
            pmf = mi.Float(1.0 / self.count)
        else:
            slot, pmf = self.distr.sample_pmf(sample1, active)
        return self._emitter(self._slot_emitter(slot, active), active), pmf

    def sample_direction(self, si, sample1, sample2, active=True, bsdf=None, ctx=None):
        """Light sample in solid-angle form, selection included.

        Returns (ds, weight, norm) with ``ds.pdf = p(j) p_j(omega)`` (for a delta emitter
        ``ds.delta`` is set and ``ds.pdf`` is meaningless for MIS),
        ``weight = L_e G / (p(j) p_j)`` as Mitsuba's ``Emitter.sample_direction`` defines it
        (no visibility test), and ``norm`` from :meth:`choose`, to pass to
        :meth:`pdf_direction` from the same ``si``.  ``bsdf`` and ``ctx``: the BSDF at ``si``
        (unused here; a resampling selection targets the unshadowed contribution with it)."""
        if self.count == 0:
            return _no_direction_sample(), mi.Spectrum(0.0), None
        emitter, sel, norm, divisor = self.weighted_choice(si, sample1, active)
        active = active & (sel > 0)
        if not is_jit() and not active:
            return _no_direction_sample(), mi.Spectrum(0.0), norm
        ds, weight = emitter.sample_direction(si, sample2, active)
        ds.emitter = emitter
        ds.pdf = ds.pdf * sel
        weight = dr.select(active, weight / dr.select(active, divisor, 1.0), 0.0)
        return ds, weight, norm

    def weighted_choice(self, si, sample1, active=True):
        """(EmitterPtr, p(j | si), norm, what the light sample's weight is divided by): p(j)
        itself here; a resampled choice (light_tree.ResampledTreeSelection) divides by the
        inverse of its resampling weight and keeps p(j) for the MIS densities."""
        emitter, sel, norm = self.choose(si, sample1, active)
        return emitter, sel, norm, sel

    def pdf_direction(self, si_from, si_hit, active=True, norm=None):
        """Solid-angle density with which light sampling from ``si_from`` produces the
        direction to the emitter surface (or environment) found at ``si_hit``; ``norm``: what
        :meth:`sample_direction` returned at ``si_from``, if it was called there."""
        if self.count == 0:
            return mi.Float(0.0)
        ds = direction_sample(self.scene, si_hit, si_from)
        emitter = ds.emitter
        if not is_jit() and (emitter is None or not active):
            return 0.0
        sel = self.pmf_at(si_from, emitter, active, norm)
        pdf = emitter.pdf_direction(si_from, ds, active & (sel > 0))
        return dr.select(active & (sel > 0), pdf * sel, 0.0)


class SelectionCache:
    """Keeps the LightSelection of the scene an integrator last rendered."""

    def __init__(self, mode: str, candidates: int = CANDIDATES):
        self.mode, self.candidates, self._scene, self._sel = mode, candidates, None, None

    @classmethod
    def of(cls, plugin) -> "SelectionCache":
        """The cache of an integrator with ``light_selection`` and ``light_candidates``
        (:data:`CANDIDATES_PARAM`); ``light_candidates`` given with another mode than ris is
        refused (it would change nothing)."""
        mode, m = plugin.light_selection, plugin.light_candidates
        if "light_candidates" in plugin.given and mode != "ris":
            from ..params import ParameterError
            raise ParameterError(f"{plugin.NAME}: parameter 'light_candidates' = {m!r} is "
                                 f"invalid with light_selection={mode!r}; allowed: only with "
                                 "light_selection='ris'")
        return cls(mode, m)

    def __call__(self, scene) -> LightSelection:
        if self._scene is not scene:
            self._sel = make(scene, self.mode, self.candidates)
            self._scene = scene
        return self._sel


# ---------------------------------------------------------------------------------------------
# adaptive selection: per shading point, proportional to an estimate of each light's irradiance
DEFENSIVE = 0.05


def _light_geometry(scene, emitters, power):
    """Per-light arrays for the adaptive estimate (numpy): kind (0 finite, 1 infinite),
    bounding-sphere centre and radius, flat normal (0 when not flat), intensity scale."""
    n = len(emitters)
    kind = np.zeros(n)
    centre = np.zeros((n, 3))
    radius = np.zeros(n)
    normal = np.zeros((n, 3))
    scale = np.zeros(n)
    bs = scene.bbox().bounding_sphere()
    r_scene = max(float(np.array(bs.radius).ravel()[0]), 1e-6)
    for j, e in enumerate(emitters):
        if mi.has_flag(e.flags(), mi.EmitterFlags.Infinite):
            kind[j] = 1
            scale[j] = power[j] / (4 * math.pi * r_scene ** 2)   # irradiance it gives a point
            continue
        shape = e.get_shape()
        if shape is not None:
            box = shape.bbox()
            lo, hi = np.array(box.min, float).ravel(), np.array(box.max, float).ravel()
            centre[j] = 0.5 * (lo + hi)
            radius[j] = 0.5 * float(np.linalg.norm(hi - lo))
            u = _r2(16, 2)
            ns = []
            for a, b in u:
                ps = shape.sample_position(0.0, mi.Point2f(float(a), float(b)))
                ns.append(np.array(ps.n, float).ravel()[:3])
            ns = np.array(ns)
            if np.allclose(ns, ns[0], atol=1e-4):
                normal[j] = ns[0]
            scale[j] = power[j] / math.pi          # = mean L_e * area
        else:
            si = dr.zeros(mi.Interaction3f)
            far = np.array(bs.center, float).ravel() + [0.0, 0.0, 2 * r_scene]
            si.p = mi.Point3f(*[float(v) for v in far])
            ds, _ = e.sample_direction(si, mi.Point2f(0.5, 0.5), True)
            centre[j] = np.array(ds.p, float).ravel()[:3]
            scale[j] = power[j] / (4 * math.pi)    # intensity of an isotropic source
    return kind, centre, radius, normal, scale


class AdaptiveLightSelection(LightSelection):
    r"""p(j | x) = (1 - delta) E_j(x) / sum_k E_k(x) + delta p_power(j),  delta = 0.05.

    E_j(x) bounds the irradiance light j can give the shading point x: its power, the distance
    to its bounding sphere (clamped at the sphere's radius), and the cosines at x and at the light
    widened by the half-angle the bounding sphere subtends (so no part of a light that may
    contribute is ruled out; a flat light facing away, or one entirely below the horizon of a
    surface that does not transmit, gets E_j = 0).  Infinite emitters count their irradiance
    Phi / (4 pi r_scene^2).  The defensive term keeps p(j | x) > 0 for every light with power,
    so the estimator stays unbiased even where the bound is loose (shading normals).

    Cost: O(N) per vertex, N + 1 evaluations of E: one pass over the lights sums the E_k and
    draws j ~ E_j / sum_k E_k by weighted reservoir sampling driven by the one uniform number
    (:meth:`_scan`); the sum is returned with the choice (``norm``), so the pdf of a
    BSDF-sampled hit from the same vertex costs one more E (a pdf without ``norm`` costs a
    pass).  Up to ``UNROLL`` (64) lights the pass is unrolled when the kernel is traced, each
    light's parameters constants in it (no gathers, and the terms a light does not need, such
    as the orientation of a sphere, drop out); beyond that it is a symbolic loop of gathers
    from N-entry tables, so the kernel stops growing with N.  Either way it reads every light
    whatever the lane's mask, so the ``norm`` of a masked-off lane is valid too.  O(N) is fine
    up to about 64 lights; a light tree (Conty & Kulla 2018, pbrt-v4's BVHLightSampler) would
    traverse a hierarchy of such bounds instead, O(log N) per vertex, at the price of a pmf
    that is exact only per tree node."""

    UNROLL = 64   # lights up to which the pass is unrolled (see _first)

    def __init__(self, scene):
        super().__init__(scene, "power")
        self.mode = "adaptive"
        if self.count == 0:
            return
        power = self.power
        kind, centre, radius, normal, scale = _light_geometry(scene, self.emitters, power)
        self.tables = dict(
            kind=kind, cx=centre[:, 0], cy=centre[:, 1], cz=centre[:, 2], radius=radius,
            nx=normal[:, 0], ny=normal[:, 1], nz=normal[:, 2], scale=scale)
        if is_jit():
            self.t = {k: mi.Float(v.astype(np.float32)) for k, v in self.tables.items()}
            ids = np.array(dr.reinterpret_array(mi.UInt32, self.emitters_dr), dtype=np.int64)
            idx = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
            idx[ids] = np.arange(self.count, dtype=np.uint32)
            self.index_by_id = mi.UInt32(idx)
        else:
            self.index_by_ptr = {e.ptr: j for j, e in enumerate(self.emitters)}

    def _row(self, j):
        """Light j's table entries: Python floats for an int j (constants in the kernel),
        gathered values for an index array."""
        if isinstance(j, int):
            return {k: float(v[j]) for k, v in self.tables.items()}
        return {k: dr.gather(mi.Float, v, j) for k, v in self.t.items()}

    def _estimate(self, si, j):
        """E_j(x): the bound on light j's irradiance at ``si`` (j: int or index array < N)."""
        g = self._row(j)
        const = isinstance(j, int)
        if const and g["kind"] > 0.5:   # infinite emitter: the same everywhere
            return mi.Float(g["scale"])
        c = mi.Point3f(g["cx"], g["cy"], g["cz"])
        d = c - si.p
        dist2 = dr.squared_norm(d)
        dist = dr.sqrt(dist2)
        wdir = d / dr.maximum(dist, 1e-12)
        sin_b = dr.minimum(g["radius"] / dr.maximum(dist, 1e-12), 1.0)
        cos_b = dr.safe_sqrt(1.0 - sin_b * sin_b)

        def widened(cos_t):  # cos(max(theta - theta_b, 0))
            sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
            return dr.select(cos_t > cos_b, 1.0, cos_t * cos_b + sin_t * sin_b)

        cos_p = dr.maximum(widened(dr.dot(si.n, wdir)), 0.0)
        n_l = mi.Vector3f(g["nx"], g["ny"], g["nz"])
        if const and not (g["nx"] or g["ny"] or g["nz"]):
            cos_l = 1.0                 # not flat: no orientation factor
        else:
            flat = dr.squared_norm(n_l) > 0
            cos_l = dr.select(flat, dr.maximum(widened(dr.dot(n_l, -wdir)), 0.0), 1.0)
        finite = g["scale"] * cos_p * cos_l / dr.maximum(dist2, g["radius"] * g["radius"])
        return finite if const else dr.select(g["kind"] > 0.5, g["scale"], finite)

    def _first(self):
        """Loop counter over the lights: a Python int (the loop is unrolled, every light's
        parameters are constants in the kernel) up to UNROLL lights and in the scalar
        variant, else a symbolic loop of gathers (the kernel does not grow with N)."""
        return 0 if (self.count <= self.UNROLL or not is_jit()) else mi.UInt32(0)

    @dr.syntax
    def _total(self, si):
        total = mi.Float(0.0)
        j = self._first()
        while dr.hint(j < self.count, label="adaptive light selection: total"):
            total += self._estimate(si, j)
            j += 1
        return total

    @dr.syntax
    def _scan(self, si, u, watch):
        """One pass over the lights: (j, E_j, E_watch, sum_k E_k) with j drawn with
        probability E_j / sum_k E_k by a weighted reservoir: light k replaces the pick with
        probability E_k / sum_{i<=k} E_i, decided by ``u``, which is rescaled to a fresh
        uniform number after each decision.  ``watch``: an index whose E is wanted too."""
        total = mi.Float(0.0)
        idx = mi.UInt32(0)
        e_idx = mi.Float(0.0)
        e_watch = mi.Float(0.0)
        u = mi.Float(u)
        j = self._first()
        while dr.hint(j < self.count, label="adaptive light selection"):
            e = self._estimate(si, j)
            total += e
            p = safe_div(e, total)
            take = u < p
            idx = dr.select(take, j, idx)
            e_idx = dr.select(take, e, e_idx)
            u = dr.select(take, u / dr.select(take, p, 1.0),
                          (u - p) / dr.select(take, 1.0, 1.0 - p))
            u = dr.minimum(u, ONE_MINUS_EPS)
            e_watch = dr.select(watch == j, e, e_watch)
            j += 1
        return idx, e_idx, e_watch, total

    def _mix(self, e_j, total, p_power):
        adaptive = dr.select(total > 0, e_j / dr.select(total > 0, total, 1.0), p_power)
        return (1.0 - DEFENSIVE) * adaptive + DEFENSIVE * p_power

    def _index(self, emitter, active):
        if is_jit():
            return dr.gather(mi.UInt32, self.index_by_id,
                             dr.reinterpret_array(mi.UInt32, emitter), active)
        return self.index_by_ptr.get(emitter.ptr, 0)

    def pmf_at(self, si, emitter, active=True, norm=None):
        """p(j | x) of ``emitter`` at the shading point ``si``; ``norm``: the sum of the
        bounds at ``si`` that :meth:`choose` returned there (computed here if None)."""
        total = self._total(si) if norm is None else norm
        e_j = self._estimate(si, self._index(emitter, active))
        return self._mix(e_j, total, self.pmf(emitter, active))

    def sample(self, sample1, active=True):
        raise NotImplementedError("adaptive selection needs the shading point: use choose")

    def choose(self, si, sample1, active=True):
        # with probability DEFENSIVE a draw from the power pmf, else from the bounds
        use_power = sample1 < DEFENSIVE
        u = dr.select(use_power, sample1 / DEFENSIVE, (sample1 - DEFENSIVE) / (1.0 - DEFENSIVE))
        u = dr.minimum(u, ONE_MINUS_EPS)
        slot_p, _ = self.distr.sample_pmf(u, active)
        idx_p = self._slot_emitter(slot_p, active)
        idx_a, e_a, e_p, total = self._scan(si, u, idx_p)
        use_power |= total <= 0
        idx = dr.select(use_power, idx_p, idx_a)
        emitter = self._emitter(idx, active)
        sel = self._mix(dr.select(use_power, e_p, e_a), total, self.pmf(emitter, active))
        return emitter, sel, total


def selection_class(mode: str) -> type:
    """The LightSelection class of a ``light_selection`` mode."""
    if mode == "bvh":
        from .light_tree import LightTreeSelection
        return LightTreeSelection
    if mode == "ris":
        from .light_tree import ResampledTreeSelection
        return ResampledTreeSelection
    return AdaptiveLightSelection if mode == "adaptive" else LightSelection


def make(scene, mode: str, candidates: int = CANDIDATES) -> LightSelection:
    cls = selection_class(mode)
    if cls is LightSelection:
        return cls(scene, mode)
    return cls(scene, candidates) if mode == "ris" else cls(scene)


def sample_dims(mode: str) -> int:
    """Uniform numbers one light choice of ``mode`` draws (its class's ``SAMPLE_DIMS``), for
    estimators that lay out their random numbers in advance (pssmlt's primary vectors)."""
    return selection_class(mode).SAMPLE_DIMS
