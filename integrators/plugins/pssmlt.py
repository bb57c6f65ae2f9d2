r"""Integrator ``pssmlt``: Metropolis sampling in primary sample space (Kelemen et al. 2002).

The image is the integral over primary samples u in [0, 1)^D (:mod:`integrators.sampling.
primary_sample`) of the path contribution f(u) splatted at its film position (the first two
coordinates of u).  With the importance I(u) = luminance of |f(u)| and b = int I(u) du (the
image's mean luminance), Metropolis sampling draws u with density I(u)/b, and pixel j is

    P_j = (b W H / N) sum_i 1_j(u_i) f(u_i) / I(u_i)    (N mutations over a W x H film)

(before Kelemen's weights, below).
* **The importance** (``importance``): Kelemen's, the luminance of the contribution
  (``luminance``, the default), sends the mutations where the image is bright, so a dim part
  of the image (the room around a lamp) gets few of them and a high *relative* error.
  ``relative`` divides it by the brightness of the sample's pixel, g_j = sqrt(B_j^2 + (0.1
  mean)^2), B_j the mean luminance of the pixel's block in a pilot image splatted from the
  bootstrap paths (no extra rendering; blocks of ``PILOT_SAMPLES`` paths, floored at a tenth
  of the image mean): I = luminance / g_j.  Metropolis works for any importance positive
  wherever f is not zero (b = int I du, estimated by the same bootstrap), and with g_j^2 =
  I_j^2 + eps the mutations per pixel minimise sum_j Var_j / (I_j^2 + eps) to first order
  (Cauchy-Schwarz on the pixels' shares; Hoberock & Hart 2010 on importance functions for
  MLT).  The pilot is fixed for a run (passes that continue the chains keep it).  Measured
  (64x64, 8 s, 3 repeats, medians of equal-time relMSE, ``benchmarks/results/pssmlt/
  importance``): with the path estimator relative brings the error to 0.52x and 0.64x
  luminance's on the two caustic scenes and 0.86x on one glass shade, but 1.7x on the other
  (pssmlt_glass_shade: the dim room is lit through the glass, its bootstrap estimate is
  heavy-tailed); with ``estimator=bdpt`` 0.92-1.0x on all four.  Mixed, hence not the default.
* **The cap** (``importance_cap``, default 8 with ``estimator=bdpt``, none with ``path``): I =
  min(I, cap x the bootstrap's mean I), the cap set by the bootstrap (whose own I it caps, so
  b is the mean of the capped I) and kept with the chains.  Any I > 0 wherever f is not zero
  is a valid target, so the estimate stays consistent; a path above the cap is then sampled
  less often than its luminance asks and weighted up by f / I.  Why: a path of very large I
  (bdpt: mostly a firefly of one strategy) is given many chains by the bootstrap's resampling
  and holds every chain that reaches it (a large step leaves with probability about mean I /
  I), so in a render's time the image keeps the bootstrap's share of it, a blob (measured on
  pssmlt_caustic: one pixel at 18x its value in each of 24 passes, 93 % of the relMSE).  The
  path estimator's large I are the caustic paths Metropolis is there to explore: capped at 8,
  its caustic errors double, hence no cap there (``BDPT_IMPORTANCE_CAP`` has the figures).
* **The estimator** is the path estimator of ``nee_path`` with its defaults (power-heuristic MIS
  between one light sample and the BSDF sample at every vertex, throughput roulette from
  depth 5), the light chosen by ``light_selection`` (default ``power``; ``bvh`` and ``ris``
  for many lights: a light choice is a function of the chain's coordinates like any other,
  ris's two numbers each get a coordinate): the shared :meth:`VertexEstimator.path`, driven by a
  :class:`PrimarySampler` that reads the chain's primary vector instead of a sampler.
* **``estimator=bdpt``** drives every strategy of :mod:`integrators.plugins.bdpt` instead (same
  ``max_depth``, any; bdpt's default ``bidir_depth``, so paths longer than 16 segments take
  s = 0 and s = 1 only; ``hide_emitters``; ``light_selection`` for its light samples, the
  light subpath started by power as bdpt does):
  a primary sample is one camera subpath and one light subpath, each reading its own part of
  the vector (the camera's first: film position, then per vertex a light sample, a BSDF
  sample and roulette; the light's: its start, then per vertex the connection to the
  camera, a BSDF sample and roulette; ``primary_sample.PrimarySampler.substream``), so that
  a longer light subpath does not shift the camera subpath's numbers.  Its contribution is a
  set of splats: the camera sample's at its pixel and each light vertex's connection to the
  camera (t = 1) at the pixel it projects to; I is the sum of their luminances, and every
  splat of the current and of the proposed path takes that path's weight.  bdpt runs kernels
  of its own (the light subpaths are stored before the camera subpaths connect to them), so
  its steps are one per kernel launch (:func:`step_splats`), not fused: the default
  ``chains`` is then ``BDPT_CHAINS`` (16,384), wide enough to pay for the launch.  Scenes
  bdpt refuses (directional lights, media, non-perspective cameras) are refused.
* **``estimator=auto``** (the default) takes ``bdpt`` where bdpt renders the scene
  (:meth:`PSSMLT.auto_choice`, once per scene and sensor), else ``path``, and says which and
  why in ``run_notes()``.  Any ``max_depth`` takes ``bdpt`` (-1, the default, included:
  bdpt's paths beyond ``bidir_depth`` are path-traced, unbounded).  On the caustic and
  glass-shade scenes bdpt's chains had 0.24-0.42x Mitsuba's ``path`` error at equal time
  where the path estimator's had 1.05-2.5x (``benchmarks/results/pssmlt/cap``, max_depth 8);
  on a faster machine, where ``path`` reaches 4,000-6,800 spp in the 8 s, 0.47-0.73x at
  max_depth -1 and 0.39-1.00x at 8, the worst where a chain holds a rare bright path (a blob;
  ``benchmarks/results/pssmlt/unbounded``, ``depth8_rerun``).  On an evenly lit scene
  Metropolis loses with either estimator, and bdpt's more (the Cornell box: 9.8x ``path``'s
  error against 6.2x): render those with ``path`` or ``bdpt``.
* **Many chains**, one per Dr.Jit lane (``chains``).  Each step proposes, for every chain, a
  large step (a fresh uniform vector) with probability ``large_step``, otherwise Kelemen's small
  step (every coordinate moved by at most ``sigma``, mod 1; a symmetric proposal), and accepts
  with a = min(1, I(u')/I(u)).
* **Many steps per kernel**: up to ``STEPS_PER_KERNEL`` steps of every chain run in one
  Dr.Jit kernel, a symbolic loop over the steps whose state is each chain's primary vector (a
  ``dr.Local`` array per lane, read by the path with a dynamic index), its contribution,
  importance and pixel; the splats are atomic adds inside the loop.  One trace and one launch
  per 64 steps instead of per step, and no flat-array rewrite per step: a mutation costs
  about 1.3 path evaluations of ``nee_path`` (the proposal of each coordinate is a hash).
  Fewer chains thus take more steps each in the same time, which is what lowers the error
  (a chain's error is dominated by its start and by bright paths it sits on: few long chains
  beat many short ones), hence the default of 2048 chains.
* **Expected-value splatting** (Veach) **with Kelemen's weights**: the current state is
  splatted with weight 1 - a and the proposal with weight a, each at its own pixel, by atomic
  adds into the film (a box filter of one pixel: each splat goes to the pixel its film position
  falls in).  A large-step proposal is also an independent uniform sample, so it counts once
  more; the two sample sets (Metropolis, density I/b per mutation, and large steps, density
  p_large) are combined by the balance heuristic: each splat is f / (I/b + p_large) times
  (1 - a), (a + [large step]), and W H / N.  With ``large_step = 0`` this is f b / I.
* **Normalisation and start**: b is the mean of I over ``bootstrap`` independent paths, refined
  by the I of every large-step proposal (independent uniform samples too); it multiplies the
  pass's splats at the end of the pass.  The chains start from the bootstrap paths, resampled
  in proportion to I (systematic resampling), so they start in the bootstrap's estimate of the
  stationary distribution: no start-up bias in expectation, but a rare bright path found by the
  bootstrap starts several chains, which splat a blob until they move apart.
* **Emission seen directly** (``separate_emission``, default on) is rendered apart by ``spp``
  camera rays per pixel: a light in view would otherwise draw most chains to its pixels.  With
  ``estimator=bdpt`` this includes the emission seen through delta scatterings only (a lamp
  behind glass, a light in a mirror: bdpt's s = 0 after an all-delta prefix, the one strategy
  that makes those paths, weight 1), by ``DELTA_RAYS`` (4) rays per mutation: such a path
  found by a chain is bright and hard to leave, a blob (measured on the caustic scene: one
  of three runs at 4x the error of the others without this, none with it).
* **Passes**: ``render()`` with ``spp`` does spp x W x H mutations (spp = mutations per pixel,
  the last step over a rotating subset of the chains).  With ``continue_chains`` (default) a
  render whose seed is the previous render's seed + 1 (the passes of ``render`` /
  :mod:`integrators.app.progressive`, ``--time`` included) continues the chains, b and the
  bootstrap of that previous render, so a longer render converges rather than restarts; any
  other seed starts afresh (new bootstrap from that seed), so runs with disjoint seed ranges
  are independent and merge exactly.  The state is kept on the integrator object, per scene.
  The run record lists ``continue_chains``; the variance layer of ``render`` treats passes as
  independent, which continued chains are not (it understates the error).
* Films: the image is RGB internally; Y, XYZ and alpha (1) channels are derived for the film's
  pixel format.  The splat is the box filter, whatever the film's ``rfilter``.
* Variants: JIT variants only (``llvm_*``, ``cuda_*``); scalar variants are refused in one line.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import depth_limit, emitted, is_jit, record_once
from ..params import MAX_COUNT, Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, mis, roulette
from ..sampling import primary_sample as ps
from ..sampling.subpath import LightWalk, VertexStore, is_delta_sample
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate, SceneError
from .bdpt import BIDIR_DEPTH, _is_pinhole, bidirectional_depth

MAX_CHAINS = 1 << 20
ESTIMATORS = ("auto", "path", "bdpt")
#: chains of the path estimator when ``chains`` is not given (see the docstring)
PATH_CHAINS = 2048
#: large-step probability of the path estimator when ``large_step`` is not given (Kelemen's and
#: pbrt-v4's 0.3; the bdpt estimator's: BDPT_LARGE_STEP)
PATH_LARGE_STEP = 0.3
MAX_BOOTSTRAP = 1 << 24


def _rgb(L, wavelengths, active):
    """The sRGB value of a radiance sample in any variant (Color3f)."""
    s = mi.unpolarized_spectrum(L)
    if mi.is_spectral:
        return mi.spectrum_to_srgb(s, wavelengths, active)
    if mi.is_monochromatic:
        return mi.Color3f(s[0], s[0], s[0])
    return mi.Color3f(s)


def film_pixel(pos, w: int, h: int):
    """Index of the pixel that film position ``pos`` (in [0, 1)^2) falls in."""
    px = dr.minimum(mi.UInt32(dr.floor(pos.x * w)), w - 1)
    py = dr.minimum(mi.UInt32(dr.floor(pos.y * h)), h - 1)
    return py * w + px


def importance(rgb):
    """I(u): luminance of |f(u)| (positive wherever any channel is non-zero)."""
    return mi.luminance(dr.abs(rgb))


IMPORTANCES = ("luminance", "relative")
#: importance=relative: bootstrap paths per block of the pilot image (the block's side follows)
PILOT_SAMPLES = 1024
#: importance=relative: the pilot's floor, as a fraction of the image's mean luminance (the
#: relMSE's 0.01 = 0.1^2 for an image of mean 1)
PILOT_FLOOR = 0.1


def pilot_scale(pix, rgb, w: int, h: int, n: int):
    """importance=relative: per pixel g = sqrt(B^2 + (PILOT_FLOOR mean)^2), B the mean
    luminance of the pixel's block estimated from ``n`` independent paths (their splats
    ``pix``, ``rgb``: arrays or lists of them), blocks of side ceil(sqrt(PILOT_SAMPLES w h / n))
    pixels, ``mean`` the image's (numpy, w h; ones for a black image).  I = luminance / g is
    then about the contribution relative to its pixel's value: Metropolis spreads the
    mutations for a relative error (Hoberock and Hart 2010 on MLT importance functions; with
    g_j = sqrt(I_j^2 + eps) the mutations per pixel minimise sum_j Var_j / (I_j^2 + eps)
    to first order), and the estimate stays consistent for any g > 0 (b = E[I] by the same
    bootstrap)."""
    pix = pix if isinstance(pix, list) else [pix]
    rgb = rgb if isinstance(rgb, list) else [rgb]
    img = np.zeros(w * h)
    for p_k, r_k in zip(pix, rgb):
        np.add.at(img, np.array(p_k, dtype=np.int64),
                  np.array(importance(r_k), dtype=np.float64))
    img *= w * h / max(n, 1)
    mean = float(img.mean())
    if not mean > 0:
        return np.ones(w * h, np.float32)
    side = max(1, math.ceil(math.sqrt(PILOT_SAMPLES * w * h / max(n, 1))))
    hb, wb = -(-h // side), -(-w // side)
    pad = np.full((hb * side, wb * side), np.nan)
    pad[:h, :w] = img.reshape(h, w)
    blocks = np.nanmean(pad.reshape(hb, side, wb, side), axis=(1, 3))
    per_pixel = np.repeat(np.repeat(blocks, side, 0), side, 1)[:h, :w].ravel()
    return np.sqrt(per_pixel ** 2 + (PILOT_FLOOR * mean) ** 2).astype(np.float32)


class ChainState:
    """The chains and what they have seen: current vectors ``u`` (flat, chains x ``dims``),
    their contributions (``rgb``, importance ``lum``, pixel ``pix``), the sum and count of I
    over independent samples (bootstrap and large-step proposals: b = lum_sum / lum_count),
    and counters.  ``key``: the run's random key (from its first seed)."""

    def __init__(self, key, dims, u, rgb, lum, pix, lum_sum, bootstrap):
        self.key, self.dims, self.u, self.rgb, self.lum, self.pix = key, dims, u, rgb, lum, pix
        self.chains = dr.width(lum)
        self.lum_sum, self.lum_count, self.bootstrap = lum_sum, bootstrap, bootstrap
        self.steps = 0           # steps taken (keys the random streams)
        self.offset = 0          # first chain of the next partial step
        self.mutations = 0
        self.accepted = 0.0      # sum of acceptance probabilities
        self.large = 0
        self.scene = self.sensor = self.size = None
        self.seed_first = self.seed_last = None
        self.pilot = None        # importance=relative: the pixels' g (pilot_scale)
        self.cap = None          # importance_cap: the cap on I

    @property
    def b(self) -> float:
        return self.lum_sum / max(self.lum_count, 1)

    def large_b(self, large_step: float):
        """p_large b, the large steps' density in Kelemen's weights (opaque: one kernel)."""
        return dr.opaque(mi.Float, large_step * self.b)


@plugin("pssmlt", "integrator")
class PSSMLT(IntegratorTemplate):
    """Primary-sample-space Metropolis light transport: many chains, bootstrap normalisation."""

    PARAMS = (
        MAX_DEPTH,
        Param("large_step", "float", PATH_LARGE_STEP, min=0.0, max=1.0,
              doc="Probability of a large step (a fresh uniform primary sample; not given: "
                  "0.8 with estimator bdpt)."),
        Param("sigma", "float", 1.0 / 64.0, min=0.0, max=0.5, min_exclusive=True,
              doc="Small-step size: Kelemen's s2 (largest offset per coordinate; s1 = s2/16)."),
        Param("chains", "int", PATH_CHAINS, min=1, max=MAX_CHAINS,
              doc="Markov chains run in parallel (one Dr.Jit lane each); fewer chains take "
                  "more steps each in the same time (up to 64 steps per kernel; not given: "
                  "16384 with estimator bdpt, one step per kernel)."),
        Param("bootstrap", "int", 131072, min=1, max=MAX_BOOTSTRAP,
              doc="Independent paths that estimate the normalisation b and seed the chains."),
        Param("estimator", "choice", "auto", choices=ESTIMATORS,
              doc="Path estimator driven by the chains: path (nee_path's), bdpt (every "
                  "strategy of bdpt, light tracing included), or auto: bdpt where the "
                  "scene allows it, else path (the run record says which and why)."),
        Param("separate_emission", "bool", True,
              doc="Render the emission seen directly by camera rays apart (spp camera rays "
                  "per pixel), not by the chains, which lights in view would draw to them "
                  "(estimator bdpt: also the emission seen through mirrors and glass, by 4 "
                  "rays per mutation)."),
        Param("importance", "choice", "luminance", choices=IMPORTANCES,
              doc="The chains' target I: luminance of the contribution (Kelemen's), or "
                  "relative: that luminance over the pixel's brightness, estimated from the "
                  "bootstrap paths (blocks of pixels, floored at a tenth of the image mean), "
                  "so that dim parts of the image get their share for a relative error."),
        Param("importance_cap", "float", 0.0, min=0.0,
              doc="Cap of the chains' target I, as a multiple of the bootstrap's mean I "
                  "(0: none; not given: 8 with estimator bdpt): I = min(I, cap mean).  A "
                  "rare path of very large I then neither starts many chains nor holds them, "
                  "and is weighted up instead (any positive I is a valid target)."),
        light_selection.PARAM, light_selection.CANDIDATES_PARAM,
        Param("continue_chains", "bool", True,
              doc="A render whose seed follows the previous one continues its chains "
                  "(render passes); false: every render starts from a new bootstrap."),
        HIDE_EMITTERS,
    )

    def setup(self):
        if not is_jit():
            raise ParameterError(
                f"pssmlt: variant {mi.variant()} is not supported (the chains are Dr.Jit "
                "lanes); use a JIT variant such as llvm_ad_rgb")
        self.heur = mis.Heuristic("power", 2.0, 0.1)
        self.lights = light_selection.SelectionCache.of(self)
        self.vertex = VertexEstimator(self.heur, 1, 1, roulette.Roulette("throughput", 5))
        self.bd = None
        #: estimator=auto: bdpt or path, decided per scene in render() (auto_choice)
        self.auto = self.estimator == "auto"
        self.auto_reason = None
        self._auto_for = None
        #: the bdpt estimator's D: paths of at most D segments take every strategy of bdpt
        self.bd_depth = bidirectional_depth(self.max_depth, BIDIR_DEPTH)
        # (auto: provisional until render() sees the scene)
        self.use_estimator("bdpt" if self.auto else self.estimator)
        self.state = None
        #: importance=relative: per pixel g of the current run's chains (pilot_scale)
        self.pilot = None
        #: importance_cap: the cap on I of the current run's chains (set by its bootstrap)
        self.cap = None

    def use_estimator(self, estimator: str):
        """Drive the chains with ``estimator`` ('path' | 'bdpt'), and set what depends on it:
        the primary-sample dimensions, what seen_emission renders apart, and the defaults of
        ``chains`` and ``importance_cap`` where they were not given."""
        self.estimator = estimator
        bd = estimator == "bdpt"
        choice = light_selection.sample_dims(self.light_selection)
        self.dims = ps.dims_for(self.max_depth, choice)
        # a finite max_depth within the stored vertices never draws past the stored coordinates
        self.extra = not (0 <= self.max_depth <= ps.MAX_STORED_VERTICES + 1)
        #: what the chains leave to seen_emission: the emission seen directly, and with the
        #: bdpt estimator also the emission seen through delta scatterings only
        self.left_out = None if not self.separate_emission else ("delta" if bd else "direct")
        if bd:
            self.dims_cam, self.dims_light = bdpt_dims(self.max_depth, self.bd_depth, choice)
            self.dims, self.extra = self.dims_cam + self.dims_light, True
        # (the values used go to run_notes: the record's params are what was asked for, its
        # identity for merges, copied before the first render decides)
        if "chains" not in self.given:   # bdpt: one kernel per step, wide steps pay
            self.chains = BDPT_CHAINS if bd else PATH_CHAINS
        if "importance_cap" not in self.given:
            self.importance_cap = BDPT_IMPORTANCE_CAP if bd else 0.0
        if "large_step" not in self.given:
            self.large_step = BDPT_LARGE_STEP if bd else PATH_LARGE_STEP

    def auto_choice(self, scene, sensor):
        """estimator=auto: bdpt where bdpt renders the scene (its one-line refusal otherwise
        becomes the reason), else path.  Decided once per (scene, sensor); a change of
        estimator drops the chains."""
        if self._auto_for == (scene, sensor):
            return
        try:
            self.bdpt_estimator(scene, sensor)
            choice, why = "bdpt", "the scene allows bdpt"
        except SceneError as e:
            choice, why = "path", str(e)
        if choice != self.estimator:
            self.use_estimator(choice)
            self.state = None
        self._auto_for, self.auto_reason = (scene, sensor), why

    def run_notes(self) -> dict:
        """For the run record: which estimator the chains drove (and, for auto, why), with the
        chains, importance cap and large-step probability it used."""
        notes = {"estimator": self.estimator, "chains": self.chains,
                 "importance_cap": self.importance_cap, "large_step": self.large_step}
        if self.auto:
            notes["estimator_auto"] = self.auto_reason
        return notes

    # ---- the estimator: one path per lane from a primary sampler --------------------------
    def contribution(self, scene, sensor, sel, sampler, active=True):
        """(pixel index, sRGB contribution, I) of each lane's primary sample.  Consumes the
        sampler's coordinates in the order of primary_sample.CAMERA_DIMS, then the path's."""
        film = sensor.film()
        w, h = (int(x) for x in film.crop_size())
        pos = sampler.next_2d(active)
        wav = sampler.next_1d(active)
        aperture = sampler.next_2d(active)
        t = sampler.next_1d(active)
        time = sensor.shutter_open() + t * sensor.shutter_open_time()
        ray, ray_w = sensor.sample_ray(time, wav, pos, aperture, active)
        ray = mi.Ray3f(ray)
        act = mi.Bool(active)
        si, L = self.camera_hit(scene, ray, act)
        if self.separate_emission:   # rendered apart (seen_emission)
            L = mi.Spectrum(0.0)
        act = act & si.is_valid() & (1 < depth_limit(self.max_depth))
        L += self.vertex.path(scene, sampler, sel, ray, si, act, self.max_depth)
        rgb = _rgb(ray_w * L, ray.wavelengths, active)
        ok = dr.all(dr.isfinite(rgb)) & mi.Bool(active)
        rgb = dr.select(ok, rgb, 0.0)
        return film_pixel(pos, w, h), rgb, importance(rgb)

    def estimate(self, scene, sensor, sel, sampler):
        """The chosen estimator's contribution of each lane's primary sample:
        :meth:`contribution` (path: one splat) or :meth:`contribution_bdpt` (lists)."""
        f = self.contribution_bdpt if self.estimator == "bdpt" else self.contribution
        pix, rgb, lum = f(scene, sensor, sel, sampler)
        if self.pilot is not None:          # importance=relative, once the pilot is known
            lum = self.relative_importance(pix, rgb)
        if self.cap is not None:            # importance_cap, once the bootstrap set it
            lum = dr.minimum(lum, self.cap)
        return pix, rgb, lum

    def relative_importance(self, pix, rgb):
        """importance=relative: I = sum over the splats of luminance / g at their pixels
        (:func:`pilot_scale`)."""
        if not isinstance(pix, list):
            return importance(rgb) / dr.gather(mi.Float, self.pilot, pix)
        lum = mi.Float(0.0)
        for p_k, r_k in zip(pix, rgb):
            lum += importance(r_k) / dr.gather(mi.Float, self.pilot, p_k)
        return lum

    def retarget(self, w: int, h: int):
        """For :func:`start`: the bootstrap's splats and I -> their I under this run's
        importance: relative (the pilot built from them first) and/or capped at
        ``importance_cap`` x their mean (the cap kept for the chains); None with
        importance=luminance and no cap."""
        if self.importance != "relative" and not self.importance_cap > 0:
            return None

        def target(pix, rgb, n, lum):
            if self.importance == "relative":
                self.pilot = mi.Float(pilot_scale(pix, rgb, w, h, n))
                lum = self.relative_importance(pix, rgb)
            if self.importance_cap > 0:
                mean = float(np.array(lum, dtype=np.float64).mean())
                self.cap = dr.opaque(mi.Float, self.importance_cap * mean) if mean > 0 else None
                if self.cap is not None:
                    lum = dr.minimum(lum, self.cap)
            return lum
        return target

    def bdpt_estimator(self, scene, sensor):
        """The ``bdpt`` integrator whose strategies the chains drive (same max_depth,
        hide_emitters, light selection), checked against the scene once."""
        if self.bd is None:
            ris = {"light_candidates": self.light_candidates} \
                if self.light_selection == "ris" else {}
            self.bd = mi.load_dict({"type": "bdpt", "max_depth": self.max_depth,
                                    "bidir_depth": BIDIR_DEPTH,
                                    "hide_emitters": self.hide_emitters,
                                    "light_selection": self.light_selection, **ris})
        if getattr(self, "_bd_checked", None) != (scene, sensor):
            self.bd.check_support(scene, sensor)
            if not _is_pinhole(sensor):
                raise SceneError("pssmlt: estimator 'bdpt' needs a 'perspective' camera "
                                 "(its light tracing splats onto the film)")
            self._bd_checked = (scene, sensor)
        return self.bd

    def streams(self, sampler):
        """The bdpt estimator's two samplers over a primary vector: (camera subpath, light
        subpath), reading disjoint coordinates (the camera's first ``dims_cam``, the light's
        the next ``dims_light``): the subpaths must be independent for bdpt's weights."""
        return (sampler.substream(0, self.dims_cam),
                sampler.substream(self.dims_cam, self.dims_light))

    def contribution_bdpt(self, scene, sensor, sel, sampler, active=True):
        """bdpt's estimate of one primary sample as splats: ([pixel of the camera sample,
        pixel of each light vertex's t = 1 connection], [their RGB values], I = the sum of
        their luminances).  The camera subpath reads the row's first ``dims_cam``
        coordinates (film position, then its vertices), the light subpath the rest.  The
        light vertices' splats are kept per lane and depth (D - 1 slots, D bdpt's
        ``bd_depth``)."""
        bd = self.bdpt_estimator(scene, sensor)
        film = sensor.film()
        w, h = (int(x) for x in film.crop_size())
        lanes = dr.width(sampler.rows)
        lane = dr.arange(mi.UInt32, lanes)
        cam, light = self.streams(sampler)
        md = bd.bd_depth
        tables, lambert = bd.tables(scene)
        cap = max(md - 2, 0)
        slots = max(md - 1, 0)
        store = VertexStore(lanes, cap)
        buf = _Splats(lanes, slots)
        if md >= 2:
            def record(si, bsdf, beta, dvcm, dvc, depth, active, smp):
                uv, rgb, ok = bd.t1_connection(scene, sensor, si, bsdf, beta, dvcm, dvc,
                                               depth, active, smp)
                buf.put(lane * slots + depth - 1, uv, rgb, ok, w, h)

            walk = LightWalk(bd.mis, bd.rr, md - 1, md - 2, lambert)
            sel_e = bd.emission_selection(scene, sel)
            walk.walk(scene, sel_e, tables, light, store, lane, mi.Bool(True), record,
                      nee_sel=None if sel_e is sel else sel)
        store.evaluate()
        buf.evaluate()
        pos = cam.next_2d()
        ray, ray_w = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        L, _ = bd.camera_walk(scene, sel, tables, sensor, cam, store, lane, mi.Ray3f(ray),
                              leave_out=self.left_out)
        rgb = _rgb(ray_w * L, ray.wavelengths, True)
        rgb = dr.select(dr.all(dr.isfinite(rgb)), rgb, 0.0)
        pix, rgbs = [film_pixel(pos, w, h)], [rgb]
        for k in range(slots):
            p_k, rgb_k = buf.get(lane * slots + k)
            pix.append(p_k)
            rgbs.append(rgb_k)
        lum = importance(rgbs[0])
        for rgb_k in rgbs[1:]:
            lum += importance(rgb_k)
        return pix, rgbs, lum

    def seen_emission(self, sensor, scene, spp: int, seed: int, w: int, h: int):
        """The emission seen directly by camera rays, by ``spp`` camera rays per pixel (box
        filter): a flat RGB image, the part of the image the chains leave out with
        ``separate_emission``."""
        n = w * h * spp
        lane = dr.arange(mi.UInt32, n)
        key = dr.opaque(mi.UInt32, _key(seed, 0x85EBCA6B))
        r = [ps.uniform(lane * 6 + i, key) for i in range(6)]
        pixel = lane // spp
        py = pixel // w
        px = pixel - py * w
        pos = mi.Point2f((mi.Float(px) + r[0]) / w, (mi.Float(py) + r[1]) / h)
        time = sensor.shutter_open() + r[5] * sensor.shutter_open_time()
        ray, ray_w = sensor.sample_ray(time, r[2], pos, mi.Point2f(r[3], r[4]))
        ray = mi.Ray3f(ray)
        si, L = self.camera_hit(scene, ray, mi.Bool(True))
        if self.left_out == "delta":        # and through delta scatterings (bdpt's s = 0)
            L += self.delta_chain_emission(scene, ray, si, lane, _key(seed, 0x27D4EB2F))
        rgb = _rgb(ray_w * L, ray.wavelengths, True)
        rgb = dr.select(dr.all(dr.isfinite(rgb)), rgb, 0.0) / spp
        image = dr.zeros(mi.Float, w * h * 3)
        splat(image, pixel, rgb, dr.any(rgb != 0))
        return image

    @record_once
    @dr.syntax
    def delta_chain_emission(self, scene, ray, si, lane, key):
        """The emission a camera ray reaches through delta scatterings only (mirrors,
        glass, null interfaces: BSDF samples of a delta lobe), after its first hit ``si``,
        up to ``max_depth`` segments: the paths whose only strategy in bdpt is s = 0 with
        weight 1, which the chains of the bdpt estimator leave out (the camera walk's
        ``leave_out="delta"``), with throughput roulette from depth 5 (which ends a chain
        between parallel mirrors).  Random numbers: 4 per bounce, hashes of ``lane`` with a
        key per bounce and dimension."""
        ctx = mi.BSDFContext()
        rr = roulette.Roulette("throughput", 5)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        ray = mi.Ray3f(ray)
        depth = mi.UInt32(1)
        max_depth = depth_limit(self.max_depth)
        k = dr.opaque(mi.UInt32, key)
        active = si.is_valid() & (depth < max_depth)
        while dr.hint(active, label="pssmlt delta chain", exclude=[k, max_depth, ctx]):
            bsdf = si.bsdf(ray)
            kd = k + depth * 4
            bs, w = bsdf.sample(ctx, si, ps.uniform(lane, kd),
                                mi.Point2f(ps.uniform(lane, kd + 1), ps.uniform(lane, kd + 2)),
                                active)
            active &= is_delta_sample(bs) & dr.any(w != 0)
            beta *= w
            eta *= bs.eta
            ray = si.spawn_ray(si.to_world(bs.wo))
            si = scene.ray_intersect(ray, active)
            L += dr.select(active, beta * emitted(scene, si, active), 0.0)
            beta, active = rr(beta, eta, depth, ps.uniform(lane, kd + 3), active)
            depth += 1
            active &= si.is_valid() & (depth < max_depth)
        return L

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """The estimator the chains drive, with an ordinary sampler (one independent path)."""
        sel = self.prepare(scene)
        ray = mi.Ray3f(ray)
        act = mi.Bool(active)
        si, L = self.camera_hit(scene, ray, act)
        valid = si.is_valid()
        act = act & valid & (1 < depth_limit(self.max_depth))
        L += self.vertex.path(scene, sampler, sel, ray, si, act, self.max_depth)
        return L, valid, []

    # ---- render: passes of spp x W x H mutations ------------------------------------------
    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if spp == 0:
            spp = sensor.sampler().sample_count()
        seed = int(seed)
        sel = self.prepare(scene)
        film = sensor.film()
        w, h = (int(x) for x in film.crop_size())

        def contribution(sampler):
            return self.estimate(scene, sensor, sel, sampler)

        if self.auto:
            self.auto_choice(scene, sensor)
        elif self.estimator == "bdpt":
            self.bdpt_estimator(scene, sensor)      # the scene check, before any work
        st = self.state

        if not (self.continue_chains and st is not None and st.scene is scene and
                st.sensor is sensor and st.size == (w, h) and seed == st.seed_last + 1):
            self.state = self.pilot = self.cap = None
            st = start(contribution, self.dims, self.chains, self.bootstrap, seed,
                       extra=self.extra, retarget=self.retarget(w, h))
            st.scene, st.sensor, st.size, st.seed_first = scene, sensor, (w, h), seed
            st.pilot, st.cap = self.pilot, self.cap
        self.pilot, self.cap = st.pilot, st.cap
        st.seed_last = seed
        self.state = st
        total = int(spp) * w * h
        image = dr.zeros(mi.Float, w * h * 3)
        # splats are f/I (w h / N); b, refined by this pass's large steps, multiplies at the end
        run(contribution, st, total, image, dr.opaque(mi.Float, w * h / total),
            self.large_step, self.sigma)
        image = image * dr.opaque(mi.Float, st.b)   # opaque: no kernel per value of b
        if self.separate_emission:
            rays = int(spp) * (DELTA_RAYS if self.left_out == "delta" else 1)
            image += self.seen_emission(sensor, scene, rays, seed, w, h)
        return self.develop_image(film, image, w, h)

    @staticmethod
    def develop_image(film, image, w, h):
        """The (h, w, channels) tensor of the film's pixel format from the RGB image."""
        rgb = np.array(image, dtype=np.float32).reshape(h, w, 3)
        text = str(film)
        fmt = "rgba"
        for line in text.splitlines():
            if "pixel_format" in line:
                fmt = line.split("=", 1)[-1].strip(" ,").lower()
        y = (0.212671 * rgb[..., 0] + 0.715160 * rgb[..., 1] + 0.072169 * rgb[..., 2])[..., None]
        ones = np.ones((h, w, 1), np.float32)
        if fmt.startswith("xyz"):
            m = np.array([[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169],
                          [0.019334, 0.119193, 0.950227]], np.float32)
            col = rgb @ m.T
        elif fmt in ("luminance", "y", "luminance_alpha", "ya"):
            col = y
        else:
            col = rgb
        out = np.concatenate([col, ones], axis=2) if fmt.endswith("a") else col
        return mi.TensorXf(np.ascontiguousarray(out, dtype=np.float32))

    # ---- what a run did -------------------------------------------------------------------
    def stats(self) -> dict:
        """b, chains, mutations, mean acceptance and large-step fraction of the current run."""
        st = self.state
        if st is None:
            return {}
        return {"b": st.b, "chains": st.chains, "bootstrap": st.bootstrap,
                "mutations": st.mutations, "seed_first": st.seed_first,
                "seed_last": st.seed_last,
                "acceptance": st.accepted / max(st.mutations, 1),
                "large_fraction": st.large / max(st.mutations, 1),
                "importance": self.importance, "importance_cap": self.importance_cap}


# ---- the chains, for any contribution (the integrator's paths, or a toy integrand in tests) ---
def _key(seed: int, counter: int):
    k = mi.sample_tea_32(mi.UInt32(seed & 0xFFFFFFFF), mi.UInt32(counter & 0xFFFFFFFF), 8)[0]
    return int(k[0]) if dr.width(k) else int(k)


def start(evaluate, dims: int, chains: int, bootstrap: int, seed: int, resample: bool = True,
          extra: bool = True, retarget=None):
    """Bootstrap and seed the chains: ``bootstrap`` independent primary vectors (generated
    from their index and a key from ``seed``) evaluated by ``evaluate(sampler) -> (pixel, rgb,
    I)``; b = mean I; the chains' vectors resampled from them in proportion to I (systematic
    resampling; with ``resample`` False, or when every I is zero, chain c takes path c).  The
    chains then start in the bootstrap's estimate of the target, so there is no start-up bias
    in expectation (a rare path of large I found by the bootstrap starts several chains,
    which splat a blob until they move apart: Metropolis's start-up noise).  ``retarget``
    (optional): (pixels, rgb, n, I) of the bootstrap -> their I under another importance,
    which ``evaluate`` then returns too (importance=relative, importance_cap).  Returns a :class:`ChainState`."""
    key = _key(seed, 0x9E3779B9)
    k = dr.opaque(mi.UInt32, key)
    pix_b, rgb_b, lum_b = evaluate(ps.primary_sampler(None, dims, dr.arange(mi.UInt32, bootstrap),
                                                      k, extra=extra))
    dr.eval(pix_b, rgb_b, lum_b)
    if retarget is not None:
        lum_b = retarget(pix_b, rgb_b, bootstrap, lum_b)
        dr.eval(lum_b)
    lum_sum = float(np.array(lum_b, dtype=np.float64).sum())
    if resample and lum_sum > 0:
        # systematic resampling: chain c takes the path at the quantile (c + xi) / chains of
        # the bootstrap's distribution of I (one xi): unbiased, each path floor or ceil of
        # its expected number of chains
        xi = ps.uniform(mi.UInt32(0), ps.stream(k, ps.STREAM_SEED))
        q = (mi.Float(dr.arange(mi.UInt32, chains)) + xi) / chains
        pick = mi.DiscreteDistribution(lum_b).sample(dr.minimum(q, 1.0 - 2.0 ** -24))
    else:
        pick = dr.arange(mi.UInt32, chains) % bootstrap
    flat = dr.arange(mi.UInt32, chains * dims)
    row = flat // dims
    u = ps.uniform(dr.gather(mi.UInt32, pick, row) * dims + (flat - row * dims), k)
    if isinstance(pix_b, list):          # several splats per path (estimator bdpt)
        rgb0 = [dr.gather(mi.Color3f, r, pick) for r in rgb_b]
        pix0 = [dr.gather(mi.UInt32, p, pick) for p in pix_b]
    else:
        rgb0, pix0 = dr.gather(mi.Color3f, rgb_b, pick), dr.gather(mi.UInt32, pix_b, pick)
    st = ChainState(key, dims, u, rgb0, dr.gather(mi.Float, lum_b, pick), pix0, lum_sum,
                    bootstrap)
    st.extra = extra
    dr.eval(st.u, st.rgb, st.lum, st.pix)
    return st


def kelemen_weights(lum, lum_c, large, scale, pb):
    """The acceptance probability a = min(1, I'/I) of a proposal of importance ``lum`` from
    a state of importance ``lum_c``, and the splat weights of the current state and of the
    proposal: Kelemen's, which combine the Metropolis samples (density I/b per mutation) and
    the large-step proposals (independent uniform samples, density p_large per mutation) by
    the balance heuristic, f / (I/b + p_large) each, i.e. f b / (I + p_large b) before the
    final factor b (``pb`` = p_large b, ``scale`` = W H / N)."""
    pos_c = lum_c > 0
    a = dr.select(pos_c, dr.minimum(1.0, lum / dr.select(pos_c, lum_c, 1.0)), 1.0)
    w_c = dr.select(pos_c, (1.0 - a) * scale / (lum_c + pb), 0.0)
    w_p = dr.select(lum > 0, (a + dr.select(large, 1.0, 0.0)) * scale / (lum + pb), 0.0)
    return a, w_c, w_p


#: Metropolis steps per kernel at most (one symbolic loop over steps; the trace is reused)
STEPS_PER_KERNEL = 64


@record_once
def steps(evaluate, st: "ChainState", ids, count: int, image, scale, large_step: float,
          sigma: float):
    """``count`` Metropolis steps of the chains ``ids`` (UInt32, distinct) in ONE kernel: a
    Dr.Jit symbolic loop over the steps whose state is each chain's primary vector (a
    ``dr.Local`` of ``dims`` Floats per lane), contribution, importance and pixel.  Each step
    proposes (large step with probability ``large_step``, else Kelemen's small step of size
    ``sigma``), splats the current and the proposed state with weights 1 - a and a (times
    ``scale`` / I, Kelemen's weights) into the flat RGB ``image`` at their pixels (atomic adds
    inside the loop) and accepts with probability a = min(1, I'/I).  Large-step proposals are
    independent uniform samples: their I refine the estimate of b after the kernel (b in the
    weights is the estimate before it).  The step's random key is a hash of the run's key and
    the step's number, so the streams are those of ``count`` separate steps."""
    n = dr.width(ids)
    m = n * count                                   # mutations
    dims = st.dims
    base = st.steps
    st.steps += count
    key0 = dr.opaque(mi.UInt32, _key(st.key, base + 1))
    u = dr.alloc_local(mi.Float, dims)
    for d in range(dims):
        u[d] = dr.gather(mi.Float, st.u, ids * dims + d)
    pb = st.large_b(large_step)
    n_steps = dr.opaque(mi.UInt32, count)           # opaque: one compiled kernel for any count
    state = (mi.UInt32(0), u, dr.gather(mi.Float, st.lum, ids),
             dr.gather(mi.Color3f, st.rgb, ids), dr.gather(mi.UInt32, st.pix, ids),
             mi.Float(0.0), mi.UInt32(0), mi.Float(0.0))

    def cond(t, u, lum_c, rgb_c, pix_c, acc, nl, ls):
        return t < n_steps

    def body(t, u, lum_c, rgb_c, pix_c, acc, nl, ls):
        k = ps.hash32(key0 + t)                     # the step's key
        large = ps.large_steps(ids, k, large_step)
        pix, rgb, lum = evaluate(ps.primary_sampler(u, dims, ids, k, large, sigma, st.extra))
        a, w_c, w_p = kelemen_weights(lum, lum_c, large, scale, pb)
        splat(image, pix_c, rgb_c * w_c, w_c > 0)
        splat(image, pix, rgb * w_p, w_p > 0)
        accept = ps.uniform(ids, ps.stream(k, ps.STREAM_ACCEPT)) < a
        for d in range(dims):                       # the accepted chains take the proposal
            index = ids * dims + d
            prop = ps.propose(u[d], index, k, large, sigma)
            u[d] = dr.select(accept, prop, u[d])
        return (t + 1, u, dr.select(accept, lum, lum_c), dr.select(accept, rgb, rgb_c),
                dr.select(accept, pix, pix_c), acc + a, nl + dr.select(large, 1, 0),
                ls + dr.select(large, lum, 0.0))

    t, u, lum_c, rgb_c, pix_c, acc, nl, ls = dr.while_loop(state, cond, body,
                                                            label="pssmlt_steps")
    rows = [u[d] for d in range(dims)]
    dr.eval(rows, lum_c, rgb_c, pix_c, image, acc, nl, ls)   # the kernel (once: then reduce)
    acc_sum, n_large, large_sum = dr.sum(acc), dr.sum(nl), dr.sum(ls)
    for d in range(dims):
        dr.scatter(st.u, rows[d], ids * dims + d)
    dr.scatter(st.lum, lum_c, ids)
    dr.scatter(st.rgb, rgb_c, ids)
    dr.scatter(st.pix, pix_c, ids)
    dr.eval(st.u, st.lum, st.rgb, st.pix)
    st.accepted += _scalar(acc_sum)
    st.large += int(_scalar(n_large))
    st.lum_sum += _scalar(large_sum)
    st.lum_count += int(_scalar(n_large))
    st.mutations += m


def step(evaluate, st: "ChainState", ids, image, scale, large_step: float, sigma: float):
    """One Metropolis step of the chains ``ids`` (:func:`steps` with one step; with several
    splats per path, :func:`step_splats`)."""
    if isinstance(st.pix, list):
        step_splats(evaluate, st, ids, image, scale, large_step, sigma)
    else:
        steps(evaluate, st, ids, 1, image, scale, large_step, sigma)


def step_splats(evaluate, st: "ChainState", ids, image, scale, large_step: float,
                sigma: float):
    """One Metropolis step of the chains ``ids`` whose paths have several splats (``st.pix``
    and ``st.rgb`` are lists: estimator bdpt, whose light tracing splats at other pixels):
    the same proposal, acceptance, Kelemen weights and random streams as :func:`steps`, with
    I the sum of the splats' luminances and every splat of the current and the proposed
    path weighted alike.  The estimator runs kernels of its own (bdpt: the light subpaths,
    then the camera subpaths), so a step cannot be one iteration of a symbolic loop as in
    :func:`steps`: each step is traced and launched on its own (hence wide steps: many
    chains)."""
    n = dr.width(ids)
    dims = st.dims
    k = ps.hash32(dr.opaque(mi.UInt32, _key(st.key, st.steps + 1)))   # as steps() at t = 0
    st.steps += 1
    pb = st.large_b(large_step)
    large = ps.large_steps(ids, k, large_step)
    pix, rgb, lum = evaluate(ps.primary_sampler(st.u, dims, ids, k, large, sigma, st.extra))
    dr.eval(pix, rgb, lum)       # once: every use below would otherwise trace the walks again
    a, w_c, w_p = kelemen_weights(lum, dr.gather(mi.Float, st.lum, ids), large, scale, pb)
    for j in range(len(pix)):
        rgb_c = dr.gather(mi.Color3f, st.rgb[j], ids)
        splat(image, dr.gather(mi.UInt32, st.pix[j], ids), rgb_c * w_c,
              (w_c > 0) & dr.any(rgb_c != 0))
        splat(image, pix[j], rgb[j] * w_p, (w_p > 0) & dr.any(rgb[j] != 0))
    accept = ps.uniform(ids, ps.stream(k, ps.STREAM_ACCEPT)) < a
    flat = dr.arange(mi.UInt32, n * dims)
    row = flat // dims
    index = dr.gather(mi.UInt32, ids, row) * dims + (flat - row * dims)
    prop = ps.propose(dr.gather(mi.Float, st.u, index), index, k,
                      dr.gather(mi.Bool, large, row), sigma)
    take = dr.gather(mi.Bool, accept, row)
    sums = (dr.sum(a), dr.sum(dr.select(large, 1, 0)), dr.sum(dr.select(large, lum, 0.0)))
    dr.eval(image, prop, take, accept, sums)
    # the accepted chains take the proposal, in place (nothing else refers to the arrays
    # any more, so the scatters copy nothing)
    dr.scatter(st.u, prop, index, take)
    dr.scatter(st.lum, lum, ids, accept)
    for j in range(len(pix)):
        dr.scatter(st.pix[j], pix[j], ids, accept)
        dr.scatter(st.rgb[j], rgb[j], ids, accept)
    dr.eval(st.u, st.lum, st.pix, st.rgb)
    a_sum, n_large, large_sum = (_scalar(x) for x in sums)
    st.accepted += a_sum
    st.large += int(n_large)
    st.lum_sum += large_sum
    st.lum_count += int(n_large)
    st.mutations += n


def run(evaluate, st: "ChainState", mutations: int, image, scale, large_step: float,
        sigma: float):
    """``mutations`` steps of single chains: whole steps over every chain (up to
    ``STEPS_PER_KERNEL`` of them per kernel), then one over a rotating subset, so that every
    chain takes its share."""
    done = 0
    while done < mutations:
        whole = (mutations - done) // st.chains
        if whole and isinstance(st.pix, list):      # several splats: one step per kernel
            step(evaluate, st, dr.arange(mi.UInt32, st.chains), image, scale, large_step,
                 sigma)
            done += st.chains
            continue
        if whole:
            count = min(whole, STEPS_PER_KERNEL)
            steps(evaluate, st, dr.arange(mi.UInt32, st.chains), count, image, scale,
                  large_step, sigma)
            done += count * st.chains
            continue
        m = mutations - done
        # opaque offset and modulus: one compiled kernel whatever subset a pass starts at
        ids = (dr.arange(mi.UInt32, m) + dr.opaque(mi.UInt32, st.offset)) % \
            dr.opaque(mi.UInt32, st.chains)
        st.offset = (st.offset + m) % st.chains
        step(evaluate, st, ids, image, scale, large_step, sigma)
        done += m


def _scalar(x) -> float:
    return float(x[0]) if dr.width(x) else float(x)


def splat(image, pix, rgb, active):
    """Atomic adds of ``rgb`` into pixel ``pix`` of the flat RGB ``image``."""
    base = pix * 3
    dr.scatter_add(image, rgb[0], base, active)
    dr.scatter_add(image, rgb[1], base + 1, active)
    dr.scatter_add(image, rgb[2], base + 2, active)


#: camera rays per mutation for the emission seen directly or through delta scatterings
#: (estimator bdpt): a ray and a few delta bounces cost a small fraction of a bdpt mutation,
#: and the lamp behind glass that they render is a large part of some images
DELTA_RAYS = 4

#: chains of the bdpt estimator when ``chains`` is not given: its steps are one kernel each
#: (two with the light subpaths), so a step should be wide, but a chain must also take enough
#: steps to leave where it started: the chains start from the bootstrap resampled by I, so a
#: rare bright bootstrap path starts many chains, and with 65,536 chains a chain takes about 15
#: steps in an 8 s render of 64 x 64 pixels, too few to spread that blob.  Measured (64 x 64,
#: 8 s, 3 repeats, equal-time relMSE / path's, 65,536 | 16,384 | 4,096 chains): glass shades
#: 0.48 | 0.47 | 0.39 and 0.52 | 0.38 | 0.29, caustics 0.27 | 0.36 | 0.48 and 0.22 | 0.23 |
#: 0.28 (4,096 chains lose a third of the mutations to launches); 16,384 is the best worst case
BDPT_CHAINS = 1 << 14

#: importance_cap of the bdpt estimator when not given.  Its rare paths of very large I are
#: mostly fireflies of one strategy (a connection with a tiny MIS denominator), which a chain
#: never leaves in a render's time (acceptance ~ mean I / I per large step) and which the
#: bootstrap's resampling gives many chains: the image keeps the bootstrap's share of them, a
#: blob (measured: one pixel at 18x its value over 24 passes, 93 % of a render's relMSE).
#: Capped, they are sampled about as often as by bdpt itself and weighted up.  Measured (64 x
#: 64, 8 s, equal-time relMSE, uncapped | cap 8, mean over seeds): pssmlt_glass_shade 0.022 |
#: 0.011, pssmlt_caustic 0.023 | 0.013 (5 seeds), caustic 0.015 | 0.015 (5), glass_shade 0.020
#: | 0.021.  The path estimator's large I are the caustic paths it exists to explore: capped
#: at 8 its caustic errors double, so it keeps no cap.
BDPT_IMPORTANCE_CAP = 8.0

#: large-step probability of the bdpt estimator when ``large_step`` is not given: bdpt finds
#: the caustic and glass-shade paths by itself, so the chains gain more from its independent samples (large steps, each splatted with Kelemen's
#: weight) than from small steps, and a chain on a rare bright path leaves it sooner (after
#: about I / (mean I x large_step) steps).  Measured (64 x 64, 6 s, 3 repeats, medians,
#: equal-time relMSE / path's against a bdpt reference, large_step 0.3 | 0.45 | 0.6 | 0.8):
#: pssmlt_caustic 0.77 | 0.62 | 0.41 | 0.44, pssmlt_glass_shade 0.28 | 0.25 | 0.21 | 0.21,
#: caustic 0.38 | 0.28 | 0.48 | 0.19, glass_shade 0.71 | 0.61 | 0.53 | 0.48 (geometric means
#: 0.49 | 0.40 | 0.39 | 0.30); an earlier run of 2 repeats, 0.3 | 0.6 | 1.0: pssmlt_caustic
#: 0.52 | 0.29 | 0.34, glass_shade 0.74 | 0.53 | 0.61.
BDPT_LARGE_STEP = 0.8


def bdpt_dims(max_depth: int, bd_depth: int, choice_dims: int = 1) -> tuple:
    """Stored coordinates of the bdpt estimator: (camera subpath, light subpath).  Camera:
    the film position, then per vertex a light sample (3), a BSDF sample (3) and roulette
    (1), up to ``max_depth`` vertices (-1: unlimited); light: the start (5), then per vertex
    the connection to the camera (2), a BSDF sample (3) and roulette (1), up to
    ``bd_depth - 1`` (bdpt's D); at most MAX_STORED_VERTICES vertices each (fresh numbers
    past them); ``choice_dims``: the numbers a light sample's choice draws (ris: 2).  The
    light subpath's start chooses its light by power (bdpt), one number."""
    v_cam = ps.MAX_STORED_VERTICES if max_depth < 0 else min(max_depth,
                                                             ps.MAX_STORED_VERTICES)
    v_light = min(max(bd_depth - 1, 0), ps.MAX_STORED_VERTICES)
    return (2 + (ps.VERTEX_DIMS - 1 + choice_dims) * v_cam,
            (5 + 6 * v_light) if bd_depth >= 2 else 0)


class _Splats:
    """The light-tracing splats of a batch of paths, one slot per lane and light-vertex
    depth: pixel and RGB (zero where the connection failed).  Scattered to by the light
    walk's loop (kept out of its loop state), read after it."""

    def __init__(self, lanes: int, slots: int):
        size = max(lanes * slots, 1)
        self.pix = dr.zeros(mi.UInt32, size)
        self.rgb = [dr.zeros(mi.Float, size) for _ in range(3)]

    def put(self, index, uv, rgb, active, w: int, h: int):
        inside = active & (uv.x >= 0) & (uv.y >= 0) & (uv.x < w) & (uv.y < h)
        px = dr.minimum(mi.UInt32(dr.maximum(dr.floor(uv.x), 0.0)), w - 1)
        py = dr.minimum(mi.UInt32(dr.maximum(dr.floor(uv.y), 0.0)), h - 1)
        dr.scatter(self.pix, py * w + px, index, inside)
        for c in range(3):
            dr.scatter(self.rgb[c], dr.select(dr.isfinite(rgb[c]), rgb[c], 0.0), index, inside)

    def evaluate(self):
        dr.eval(self.pix, self.rgb)

    def get(self, index):
        rgb = mi.Color3f(*[dr.gather(mi.Float, c, index) for c in self.rgb])
        return dr.gather(mi.UInt32, self.pix, index), rgb

