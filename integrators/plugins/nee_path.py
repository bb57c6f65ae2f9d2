r"""Integrator ``nee_path``: path tracing with next-event estimation and MIS at every vertex.

The lecture's estimator with each degree of freedom of its last slide as a parameter:

    L = L_e(x_0) + sum_k beta_k [ NEE(x_k) + w_b(x_{k+1}) L_e(x_{k+1}) ],  beta_{k+1} = beta_k f cos / p

* **PDFs at each vertex**: one BSDF sample continues the path; ``light_samples`` shadow rays
  estimate the direct light (splitting of the light estimate), combined by ``heuristic``
  (``beta``, ``alpha``) exactly as in ``direct_mis`` (:mod:`integrators.nee`).  Delta lights and
  delta lobes take weight 1.  Vertices without a smooth lobe cast no shadow rays.
* **Light selection**: ``light_selection`` = ``uniform`` | ``power`` | ``adaptive`` | ``bvh`` |
  ``ris`` (:mod:`integrators.sampling.light_selection`).
* **Path length**: ``max_depth`` (-1 unlimited), Russian roulette from ``rr_depth`` with
  ``rr`` = ``none`` | ``fixed`` (terminate with probability ``rr_prob``, survivors divided by
  1 - rr_prob) | ``throughput`` (survive with min(max(beta) eta^2, 0.95), as Mitsuba's ``path``
  and pbrt).  All three are unbiased.
* **Splitting**: ``split`` = k independent continuations from each camera ray's first hit, each
  weighted 1/k; the camera ray, the first intersection and its emission are paid once.  The
  integrator traces ``split`` paths per camera sample (``paths_per_sample``), which cost
  comparisons must count.

* **Efficiency-aware roulette and splitting** (``rr=adaptive``, EARS: Rath et al. 2022): at
  every vertex a factor n(x) in [``rr_min``, ``split_max``], learned per region from the earlier
  passes of the same render, decides how many copies continue the path (n < 1: roulette with
  survival n; n > 1: floor(n) or ceil(n) copies, each weighted 1/n).  With ``always`` the
  first ``split_depth`` vertices split: the first hit's copies one after another in the lane
  of the same kernel (``split_depth`` 1, the default), deeper splits as new lanes of a
  wavefront (:mod:`integrators.sampling.splitting`), at most ``max_lanes`` alive at once; with
  ``never`` n is clamped to one, roulette only, every path in one kernel; ``measured`` times a
  pass of each and keeps the faster to a given error.  ``render`` is then
  this integrator's own (JIT variants only), the learned state is kept per scene across
  passes, and ``stats`` counts the rays it traced.  ``split`` must be 1 then.  Every learning
  roulette pass also estimates, on its own paths, the throughput rule's variance and cost
  (under ``never`` and ``auto`` the classic passes go on until the pixels hold 4 samples, whose
  variance the factors need, and the first roulette pass's estimate decides); where the
  learned roulette is not worth 1.3x the plain kernel's time per unit of work, the
  render goes on with ``nee_path``'s own kernel and the throughput rule (``stats['mode']`` =
  ``plain``, rays not counted); under ``auto`` its first plain pass (or the ``bound`` part
  that sent it plain) takes two copies of the first hit on its first two camera samples per
  pixel and measures how much of the image's variance they average, and the plain passes
  after it take the copies (``split``, up to ``split_max``) of highest predicted efficiency
  where that is 1.3x one copy's (``stats['copies']``).  By default
  (``split_policy=auto``) a split pass follows the roulette pass where it gained enough, and
  estimates on its first copies what the roulette would have given; the render splits while
  splitting pays, else goes on with roulette only, or plain.  While it learns, a render call is
  rendered in parts of doubling size (1/16, 1/16, 1/8, 1/4 of its samples, then the rest;
  ``stats['parts']``), learning between them, so a mode decided on one part (the plain kernel
  included) renders the rest of the call, where the samples left are worth a part's measured
  fixed cost; learning stops once the regions hold enough samples (``settled`` in the run
  record).

With ``heuristic=power, light_selection=uniform, rr=throughput, light_samples=1, split=1`` this is
the estimator of Mitsuba's built-in ``path`` (tested statistically on the Cornell box).
"""
from __future__ import annotations

import contextlib
import dataclasses
import time

import drjit as dr
import mitsuba as mi

from ..common import depth_limit, is_jit, luminance, record_once, widen
from ..params import MAX_COUNT, Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, mis, roulette, splitting
from ..sampling.learning import film_shape, sensor_view
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate


@plugin("nee_path", "integrator")
class NEEPath(IntegratorTemplate):
    """Path tracing with next-event estimation, MIS, light selection, Russian roulette, splitting."""

    PARAMS = (
        MAX_DEPTH, roulette.RR_PARAMS[0],
        dataclasses.replace(roulette.RR_PARAMS[1], choices=(*roulette.RR_MODES, "adaptive"),
                            doc="Russian roulette: none, fixed termination probability, from the "
                                "throughput, or adaptive (EARS: roulette and splitting at every "
                                "vertex, learned per region)."),
        *roulette.RR_PARAMS[2:],
        Param("rr_min", "float", 0.1, min=0.001, max=1.0,
              doc="rr=adaptive: smallest survival probability of a vertex."),
        Param("split_max", "int", 4, min=1, max=64,
              doc="rr=adaptive: largest number of copies a vertex splits into."),
        Param("split_depth", "int", 1, min=1, max=64,
              doc="rr=adaptive: vertices from the first hit where a path may split (1: the "
                  "first hit's copies one after another in one kernel; more: by path "
                  "replication, not with split_policy=auto); deeper ones use roulette only."),
        Param("split_policy", "choice", "auto", choices=splitting.POLICIES,
              doc="rr=adaptive: never (learned roulette only, every path in one kernel), "
                  "always (learned splitting at the first split_depth vertices), measured "
                  "(one pass of each, then the more efficient as timed in the render), auto "
                  "(a split pass estimates the roulette on its own paths; splitting kept "
                  "while it pays)."),
        Param("max_lanes", "int", 1 << 20, min=1 << 10, max=1 << 26,
              doc="rr=adaptive: paths alive at once (bounds memory; split factors are scaled "
                  "down where a bounce would pass it)."),
        dataclasses.replace(mis.PARAMS[0], default="power"), *mis.PARAMS[1:],
        light_selection.PARAM, light_selection.CANDIDATES_PARAM,
        Param("light_samples", "int", 1, min=0, max=MAX_COUNT,
              doc="Shadow rays per vertex (NEE splitting; strata of one sample: stratified "
                  "over the lights and their surfaces)."),
        Param("split", "int", 1, min=1, max=MAX_COUNT, doc="Independent continuations from the first hit."),
        HIDE_EMITTERS,
    )

    def setup(self):
        self.heur = mis.Heuristic.from_params(self.params)
        self.lights = light_selection.SelectionCache.of(self)
        self.adaptive = self.rr == "adaptive"
        rr = dict(self.params, rr="none") if self.adaptive else self.params
        self.vertex = VertexEstimator(self.heur, self.light_samples, 1,
                                      roulette.Roulette.from_params(rr))
        #: rr=adaptive's ``plain`` passes (the learned roulette predicted not to pay): the
        #: throughput rule in Mitsuba's megakernel
        self.plain_vertex = VertexEstimator(
            self.heur, self.light_samples, 1,
            roulette.Roulette.from_params(dict(self.params, rr="throughput")))
        self.paths_per_sample = self.split
        self.ears = None
        #: tests: a rule (sampler, active) -> n replacing the learned n at every vertex
        #: (:func:`~integrators.sampling.splitting.random_factors`), None: learned
        self.forced_factor = None
        #: what the last rr=adaptive render traced (rays, camera samples, lanes)
        self.stats = {}
        self._plain_call = False
        if self.adaptive:
            if self.split != 1:
                raise ParameterError(f"nee_path: parameter 'split' = {self.split!r} is invalid "
                                     "with rr=adaptive; allowed: 1 (rr=adaptive splits at every "
                                     "vertex by itself)")
            if self.split_policy == "auto" and self.split_depth != 1:
                raise ParameterError(f"nee_path: parameter 'split_depth' = {self.split_depth!r} "
                                     "is invalid with split_policy=auto (the default); "
                                     "allowed: 1, or split_policy always, never or measured "
                                     "(auto estimates the roulette on the first hit's copies, "
                                     "which run in one kernel only with split_depth 1)")
            if not is_jit():
                raise ParameterError(f"nee_path: rr = 'adaptive' needs a JIT variant (llvm_*, "
                                     f"cuda_*), the active variant is {mi.variant()}: its path "
                                     "replication is a wavefront over Dr.Jit arrays")

    def scene_warnings(self, scene):
        if self.adaptive:    # a new scene: learn from scratch
            self.ears = splitting.EARS(scene, self.rr_min, self.split_max, self.rr_depth,
                                       self.split_depth, self.split_policy, self.max_depth)
        return []

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        """Mitsuba's render; with rr=adaptive the wavefront of
        :mod:`integrators.sampling.splitting` (path replication), which then learns from the
        pass for the next one."""
        if not self.adaptive:
            return self.base_render(scene, sensor, seed, spp, develop, evaluate)
        self.prepare(scene)
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        spp = int(spp) if spp else int(sensor.sampler().sample_count())
        film = sensor.film()
        film.prepare([])
        self.ears.forced = self.forced_factor
        if self.ears.mode != "plain":       # (a new film or view: its pixels measured first)
            self.ears.film(film_shape(film), sensor_view(sensor))
        if self.forced_factor is not None:      # (tests: factors given, no mode to learn)
            self.ears.mode = self.ears.next_mode()
        # (the plain mode: Mitsuba's kernel, no rays counted; the copy trial needs 2 spp)
        if self.ears.mode == "plain" and not (self.ears.copy_trial and spp >= 2):
            # (Mitsuba's render calls this one again, once: a pass counted at the outer call)
            outer = not self._plain_call
            if outer:
                self.ears.passes += 1
                self.stats = dict(mode="plain", max_lanes=0, copies=self.ears.copies)
            self._plain_call = True
            try:
                return self.base_render(scene, sensor, seed, spp, develop, evaluate)
            finally:
                self._plain_call = not outer
        self.ears.passes += 1
        # (the pass's time: only the measured policy uses it)
        timed = self.split_policy == "measured"
        block, stats = None, {}
        # (while learning, a call is rendered in parts of doubling size, learning between them:
        # splitting.EARS.part; a part in the plain mode runs this integrator's own kernel)
        # (a deciding part is timed: its fixed cost decides whether another part pays)
        done, k = 0, 0
        while done < spp:
            part = self.ears.part(spp, done, k)
            wave = splitting.Wavefront(self, self.ears, self.max_lanes)
            mode = self.ears.mode
            sub_seed = int(seed) if k == 0 else splitting.seed_mix(int(seed), k, 0x5B)
            clock = timed or self.ears.deciding
            with splitting.pass_clock() if clock else contextlib.nullcontext([0.0]) as seconds:
                block = wave.render(scene, sensor, sub_seed, part, block)
            t0 = time.perf_counter()
            if mode == "bound":     # (the plain kernel, its costs bounding learning's gain)
                self.ears.measure_bound(part, wave.trial)
            elif self.ears.learning and mode != "plain":
                self.ears.learn(part, seconds[0] if timed else 0.0)
            elif wave.trial:
                self.ears.measure_copies(part)
            if clock and seconds[1] is not None:
                self.ears.part_cost = (seconds[1] + time.perf_counter() - t0, seconds[2] / part)
            done, k = done + part, k + 1
            for key, v in wave.stats.items():     # (largest or summed over the parts)
                if key in ("max_lanes", "bounces"):
                    stats[key] = max(stats.get(key, 0), v)
                else:
                    stats[key] = stats.get(key, 0) + v
            stats.setdefault("parts", []).append((mode, part))
        self.stats = dict(stats, mode=mode)
        if mode == "plain":
            self.stats["copies"] = self.ears.copies
        film.put_block(block)
        return film.develop() if develop else block.tensor()

    def run_notes(self) -> dict:
        """For the run record (rr=adaptive): the passes, the mode they now run in and the
        learned roulette's efficiency against the throughput rule as a roulette pass estimated
        it (what sent the render to the plain kernel, or kept it learning; before it, a
        classic pass's estimate of the young table at its best scale, which may send the
        render plain first), and splitting's
        against the roulette as a split pass estimated it (``auto``: what kept or ended it);
        in the plain mode the first hit's copies per camera sample."""
        if not self.adaptive or self.ears is None:
            return {}
        e = self.ears
        notes = {"rr": "adaptive", "passes": e.passes, "mode": e.mode, "settled": e.settled}
        if e.gain is not None:
            notes["estimated_gain_over_throughput_rule"] = round(float(e.gain), 3)
        if e.young_gain is not None:    # (a classic pass's, the young table's best scale)
            notes["estimated_gain_young_table"] = {"gain": round(float(e.young_gain), 3),
                                                   "scale": e.gain_scale}
        if e.gain_bound is not None:    # (a bound part's bound on it, EARS.bound_gain)
            notes["gain_bound"] = round(float(e.gain_bound), 3)
        if e.split_gain is not None:
            notes["estimated_gain_of_splitting_over_roulette"] = round(float(e.split_gain), 3)
        if e.mode == "plain":       # (the copies of the first hit the copy trial chose)
            notes["plain_copies"] = e.copies
        return notes

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """One camera sample (rr=adaptive renders through :meth:`render` instead, except in its
        ``plain`` passes, which come here: the throughput rule, with the copies of the first
        hit its EARS state chose)."""
        copies = self.ears.copies if self.adaptive and self.ears is not None else self.split
        L, valid, _ = self.sample_copies(scene, sampler, ray, copies, active)
        return L, valid, []

    @record_once
    @dr.syntax
    def sample_copies(self, scene, sampler, ray, copies, active=True, learner=None):
        """One camera sample with ``copies`` copies of the first hit's reflected light (its
        light samples and continuation), each weighted 1/copies: (L, valid, half), half the
        difference of the first two copies' luminance where copies >= 2 (whose variance given
        the camera sample is that of the mean of two copies; 0 on lanes of one copy), else
        None.  ``copies``: a count, or one per lane (``UInt32``: the copy trial's lanes).
        ``learner``: the paths' learner (:meth:`VertexEstimator.path`; every copy's path)."""
        active = mi.Bool(active)
        ray = mi.Ray3f(ray)
        sel = self.prepare(scene)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        active = active & valid & (1 < depth_limit(self.max_depth))
        half = None
        single = isinstance(copies, int) and copies == 1
        if dr.hint(single, mode="scalar"):
            L += self.reflected(scene, sampler, sel, ray, si, active, learner)
        else:
            acc = mi.Spectrum(0.0)
            diff = widen(mi.Float(0.0), ray.o.x)
            k = mi.UInt32(0)
            # (the count and weight opaque: one kernel for every count)
            if dr.hint(isinstance(copies, int), mode="scalar"):
                count = dr.opaque(mi.UInt32, copies)
                weight = dr.opaque(mi.Float, roulette.split_weight(copies))
            else:
                count = mi.UInt32(copies)
                weight = roulette.split_weight(mi.Float(count))
            while dr.hint(k < count, label="nee_path split", exclude=[ray, si, active, count]):
                r = self.reflected(scene, sampler, sel, ray, si, active, learner)
                acc += r
                y = luminance(r)
                diff += dr.select(k == 0, y, dr.select(k == 1, -y, 0.0))
                k += 1
            L += acc * weight
            half = dr.select(count >= 2, 0.5 * diff, 0.0)
        return L, valid, half

    def reflected(self, scene, sampler, sel, ray, si, active, learner=None):
        """One path's estimate of the light reflected at the first hit ``si`` (its emission
        excluded): the shared per-vertex estimator at every vertex (``learner``: its learner,
        :meth:`VertexEstimator.path`)."""
        vertex = self.plain_vertex if self.adaptive else self.vertex
        return vertex.path(scene, sampler, sel, ray, si, active, self.max_depth, learner)
