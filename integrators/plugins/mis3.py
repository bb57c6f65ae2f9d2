r"""Integrator ``mis3``: the lecture's three-PDF one-sample MIS, at every vertex of a path.

Three techniques sample the integrand f L cos at a vertex x:

1. the **cosine lobe** p_1: ``BSDF.sample`` restricted to the BSDF's diffuse components,
2. the **glossy lobe** p_2: ``BSDF.sample`` restricted to its glossy components,
3. **light sampling** p_3: a light by ``light_selection``, a point on it, a shadow ray.

Technique probabilities p(1), p(2), p(3) come from ``selection`` (below), over the techniques
the vertex has (:mod:`integrators.sampling.techniques` splits any Mitsuba BSDF by its component
flags).

**Estimator.**  The integrand is split into the emitted part f L_e cos and the reflected part
f L_r cos.  At each vertex:

* with probability p(3) a light sample x_l is drawn (technique 3);
* **every path continues**: a lobe J in {1, 2} is drawn with probability
  pi_J = p(J) / (p(1) + p(2)) (the technique choice given that the path goes on; with p(3) = 0 it
  is the lecture's p(I) itself), and a direction omega ~ p_J.

Per vertex the effective densities are q_3 = p(3) p_3 and q_J = pi_J p_J: the expected number
of samples each technique contributes at x (the one-sample MIS of the lecture, with the light
technique's sample taken in addition to, not instead of, the continuation).  Then

* the light sample adds  f L_e G w_3(q_3, q_1, q_2) / (p(3) p_3(x_l));
* emission found by the continuation adds  f L_e cos w_J(q_3, q_1, q_2) / q_J(omega);
* the throughput becomes  beta f cos w'_J(q_1, q_2) / q_J(omega), w' the heuristic over the
  two lobe techniques (light sampling produces no continuation).

For every direction the weights of the techniques that can produce it sum to one (w_3 + w_1 +
w_2 = 1 for emission, w'_1 + w'_2 = 1 for the reflected part), so
E[contribution] = sum_k p(k-sample) E[w_k f / q_k] = integral of f: unbiased for **any**
technique probabilities, including ones learned from the render itself (tested with random
p-vectors).

**Delta lobes and null surfaces skip the choice.**  A vertex whose BSDF has a delta (specular)
or ``null`` component continues with the BSDF's own sample (``BSDF.sample`` over all its
lobes: the BSDF picks the delta part in proportion to its weight, e.g. Fresnel), so the delta
part is not divided by a technique probability; its smooth part then has the single density
q_b = p_bsdf(omega) against q_3.  A purely specular or null vertex draws no light sample.
Delta lights take weight 1.

**Technique probabilities** (``selection``):

* ``fixed``: (``p_cosine``, ``p_glossy``, ``p_light``) over the techniques the vertex has,
  normalised (a diffuse surface never draws from the glossy pdf; a scene without lights, or a
  vertex without a smooth lobe, never draws light samples);
* ``adaptive``: the cosine technique gets p_cosine a_d, the glossy one p_glossy (1 - a_d),
  a_d the diffuse albedo (``eval_diffuse_reflectance``, 1/2 when a BSDF does not report it), the
  light p_light; normalised.

With p(1) = p(2) = 0 (``p_light = 1``) the continuation is the BSDF's own sample.

* ``learned``: the BSDF's own sample continues every path (the shared path estimator of
  :mod:`integrators.sampling.vertex`) and a light sample is taken with a probability p(3)
  learned per region of the scene (:class:`~integrators.sampling.learning.RegionGrid`: position
  and normal octant) from the earlier passes of the same render.  Every light sample and every
  emission hit is weighted for the p(3) it was drawn with (effective light density p(3) p_l), so
  the image is unbiased for any table of probabilities.  What is learned: with the balance
  heuristic the second moment of a vertex's direct-light estimate is
  M(p) = int (f L_e)^2 / (p p_l + p_b); each light sample or emission hit adds
  (f L_e)^2 / ((p p_l + p_b) Q0) for every candidate p (Q0 the density it was drawn with), so all
  candidates are estimated from the same samples, and so is each technique's share of the mean
  (mu_l(p), mu_b(p)); between passes each region takes the candidate that makes the *image*
  most efficient (1 / (relMSE x time)): w_r (V(p) + V_rest) + (V / C) (1 + 0.5 p + C_rest)
  (a light sample costs about half a vertex; the argument below).  V(p) = M(p) - S_l(p) /
  max(p, 1) - mu_b^2 (:func:`allocation_variance`) is the vertex's noise: a region pools many
  points, and the variation of the mean between them is no noise that light samples could
  reduce.  S_l(p) =
  E[m_l(x; p)^2], the squared mean over the region's points of the light technique's share at
  a point (m_l(x; p) = int f L_e w_l(p)), is measured per candidate: the product of two
  independent light samples' weighted estimates at each recording vertex
  (:meth:`MIS3.record_pair`, two extra shadow rays on the recording vertices of the learning
  pass).  The BSDF technique's share keeps its pooled mean (its variation between points is
  counted as noise: estimated by light samples, it is heavy-tailed on glossy surfaces).
  History, side runs at 128 px and 512 spp against `path`: measuring the variation of the
  total m(x) and charging it to both shares in proportion took light samples away where a
  highlight's BSDF share varies most (veach_mis 1.28x; small_light 0.87x, furnace 0.88x); no
  correction at all gave light samples where the tiny light's share is exact at every point
  and only varies between points (veach_mis 1.39-1.45x, small_light 0.77-0.79x, furnace
  1.03-1.05x); the light share per candidate: veach_mis 1.41x, small_light 0.88x, furnace
  1.02x.  V_rest and C_rest, the rest of the pixel sample, are measured: each recording path
  is followed to its end and its estimate's square, mean and cost (rays plus
  0.5 per expected light sample) go to the cell of its first recording vertex; V_rest is their
  variance less the vertex's pooled variance at the allocation they were recorded with, C_rest
  their cost less the vertex's (until a region has 32 such paths: 0.3 V(1) and 0,
  ``LEARN_REST_VAR``).  A region keeps p = 1 unless a candidate below one promises 20 % less
  (above one no margin: the estimates of M(p) there are not heavy-tailed), and p(3) = 1 until
  the region has 64 recorded visits and 32 non-zero samples.  The
  candidates start at 0.05: the floor that keeps delta lights (which only light sampling
  reaches) and every other light reachable.
  **Candidates above one allocate light samples** (Sbert and Havran's variance-optimal sample
  allocation for MIS): an expected count n is rounded stochastically to m = floor(n) or
  ceil(n) light samples, averaged, each weighted at the effective density m p_l (the
  multi-sample MIS estimator given m, unbiased for every m >= 1), and emission found by the
  BSDF sample is weighted against m p_l; M(n) is estimated by the same formula.
  **The image's exchange rate** (the EARS argument, Rath et al. 2022, applied to the light
  samples): the image's relMSE per camera sample is V = mean over pixels of Var_p / (I_p^2 +
  eps) and its cost C per camera sample; a region visited f_r times per camera sample that
  changes its vertices' variance by dV and cost by dc changes V by f_r w_r dV and C by f_r dc
  (w_r the mean of 1 / (I_p^2 + eps) over its visits' pixels), and V C falls iff w_r dV +
  (V / C) dc < 0: every region trades variance against cost at the image's rate V / C.  The
  pixel sample's own (V(p) + V_rest) (cost + C_rest), the objective before, trades at that
  pixel sample's rate instead, so it spent light samples where a pixel's noise is small next
  to the image's (a bright highlight, whose relative error is small) and saved them where its
  other noise is large, though there the image's relMSE is (:class:`~integrators.sampling.
  learning.PixelStats`: veach_mis, the table keeping one light sample in 30 % of the visits
  where a uniform 4 was 1.2x as efficient).  The pixels are measured while learning: a
  first learning call spends half its learning share (``LEARN_PIXELS``) on the pixels' means
  before any vertex records, each recording visit then adds its pixel's weight, and the
  recording passes give V and C; V / C is taken as the new decisions will make it (their
  predicted change of V and C, ``LEARN_ROUNDS`` rounds of the fixed point).  Where the pixels
  are not known (a scalar variant, a wavefront Mitsuba did not lay out pixel by pixel, or a
  first call too small to measure them) the pixel sample's own objective stays.
  Every vertex of a recording pass records statistics (the recording code runs, masked, in
  every SIMD packet that has one recording lane, so a fraction saves nothing: 124 ms for a
  64-spp recording pass on veach_mis with a quarter of the vertices or all, 79 ms without
  records).  A render call that is still learning spends its first thirty-second of samples
  learning (a first call: half of it measuring the pixels), then, while the decisions still
  move, a recording pass of twice that with what it learned (``LEARN_MORE``), then renders the
  rest with what it learned (the first samples render at one light sample everywhere: the
  smaller their share, the less they weigh in the image); learning
  stops (the kernel drops its statistics) once a pass changes the decisions of less than 5 %
  of the visits.  Rendering in passes (``render --spp`` or ``--time``) keeps learning until
  then; a new scene starts from scratch (``reset_learning()`` forgets on request).
"""
from __future__ import annotations

import dataclasses
import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import any_flag, bsdf_at, bsdf_flags, channel_mean, depth_limit, is_jit, lnot, \
    luminance, record_once, safe_div, widen
from ..params import Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, mis, roulette
from ..sampling.learning import PixelStats, RegionGrid
from ..sampling.techniques import DELTA, DIFFUSE, GLOSSY, lobe_contexts
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate


SELECTIONS = ("fixed", "adaptive", "learned")
#: candidate light-sample allocations of selection=learned: a probability of one light sample
#: up to 1, an expected number of light samples above it (the smallest is the floor)
LEARNED_P = (0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, 1.0, 1.5, 2.0, 3.0, 4.0)
ONE = LEARNED_P.index(1.0)
#: cost of a light sample (shadow ray, light and BSDF evaluation) relative to a vertex without
#: one (measured: nee_path 0.089 s against bsdf_path 0.06 s per pass on veach_mis)
LIGHT_COST = 0.5
#: the vertex's own cost in vertex units (a ray), and the stand-ins for the rest of the pixel
#: sample where a region has fewer than LEARN_MIN_PATHS recorded paths: no cost, and a variance
#: of LEARN_REST_VAR times the vertex's at p(3) = 1.  History of the stand-in (before the rest
#: was measured): with the variance model of allocation_variance,
#: 0 allocates up to 4 light samples wherever they lower the vertex's variance (veach_mis 1.45x
#: `path`, but the Cornell box 0.68x and small_light 0.58x, whose noise is indirect or in the
#: camera's view of the light), 1 allocates too little for veach_mis (0.82x); 0.3 keeps every
#: experiment scene at 0.72x or more over two runs (geometric mean 1.04-1.08x, 1's 1.08x; one
#: or two runs each, within the noise of each other; benchmarks/results/mis3/variance)
LEARN_REST_COST = 1.0
LEARN_REST_VAR = 0.3
#: paths recorded in a region (at their first recording vertex) before their measured variance
#: and cost stand for the rest of the pixel sample (before: the LEARN_REST_* stand-ins)
LEARN_MIN_PATHS = 32
#: the statistics of a region: per candidate M(c), then the mean, visits and hits, then per
#: candidate mu_l(c) (``_learn``), then from PATH_STATS the recorded paths' second moment, mean,
#: cost and count (``record_path``), then from PAIRS per candidate the product of the pair of
#: light-share estimates (``record_pair``)
PATH_STATS = 2 * len(LEARNED_P) + 3
PAIRS = PATH_STATS + 4
#: the sum over a region's recording visits of their pixel's weight 1 / (I_p^2 + PIXEL_EPS),
#: and the number of those visits (the ones recorded once the pixels' means were known)
WEIGHT = PAIRS + len(LEARNED_P)
#: visits a region needs before its learned probability replaces the adaptive one
LEARN_MIN_VISITS = 64
#: non-zero light samples or emission hits a region needs before it leaves p(3) = 1
LEARN_MIN_HITS = 32
#: a render call of selection=learned that is still learning first renders this share of its
#: samples, learns from them, and renders the rest with what it learned.  Its samples render at
#: one light sample (its variance weighs share^2 / share = share in the image), so a small
#: share with more recording vertices per sample: veach_mis 1.29-1.32x `path` instead of
#: 1.15-1.18x (share 1/8, fraction 1/8), the other experiment scenes within the noise (side runs
#: at 128 px and 512 spp).  With the image's objective (LEARN_IMAGE), veach_mis against `path`
#: over 12 renders: 1/16 and one recording pass 1.53x, 1/32 and a second recording pass of
#: twice its size (LEARN_MORE 1) 1.59x, two more (1/32 + 1/16 + 1/8 in all) 1.55x
LEARN_SHARE = 1 / 32
#: fraction of the vertices of a recording pass that record statistics (all: a recording pass
#: costs the same with a quarter, see the docstring; before, a quarter)
LEARN_FRACTION = 1.0
#: a learned p(3) below 1 must promise at least this factor less variance x cost than p(3) = 1
#: (the estimates of small p(3) are heavy-tailed and read low more often than high; above one
#: the density grows and the estimates do not: no margin there)
LEARN_MARGIN = 0.8
#: learning stops once a pass changes the decisions of less than this fraction of the visits
LEARN_SETTLED = 0.05
#: whether the recording vertices measure the light share's squared mean between points
#: (``record_pair``; False: the pooled variance is taken as the vertex's noise, for comparison)
LEARN_PAIRS = True
#: whether the allocation weighs each region by its pixels' weight in the relMSE and trades
#: variance against cost at the image's rate (PixelStats; False: each pixel sample's own
#: variance x cost, as before, for comparison).  Side runs against `path` (128 px, 512 spp,
#: with the schedule of their time): veach_mis 1.24x -> 1.56x, small_light 0.95x -> 1.15x,
#: sharp_glossy 0.78x -> 0.83x, furnace 1.03x -> 1.75x, many_lights 5.5x -> 6.1x, the Cornell
#: box, specular_box, the caustic and the ajar door unchanged within the noise
#: (benchmarks/results/mis3/image_rate)
LEARN_IMAGE = True
#: the part of a first learning share that measures the pixels' means before any vertex
#: records (the recording vertices weigh what they see by their pixel's weight in the relMSE)
LEARN_PIXELS = 0.5
#: recording passes a learning call may add after its first (each twice the last, while the
#: decisions move), and the share of the call's samples they may take in all
LEARN_MORE = 1
LEARN_MORE_SHARE = 0.25
#: rounds of the fixed point between the decisions and the image's V / C they imply
LEARN_ROUNDS = 4


def allocation_variance(second, mean, mean_l, candidates=LEARNED_P, sq_l=None):
    r"""Variance of a vertex's direct-light estimate for each candidate allocation c, from the
    statistics of :meth:`MIS3._learn` (per region: rows; per candidate: columns).

    With the balance heuristic, c light samples (c <= 1: one, with probability c; c > 1 an
    integer) and the BSDF sample, the estimate is a sum of f / (c p_l + p_b) over the samples
    drawn, and

        V(c) = M(c) - mu_l(c)^2 / max(c, 1) - mu_b(c)^2,

    M(c) = int f^2 / (c p_l + p_b) (``second``), mu_l(c) = int f w_l (``mean_l``) and mu_b(c) =
    mu - mu_l(c) the two techniques' shares of the mean mu (``mean``) (for c > 1 the light
    part is the mean of c samples: its squared mean counts 1/c; for c <= 1 the light sample
    and the BSDF sample are independent, whose cross term cancels).  Subtracting mu^2 instead
    understates V by 2 mu_l mu_b + (1 - 1/c) mu_l^2, which is most of V once c > 1: every
    allocation above one then looked free of variance and the cheapest of them won.  A
    non-integer c > 1 is drawn as floor(c) or ceil(c) samples (``VertexEstimator.direct``),
    whose variances mix by the fraction of c.  With ``sq_l`` (per candidate E[m_l(x; c)^2],
    the light share's squared mean over the region's points, at least mu_l(c)^2) it replaces
    mu_l(c)^2: the variance is then the points' noise, without the variation of the light
    share's mean between them.  Clamped at zero (the three sums are estimates),
    plus a floor of 1e-6 of the mean second moment so that a region of zeros keeps its cost
    order."""
    second = np.asarray(second, dtype=np.float64)
    mean = np.asarray(mean, dtype=np.float64).reshape(-1, 1)
    mean_l = np.asarray(mean_l, dtype=np.float64)
    cand = [float(x) for x in candidates]
    c = np.maximum(np.array(cand), 1.0)[None, :]
    light = mean_l ** 2 if sq_l is None else np.maximum(np.asarray(sq_l, np.float64), mean_l ** 2)
    var = np.maximum(second - (light / c + (mean - mean_l) ** 2), 0.0)
    # a count c > 1 between integers is rounded to floor(c) or ceil(c) light samples, each
    # count's estimate unbiased: the variance is the mixture (1 - t) V(floor) + t V(ceil)
    for j, x in enumerate(cand):
        lo, hi = math.floor(x), math.ceil(x)
        if x > 1 and lo != hi and float(lo) in cand and float(hi) in cand:
            t = x - lo
            var[:, j] = (1 - t) * var[:, cand.index(float(lo))] + t * var[:, cand.index(float(hi))]
    return var + 1e-6 * second.mean(axis=1, keepdims=True)


def _prob(name, default, doc):
    return Param(name, "float", default, min=0.0, max=1.0, doc=doc)


@plugin("mis3", "integrator")
class MIS3(IntegratorTemplate):
    """One-sample MIS over a cosine lobe, a glossy lobe and light sampling, at every vertex."""

    PARAMS = (
        _prob("p_cosine", 1 / 3, "Weight of the cosine-lobe technique."),
        _prob("p_glossy", 1 / 3, "Weight of the glossy-lobe technique."),
        _prob("p_light", 1 / 3, "Weight of light sampling."),
        Param("selection", "choice", "learned", choices=SELECTIONS,
              doc="Technique probabilities: the fixed p-vector, adapted per vertex, or the "
                  "light-sample allocation learned per region from the render's own samples "
                  "(the default; `fixed` when a p-vector is given without `selection`)."),
        dataclasses.replace(mis.PARAMS[0], default="balance"), *mis.PARAMS[1:],
        dataclasses.replace(light_selection.PARAM, default="adaptive"),
        light_selection.CANDIDATES_PARAM,
        MAX_DEPTH, *roulette.RR_PARAMS, HIDE_EMITTERS,
    )

    def setup(self):
        p_given = sorted(self.given & {"p_cosine", "p_glossy", "p_light"})
        if p_given and "selection" not in self.given:   # the lecture's p-vector, as asked
            self.params["selection"] = self.selection = "fixed"
        elif p_given and self.selection == "learned":
            raise ParameterError(f"mis3: {', '.join(p_given)} given with selection='learned', "
                                 "which learns the light-sample allocation and uses no p-vector; "
                                 "allowed: selection='fixed' or 'adaptive' with a p-vector")
        total = self.p_cosine + self.p_glossy + self.p_light
        if not total > 0:
            raise ParameterError("mis3: p_cosine + p_glossy + p_light = 0; allowed: "
                                 "probabilities in [0, 1] with a positive sum")
        self.p_fixed = (self.p_cosine / total, self.p_glossy / total, self.p_light / total)
        self.heur = mis.Heuristic.from_params(self.params)
        self.lights = light_selection.SelectionCache.of(self)
        self.vertex = VertexEstimator(self.heur, 1, 1, roulette.Roulette.from_params(self.params))
        self.vertex.allocates = self.params["selection"] == "learned"
        self.learned = self.params["selection"] == "learned"
        self.grid = None
        #: set False to freeze what was learned (the table then stays as it is)
        self.learning = True
        #: true once a pass changed the decisions of less than LEARN_SETTLED of the visits:
        #: later passes record nothing (no statistics in the kernel: the cost of learning ends)
        self.settled = False
        self._quiet = False
        self._learn_passes = 0
        self._depth = 0
        #: per-pixel statistics of the render so far (:class:`PixelStats`; None: none yet)
        self.pixels = None
        self._collect = self._weigh = False
        self._pixel = None
        self._spp = 0
        #: camera samples of the recording passes so far (visits per camera sample, f_r)
        self._recorded = 0
        #: the objective the last learn() minimised (for the run record)
        self._objective = None

    # ---- selection=learned: the light-sample probability per region ------------------------
    def scene_warnings(self, scene):
        if self.learned:   # a new scene: learn from scratch
            self.grid = RegionGrid(scene, stats=WEIGHT + 2)
            self.pixels = None
            self._recorded = 0
            self._objective = None
            self.settled = False
            self._learn_passes = 0
        return []

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        """Mitsuba's render; with selection=learned, the pass's statistics then set the
        light-sample probability of every region for the next pass, and a render call that is
        still learning splits itself in passes (:meth:`_learning_call`): LEARN_SHARE of its
        samples first, learned from, then the rest (the spp-weighted mean of unbiased images,
        each pass with a seed of its own), so a single call already profits from what it
        learns."""
        if self.learned and develop and self._depth == 0:
            self.prepare(scene)
            if self.recording:
                sensor_obj = self._sensor(scene, sensor)
                total = int(spp) if spp else sensor_obj.sampler().sample_count()
                first = int(total * LEARN_SHARE)
                if first >= 1 and total - first >= 1:
                    img = None
                    for n, part in self._learning_call(scene, sensor, sensor_obj, int(seed),
                                                       total, first, evaluate):
                        img = part * (n / total) if img is None else img + part * (n / total)
                    return img
        return self._pass(scene, sensor, seed, spp, evaluate, develop)

    def _learning_call(self, scene, sensor, sensor_obj, seed, total, first, evaluate):
        """The passes of a render call that is still learning, [(spp, image)]: the pixels'
        means first where none are known (``LEARN_PIXELS`` of the learning share; a share of
        one sample: its recording pass measures them for the next call), a recording pass, up
        to ``LEARN_MORE`` more of twice the size while the decisions move, then the rest with
        what was learned."""
        px = None
        if is_jit() and LEARN_IMAGE:
            px = self.pixels = PixelStats.of(self.pixels, sensor_obj)
        parts = []

        def run(n, s, quiet, collect=True):
            # (pixels collected while the image's objective is on; the visits weighted by
            # their pixels once their means are known)
            self._quiet, self._collect = quiet, collect and px is not None
            self._weigh = px is not None and px.count > 0
            try:
                parts.append((n, self._pass(scene, sensor, s % 2 ** 32, n, evaluate)))
            finally:
                self._quiet = self._collect = self._weigh = False

        pre = int(first * LEARN_PIXELS) if px is not None and px.count == 0 else 0
        if pre:
            run(pre, seed + 3 * 2 ** 30, True)
        run(first - pre, seed, False)
        size, used = first - pre, first
        for extra in range(LEARN_MORE):
            size *= 2
            if not self.recording or used + size > total * LEARN_MORE_SHARE:
                break
            run(size, seed + (extra + 1) * 2 ** 28, False)
            used += size
        # the rest uses what was learned, records nothing
        run(total - used, seed + 2 ** 31, True, collect=False)
        return parts

    def reset_learning(self):
        """Forget what was learned (the next render learns from scratch; compiled kernels are
        kept): for experiments that time independent renders of one integrator."""
        if self.grid is not None:
            self.grid.reset()
        self.settled = False
        self._learn_passes = 0
        self.pixels = None
        self._recorded = 0
        self._objective = None

    def run_notes(self) -> dict:
        """For the run record: how the light-sample allocation was learned."""
        if not self.learned:
            return {}
        notes = {"selection": "learned", "recorded_passes": self._learn_passes,
                 "settled": self.settled, "learning": self.learning}
        if self.grid is not None:
            t = self.grid.table()
            t = t[t > 0]
            notes["regions_learned"] = int(t.size)
            if t.size:
                notes["allocation_quantiles_10_50_90"] = [round(float(q), 3) for q in
                                                          np.quantile(t, [0.1, 0.5, 0.9])]
        image = self.pixels.image() if self.pixels is not None else None
        # (what the regions' decisions minimised: see "The image's exchange rate")
        if self._objective is not None:
            notes["objective"] = self._objective
        if image is not None:
            notes["image_rel_variance_per_sample"] = round(image[0], 6)
            notes["cost_per_sample"] = round(image[1], 4)
        return notes

    @staticmethod
    def _sensor(scene, sensor):
        return scene.sensors()[sensor] if isinstance(sensor, int) else sensor

    def _pass(self, scene, sensor, seed, spp, evaluate=True, develop=True):
        """One call of Mitsuba's render, then (while learning) learn from its statistics."""
        self._depth += 1
        self._spp = int(spp)
        self._pixel = None
        recording = self.recording
        try:
            img = self.base_render(scene, sensor, seed, spp, develop, evaluate)
        finally:
            self._depth -= 1
        if self._pixel is not None and self._depth == 0:   # (the kernel collected)
            dr.eval(img)
            self.pixels.passed(spp, costed=recording)
        if recording and self._depth == 0:   # (the kernel recorded statistics)
            dr.eval(img)
            if is_jit():   # (the camera samples of every recording pass: f_r in learn)
                self._recorded += int(spp) * PixelStats.layout(self._sensor(scene, sensor))
            self.learn()
            self._learn_passes += 1
        return img

    @property
    def recording(self) -> bool:
        """Whether the next pass records statistics (read when the kernel is traced)."""
        return bool(self.learned and self.learning and not self.settled and
                    not self._quiet and self.grid is not None)

    def learn(self):
        """Per region, the candidate p(3) that minimises (variance of the direct-light estimate)
        x (cost of the vertex), from the statistics of every pass so far (see the docstring)."""
        k = len(LEARNED_P)
        old = self.grid.table()
        # the cells ever visited and their statistics (the others keep -1)
        live, st = self.grid.visited(k + 1)
        n = st[:, k + 1]
        # a region leaves p(3) = 1 only on enough visits and enough non-zero samples: the
        # second moments of small p are heavy-tailed and read low on a few samples
        ok = (n >= LEARN_MIN_VISITS) & (st[:, k + 2] >= LEARN_MIN_HITS)
        nn = np.where(ok, n, 1.0)[:, None]
        second, mean, mean_l = st[:, :k] / nn, st[:, k] / nn[:, 0], st[:, k + 3:PATH_STATS] / nn
        pooled = allocation_variance(second, mean, mean_l)
        sq_l = st[:, PAIRS:PAIRS + k] / nn if LEARN_PAIRS else None
        var = allocation_variance(second, mean, mean_l, sq_l=sq_l)
        cost = LEARN_REST_COST + LIGHT_COST * np.array(LEARNED_P)[None, :]
        # the rest of the pixel sample: the variance and cost of the paths through the region
        # less this vertex's share at the allocation they were recorded with (its nearest
        # candidate); where too few paths were recorded, the stand-ins LEARN_REST_*
        n_p = st[:, PATH_STATS + 3]
        have = n_p >= LEARN_MIN_PATHS
        npp = np.where(have, n_p, 1.0)
        v_pix = np.maximum(st[:, PATH_STATS] / npp - (st[:, PATH_STATS + 1] / npp) ** 2, 0.0)
        c_pix = st[:, PATH_STATS + 2] / npp
        now = old[live]
        u = np.argmin(np.abs(np.log(np.where(now > 0, now, 1.0))[:, None]
                             - np.log(np.array(LEARNED_P))[None, :]), axis=1)
        rows = np.arange(len(u))
        v_rest = np.where(have, np.maximum(v_pix - pooled[rows, u], 0.0),
                          LEARN_REST_VAR * var[:, ONE])
        c_rest = np.where(have, np.maximum(c_pix - cost[0, u], 0.0), 0.0)
        cand = np.array(LEARNED_P, dtype=np.float32)

        def choose(j):   # the candidate of least j, and one light sample kept by the margin
            arg = np.argmin(j, axis=1)
            below = cand[arg] < 1.0   # (the margin: see LEARN_MARGIN)
            keep_one = below & (j[rows, arg] > LEARN_MARGIN * j[:, ONE])
            return np.where(keep_one, ONE, arg)

        image = self.pixels.image() if self.pixels is not None else None
        weighed = st[:, WEIGHT + 1]
        if image is not None and weighed.sum() > 0:
            # the image's efficiency: each region's variance in relMSE units (its visits' mean
            # pixel weight) traded against cost at the image's rate V / C (PixelStats); V and
            # C as they will be under the new decisions (visits per camera sample f_r), a few
            # rounds of the fixed point
            v_img, c_img = image
            # (a region whose visits were all recorded before the pixels were known: the
            # mean weight of all weighed visits)
            w_r = np.where(weighed > 0, st[:, WEIGHT] / np.maximum(weighed, 1.0),
                           st[:, WEIGHT].sum() / weighed.sum())
            f_r = np.where(ok, n / (LEARN_FRACTION * max(self._recorded, 1)), 0.0)
            lam = v_img / c_img
            for r in range(LEARN_ROUNDS + 1):
                arg = choose(w_r[:, None] * (var + v_rest[:, None])
                             + lam * (cost + c_rest[:, None]))
                if r == LEARN_ROUNDS:
                    break
                dv = float(np.sum(f_r * w_r * (var[rows, arg] - var[rows, u])))
                dc = float(np.sum(f_r * LIGHT_COST * (cand[arg] - cand[u])))
                lam = max(v_img + dv, 0.1 * v_img) / max(c_img + dc, 0.1 * c_img)
            self._objective = "image relMSE x cost"
        else:
            arg = choose((var + v_rest[:, None]) * (cost + c_rest[:, None]))
            self._objective = "pixel sample variance x cost"
        best = cand[arg]
        table = np.full(len(old), -1.0, dtype=np.float32)
        table[live] = np.where(ok, best, -1.0)
        # settled: the decisions that changed carry less than LEARN_SETTLED of the visits
        def used(t):   # the p(3) a vertex uses (1 where nothing is learned yet)
            return np.log(np.where(t > 0, t, 1.0))
        changed = n[np.abs(used(table[live]) - used(now)) > 0.2].sum()
        # (and most visits are in regions that have learned: else more passes are needed)
        self.settled = bool(n.sum() > 0 and changed < LEARN_SETTLED * n.sum() and
                            n[ok].sum() >= 0.5 * n.sum())
        self.grid.set_table(table)

    # the learner interface of VertexEstimator.path
    def light_probability(self, si, sampler, active):
        """p(3) of the region of ``si`` (1 until the region has been learned), and where to
        record what this vertex finds: its cell, and whether this vertex is one of the
        fraction LEARN_FRACTION of vertices that record statistics (the choice uses only ratios
        of the statistics, so a random subset serves as well at a fraction of the cost)."""
        cell = self.grid.cell_of(si)
        record = None
        if self.recording:
            record = active & (sampler.next_1d(active) < LEARN_FRACTION)
            visit = {len(LEARNED_P) + 1: mi.Float(1.0)}
            if self._weigh and self._pixel is not None:
                # (and its pixel's weight in the relMSE, where the pixels' means are known)
                visit[WEIGHT] = dr.gather(mi.Float, self.pixels.weights(), self._pixel, record)
                visit[WEIGHT + 1] = mi.Float(1.0)
            self.grid.add(cell, visit, record)
        table = self.grid.lookup(cell, active)
        return dr.select(table > 0, table, 1.0), (cell, record)

    def record_light(self, cell, beta, d, p3):
        """Statistics of a light sample (value: luminance of beta f L_e, per unit of the light
        pdf for a delta light)."""
        if d.ls is None or cell[1] is None:
            return
        ls, (cell, record) = d.ls, cell
        value = luminance(beta * d.f_l * ls.weight * dr.select(ls.ds.delta, 1.0, ls.ds.pdf))
        # only the first of n > 1 light samples records: it stands for all n (factor n)
        self._learn(cell, value, ls.ds.pdf, p3, d.pdf_l, ls.ds.delta, ls.visible & record,
                    dr.maximum(p3, 1.0))

    def record_hit(self, cell, beta_weight, L_e, pdf_l, pdf_b, p3, active):
        """Statistics of emission found by the BSDF sample (beta_weight: beta f cos / p_b after
        the vertex's roulette, so that the survivors' values stand for the paths it ended)."""
        cell, record = cell
        if record is None:
            return
        value = luminance(beta_weight * pdf_b * L_e)
        self._learn(cell, value, pdf_l, p3, pdf_b, mi.Bool(False), active & record)

    def path_start(self, like):
        """The state that follows a path while recording (None otherwise): the cell of its
        first recording vertex, whether it has one, and its cost so far in vertex units (the
        camera ray: 1)."""
        if not self.recording:
            return None
        return (widen(mi.UInt32(0), like.x), widen(mi.Bool(False), like.x),
                widen(mi.Float(1.0), like.x))

    def path_vertex(self, track, cell, p3, active):
        """The path state after a vertex (its cost: a ray and p3 light samples)."""
        if track is None or cell[1] is None:
            return track
        (where, on, cost), (idx, record) = track, cell
        first = record & lnot(on)
        return (dr.select(first, idx, where), on | record,
                cost + dr.select(active, 1.0 + LIGHT_COST * p3, 0.0))

    def path_ray(self, track, active):
        """The path state after its roulette at a vertex (unchanged: the vertex's ray is in
        its cost)."""
        return track

    def record_path(self, track, L):
        """Statistics of a whole path (the luminance of its estimate, and its cost) in the
        cell of its first recording vertex: the variance and cost of the pixel sample."""
        if track is None:
            return
        where, on, cost = track
        if self._pixel is not None:
            self.pixels.add_cost(self._pixel, cost)
        value = luminance(L)
        self.grid.add(where, {PATH_STATS: value * value, PATH_STATS + 1: value,
                              PATH_STATS + 2: cost, PATH_STATS + 3: mi.Float(1.0)}, on)

    def record_pair(self, scene, sel, sampler, si, bsdf, cell, beta, active):
        """Two independent light samples at a recording vertex, for the statistics only: per
        candidate c, the product of their estimates of the light technique's share at this
        point, m_l(x; c) = int f L_e w_l(c) (w_l(c) = c p_l / (c p_l + p_b)), estimates its
        squared mean E_x[m_l(x; c)^2] over the region's points."""
        idx, record = cell
        if record is None or not LEARN_PAIRS:
            return
        act = active & record
        if not is_jit() and not act:
            return
        ctx = mi.BSDFContext()
        z = []
        for _ in range(2):
            ls = VertexEstimator.light_sample(scene, sel, sampler, si, act, bsdf, ctx)
            f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ls.ds.d), ls.visible)
            v = dr.select(ls.visible, luminance(beta * f * ls.weight), 0.0)
            z.append([v * w for w in self._light_shares(ls.ds.pdf, pdf_b, ls.ds.delta)])
        self.grid.add(idx, {PAIRS + j: z[0][j] * z[1][j] for j in range(len(LEARNED_P))}, act)

    def _learn(self, cell, value, pdf_l, p3, q_b, delta, active, count=1.0):
        # M(p) = int I^2 / (p p_l + q_b): each sample adds I^2 / ((p p_l + q_b) Q0), Q0 the
        # density it was drawn with (the balance combination of both techniques); for a
        # delta light, M(p) = A / p and a sample drawn with probability p3 adds I^2 / (p3 p)
        q0 = dr.select(delta, p3, p3 * pdf_l + q_b)
        inv_q0 = safe_div(count, q0)
        vals = [value * value * inv_q0 * dr.select(delta, 1.0 / p, safe_div(1.0, p * pdf_l + q_b))
                for p in LEARNED_P]
        vals += [value * inv_q0, mi.Float(0.0), mi.Float(1.0)]   # mean, (visits), hits
        # the light technique's share mu_l(p) = int I w_l(p)
        vals += [value * inv_q0 * w for w in self._light_shares(pdf_l, q_b, delta)]
        self.grid.add(cell, vals, active & (value > 0))

    @staticmethod
    def _light_shares(pdf_l, q_b, delta):
        """Per candidate p, the light technique's balance weight w_l(p) = p p_l / (p p_l + q_b)
        of a direction (1 for a delta light): its share of what the vertex estimates there."""
        return [dr.select(delta, 1.0, safe_div(p * pdf_l, p * pdf_l + q_b)) for p in LEARNED_P]

    def technique_probs(self, bsdf, si, has_lights: bool, active):
        """(p1, p2, p3) at this vertex, summing to one (zero where nothing is there)."""
        flags = bsdf_flags(bsdf)
        has_d = any_flag(flags, DIFFUSE)
        has_g = any_flag(flags, GLOSSY)
        smooth = mi.has_flag(flags, mi.BSDFFlags.Smooth)
        if self.params["selection"] == "fixed":
            # the fixed p-vector over the techniques this vertex has: a mirror, glass or null
            # surface samples its lobe with probability 1 and draws no light sample
            r1 = dr.select(has_d, self.p_fixed[0], 0.0)
            r2 = dr.select(has_g, self.p_fixed[1], 0.0)
            r3 = dr.select(smooth, self.p_fixed[2], 0.0) if has_lights else mi.Float(0.0)
            inv = safe_div(1.0, r1 + r2 + r3)
            return r1 * inv, r2 * inv, r3 * inv
        a_d = mi.Float(0.5)
        if bsdf is not None:
            a_d = channel_mean(bsdf.eval_diffuse_reflectance(si, active & has_d))
            a_d = dr.select(a_d > 0, dr.minimum(a_d, 1.0), 0.5)
        r1 = dr.select(has_d, self.p_cosine * a_d, 0.0)
        r2 = dr.select(has_g, self.p_glossy * dr.select(has_d, 1.0 - a_d, 1.0), 0.0)
        r3 = dr.select(smooth & has_lights, self.p_light, 0.0) if has_lights else mi.Float(0.0)
        inv = safe_div(1.0, r1 + r2 + r3)
        return r1 * inv, r2 * inv, r3 * inv

    @staticmethod
    def lobe_q(bsdf, si, wo, pi1, active, has_d: bool, has_g: bool):
        """Effective densities (pi_1 p_1, pi_2 p_2) of the lobe techniques for ``wo`` (no pdf
        call for a lobe no surface of the scene has)."""
        _, ctx_d, ctx_g = lobe_contexts()
        zero = mi.Float(0.0)
        # clamped: roughplastic's diffuse-only pdf is negative below the horizon (its cosine
        # is not clamped when one component is asked for), which would break the weights
        q_d = pi1 * dr.maximum(bsdf.pdf(ctx_d, si, wo, active), 0.0) if has_d else zero
        q_g = (1.0 - pi1) * dr.maximum(bsdf.pdf(ctx_g, si, wo, active), 0.0) if has_g else zero
        return q_d, q_g

    @staticmethod
    def continuation(bsdf, si, s1, s2, act, own, use_1, has_d: bool, has_g: bool,
                     maybe_own: bool):
        """The continuation's BSDF sample and the weight the BSDF gave it: the cosine lobe where
        ``use_1``, the BSDF's own sample where ``own``, else the glossy lobe (only the calls the
        scene can need).  The weight is used as f/pdf for ``own`` samples, and for every
        sample as the BSDF's verdict on it: a zero weight with a non-zero pdf (e.g.
        ``roughdielectric`` on the wrong side) is an invalid sample."""
        ctx, ctx_d, ctx_g = lobe_contexts()
        if not is_jit():    # one lane: one call
            ctx_j = ctx if own else (ctx_d if use_1 else ctx_g)
            return bsdf.sample(ctx_j, si, s1, s2, act)
        bs, w = dr.zeros(mi.BSDFSample3f), mi.Spectrum(0.0)
        if has_g:
            bs, w = bsdf.sample(ctx_g, si, s1, s2, act & lnot(own | use_1))
        if has_d:
            bs_d, w_d = bsdf.sample(ctx_d, si, s1, s2, act & use_1)
            bs, w = dr.select(use_1, bs_d, bs), dr.select(use_1, w_d, w)
        if maybe_own:
            bs_o, w_o = bsdf.sample(ctx, si, s1, s2, act & own)
            bs, w = dr.select(own, bs_o, bs), dr.select(own, w_o, w)
        return bs, w

    def sample(self, scene, sampler, ray, medium=None, active=True):
        if not self.learned:
            return self.sample_lobes(scene, sampler, ray, active)
        # selection=learned: the BSDF's own sample continues every path, and a light sample is
        # taken with the probability learned for the region (the shared path estimator)
        sel = self.prepare(scene)
        active = mi.Bool(active)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        active &= valid & (1 < depth_limit(self.max_depth))
        # while collecting pixel statistics, each lane's pixel (None: not laid out by pixel)
        self._pixel = self.pixels.pixel(sampler.wavefront_size(), self._spp) \
            if self._collect and is_jit() else None
        L += self.vertex.path(scene, sampler, sel, mi.Ray3f(ray), si, active, self.max_depth,
                              learner=self if sel.count > 0 else None)
        if self._pixel is not None:
            self.pixels.add(self._pixel, luminance(L))
        return L, valid, []

    @record_once
    @dr.syntax
    def sample_lobes(self, scene, sampler, ray, active):
        """selection=fixed|adaptive: the three techniques at every vertex (the docstring)."""
        ctx, ctx_d, ctx_g = lobe_contexts()
        vx = self.vertex
        sel = self.prepare(scene)
        # what the scene's surfaces have (Python ints): no sampling call for what none has
        has_d = bool(self.scene_flags & int(DIFFUSE))
        has_g = bool(self.scene_flags & int(mi.BSDFFlags.Glossy))
        maybe_own = bool(self.scene_flags & int(DELTA)) or \
            min(self.p_cosine, self.p_glossy) == 0 or not (has_d or has_g)
        has_lights = sel.count > 0
        max_depth = depth_limit(self.max_depth)
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        active = active & valid & (1 < max_depth)

        while dr.hint(active, label="mis3", exclude=[max_depth]):
            bsdf = bsdf_at(si, ray, active)
            p1, p2, p3 = self.technique_probs(bsdf, si, has_lights, active)
            # the BSDF's own sample where it has a delta or null part (or no lobe technique has
            # a probability, p_light = 1), else the chosen lobe
            own = active & (any_flag(bsdf_flags(bsdf), DELTA) | (p1 + p2 <= 0))
            pi1 = safe_div(p1, p1 + p2)

            # ---- technique 3: a light sample, with probability p(3) ----
            norm = None   # the light selection's normaliser at si, reused for the emission
            use_l = active & (sampler.next_1d(active) < p3)
            if is_jit() or (use_l and has_lights):
                ls = vx.light_sample(scene, sel, sampler, si, use_l, bsdf, ctx)
                norm = ls.norm
                wo = si.to_local(ls.ds.d)
                f, pdf_own = bsdf.eval_pdf(ctx, si, wo, ls.visible)
                q_d, q_g = self.lobe_q(bsdf, si, wo, pi1, ls.visible & lnot(own), has_d, has_g)
                q_b = [dr.select(own, pdf_own, q_d), dr.select(own, 0.0, q_g)]
                L += beta * safe_div(vx.light_term(ls, f, q_b, light_scale=p3), p3)
            else:
                sampler.next_1d()
                sampler.next_2d()

            # ---- the continuation: a lobe J with probability pi_J (or the BSDF's own) ----
            use_1 = lnot(own) & (sampler.next_1d(active) < pi1)
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            act = mi.Bool(active)
            if is_jit() or act:
                bs, w_own = self.continuation(bsdf, si, s1, s2, act, own, use_1, has_d, has_g,
                                              maybe_own)
                delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                act &= (bs.pdf > 0) & dr.any(w_own != 0)
                smooth_b = act & lnot(delta)
                f = bsdf.eval(ctx, si, bs.wo, smooth_b & lnot(own))
                q_d, q_g = self.lobe_q(bsdf, si, bs.wo, pi1, smooth_b & lnot(own), has_d, has_g)
                q_b = [dr.select(own, bs.pdf, q_d), dr.select(own, 0.0, q_g)]
                first = own | use_1                       # which entry of q_b sampled omega
                # f cos / q_J (the BSDF's own weight for its own sample) and w'_J
                w_lobe = self.heur.weights(q_b)
                base = dr.select(own, w_own, safe_div(f, dr.select(use_1, q_b[0], q_b[1])))
                w_cont = dr.select(own, 1.0, dr.select(use_1, w_lobe[0], w_lobe[1]))
                ray_b = si.spawn_ray(si.to_world(bs.wo))
                si_b = scene.ray_intersect(ray_b, act)
                # emission: weighted over q_3 and the continuation's densities
                L_e = vx.emission(scene, sel, si, si_b, q_b, delta, act, norm, index=first,
                                  light_scale=p3)
                L += dr.select(act, beta * base * L_e, 0.0)
                beta = dr.select(act, beta * base * w_cont, 0.0)
                eta *= bs.eta
                ray = ray_b
                si = si_b
            depth += 1
            active = act
            beta, active = vx.roulette(beta, eta, depth, sampler, active)
            active &= si.is_valid() & (depth + 1 < max_depth)
        return L, valid, []
