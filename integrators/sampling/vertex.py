r"""The per-vertex estimator: what every integrator computes at a surface interaction.

At a vertex x with throughput beta, a path-tracing estimator with light sampling does four things
(the role of pbrt-v4's ``SampleLd`` with its emission weighting, or Tungsten's ``TraceBase``):

1. **Light samples** (``N_l`` of them): a light k picked by the light selection with p(k), a
   point on it, a shadow ray, and the MIS-weighted estimate

       1/N_l sum_j w_l(omega_j) f(omega_j) L_e G / (p(k_j) p_{k_j}(x_j)),

   :meth:`VertexEstimator.light_estimate` (:meth:`light_sample` + :meth:`light_weight`).
   The N_l samples are strata of one (:meth:`VertexEstimator.stratum`: the light choice's
   uniform rotated by j/N_l, the point sample by j steps of the R2 sequence), so they spread
   over the lights and over each light's surface; each is still distributed as a single light
   sample, which is all the multi-sample MIS estimator needs to stay unbiased.
2. **A BSDF sample** omega_b with f cos / p_b: it continues the path (``nee_path``, ``mis3``)
   or only looks for emission (``direct_mis``).  With one light sample, the BSDF is evaluated for
   the light direction and sampled in one call (``eval_pdf_sample``, as Mitsuba's ``path`` does):
   :meth:`VertexEstimator.direct`.
3. **Emission found by the BSDF sample**, with the weight w_b(omega_b) over the densities of
   every technique that can produce omega_b (:meth:`VertexEstimator.emission`): the light
   technique's density is p(k) p_k(omega_b) from the selection at x, so the two weights sum to one
   wherever both techniques can produce a direction.
4. **Russian roulette** on the new throughput (:mod:`integrators.sampling.roulette`).

Densities are *effective* densities q = (number of samples or technique probability) x pdf, so
the same code serves the multi-sample estimator (q_l = N_l p_l, q_b = N_b p_b) and the one-sample
estimator of ``mis3`` (q_I = p(I) p_I over three techniques, ``light_scale`` = p(3), two BSDF
densities).  Delta lights are reachable only by light sampling and delta lobes only by BSDF
sampling: both take weight 1.  Vertices without a smooth lobe cast no shadow rays.
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import drjit as dr
import mitsuba as mi

from ..common import (bsdf_at, bsdf_flags, depth_limit, emitted, is_jit, lnot, record_once,
                      safe_div, widen)
from .light_selection import rotated_2d
from .mis import Heuristic
from .roulette import Roulette


class Direct(NamedTuple):
    """What :meth:`VertexEstimator.direct` computes at a vertex."""
    L: "mi.Spectrum"             # the light-sample estimate (MIS-weighted)
    bs: "mi.BSDFSample3f"        # the BSDF sample
    weight: "mi.Spectrum"        # its f cos / p_b
    norm: object                 # the light selection's normaliser, for emission()
    ls: "LightSample | None"     # the light sample (N_l = 1)
    f_l: "mi.Spectrum | None"    # f cos of the light sample's direction (N_l = 1)
    pdf_l: "mi.Float | None"     # the BSDF's pdf of that direction (N_l = 1)
    light_scale: object = None   # with p_light: the light technique's sample count/probability


class LightSample(NamedTuple):
    ds: "mi.DirectionSample3f"   # ds.pdf = p(k) p_k(omega); ds.delta for delta lights
    weight: "mi.Spectrum"        # L_e G / (p(k) p_k), no visibility
    visible: "mi.Bool"           # lanes whose sample is unoccluded and non-zero
    norm: object                 # the selection's normaliser at x (see light_selection)
    samples: tuple = None        # (choice sample, point sample) it was drawn from


def no_bsdf_sample():
    """(BSDFSample, weight) of a lane without a surface (scalar variants)."""
    return dr.zeros(mi.BSDFSample3f), mi.Spectrum(0.0)


class VertexEstimator:
    """Light samples, the BSDF sample, the emission weight and roulette at one vertex.

    ``heur``: the MIS heuristic; ``n_l``: light samples per vertex (0: no light sampling);
    ``n_b``: BSDF samples whose densities enter the weights (1 for a path's continuation);
    ``roulette``: the path's Russian roulette (None: none)."""

    def __init__(self, heur: Heuristic, n_l: int = 1, n_b: int = 1,
                 roulette: Roulette | None = None):
        self.heur, self.n_l, self.n_b = heur, int(n_l), int(n_b)
        self.rr = roulette or Roulette("none")
        #: whether a per-lane ``p_light`` of :meth:`direct` may exceed one (an expected number
        #: of light samples; set by an integrator that allocates them)
        self.allocates = False

    # ---- 1. light samples -----------------------------------------------------------------
    @staticmethod
    def light_sample(scene, sel, sampler, si, active, bsdf=None, ctx=None,
                     samples=None) -> LightSample:
        """One light sample at ``si`` with its shadow ray (``bsdf`` and ``ctx``: the BSDF the
        sample will be evaluated with, for a selection that resamples by the unshadowed
        contribution; ``samples``: its (choice, point) uniforms, drawn from ``sampler`` if
        not given)."""
        if samples is None:
            samples = (sel.sample_1d(sampler, active), sampler.next_2d(active))
        s1, s2 = samples
        ds, em_weight, norm = sel.sample_direction(si, s1, s2, active, bsdf=bsdf, ctx=ctx)
        act = active & dr.any(em_weight != 0)
        act &= lnot(scene.ray_test(si.spawn_ray_to(ds.p), act))
        return LightSample(ds, em_weight, act, norm, samples)

    #: whether the light samples of one vertex are strata of the first one's uniforms
    #: (:meth:`stratum`; False: independent draws from the sampler, for comparison)
    STRATIFY = True

    def stratum(self, sel, sampler, samples, k, m, active=True):
        """The uniforms of light sample k of m at a vertex from those of sample 0: the choice
        sample rotated by the selection (:meth:`LightSelection.stratum`), the point sample by k
        steps of the R2 sequence.  Each sample is still distributed as a single one (so the
        m-sample MIS estimator stays unbiased), and the m together are stratified over the
        lights and over each light's surface: **stratified next-event estimation** at no
        cost, where m independent samples would often pick the same light twice."""
        if not self.STRATIFY:
            return sel.sample_1d(sampler, active), sampler.next_2d(active)
        return sel.stratum(samples[0], k, m), rotated_2d(samples[1], k)

    def light_weight(self, ls: LightSample, q_bsdf: Sequence, light_scale=None):
        """MIS weight of a light sample against the BSDF techniques' effective densities
        ``q_bsdf`` at its direction (1 for a delta light)."""
        scale = self.n_l if light_scale is None else light_scale
        return dr.select(ls.ds.delta, 1.0, self.heur.weight(0, [scale * ls.ds.pdf, *q_bsdf]))

    def light_term(self, ls: LightSample, f, q_bsdf: Sequence, light_scale=None):
        """f L_e G / (p(k) p_k) w_l of one light sample, zero where it is occluded."""
        return dr.select(ls.visible, f * ls.weight * self.light_weight(ls, q_bsdf, light_scale),
                         0.0)

    @record_once
    @dr.syntax
    def light_estimate(self, scene, sel, sampler, ctx, si, bsdf, active):
        """1/N_l sum over N_l light samples (densities against N_b BSDF samples)."""
        L = mi.Spectrum(0.0)
        first = (sel.sample_1d(sampler, active), sampler.next_2d(active))
        j = mi.UInt32(0)
        while dr.hint(j < self.n_l, label="light samples", exclude=[si, bsdf, ctx, first]):
            if dr.hint(is_jit() or active, mode="scalar"):   # (scalar: a bool)
                ls = self.light_sample(scene, sel, sampler, si, active, bsdf, ctx,
                                       self.stratum(sel, sampler, first, j, self.n_l, active))
                f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ls.ds.d), ls.visible)
                L += self.light_term(ls, f, [self.n_b * pdf_b])
            j += 1
        return L / self.n_l

    # ---- 2. light samples and the BSDF sample together --------------------------------------
    def direct(self, scene, sel, sampler, ctx, si, bsdf, active, p_light=None) -> Direct:
        """The light-sample estimate at ``si`` and one BSDF sample (:class:`Direct`).

        ``norm`` goes to :meth:`emission` for the emission that ``bs`` finds.  No shadow rays
        where the BSDF has no smooth lobe.  With ``p_light`` (N_l = 1 only; a Float per lane)
        the light sample is taken with that probability and weighted for it (its effective
        density p_light p_l, the estimate divided by p_light): stochastic next-event
        estimation, unbiased for any p_light > 0.  A ``p_light`` above one is an expected
        number of light samples n: m = floor(n) or ceil(n) of them by stochastic rounding
        (:meth:`extra_light_samples`), averaged (divided by m, at effective density m p_l: the
        multi-sample MIS estimator given m, so unbiased for each m >= 1 and free of the noise
        of dividing a random count by n).  ``Direct.light_scale`` is the light technique's
        count or probability, for the weight of the emission the BSDF sample finds."""
        n_l = self.n_l if sel.count > 0 else 0
        smooth = active & mi.has_flag(bsdf_flags(bsdf), mi.BSDFFlags.Smooth)
        if n_l == 1:
            scale = p_light
            if p_light is not None:
                u = sampler.next_1d(active)
                smooth &= u < p_light
                if dr.hint(self.allocates, mode="scalar"):
                    base = dr.floor(p_light)
                    scale = dr.select(p_light > 1.0,
                                      base + dr.select(u < p_light - base, 1.0, 0.0), p_light)
            ls = self.light_sample(scene, sel, sampler, si, smooth, bsdf, ctx)
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            if bsdf is None:
                return Direct(mi.Spectrum(0.0), *no_bsdf_sample(), ls.norm, ls, None, None)
            f_l, pdf_l, bs, weight = bsdf.eval_pdf_sample(ctx, si, si.to_local(ls.ds.d),
                                                          s1, s2, active)
            if p_light is None:
                L = self.light_term(ls, f_l, [self.n_b * pdf_l])
            else:
                L = safe_div(self.light_term(ls, f_l, [self.n_b * pdf_l], scale), scale)
                L += self.extra_light_samples(scene, sel, sampler, ctx, si, bsdf, smooth,
                                              scale, ls.samples)
            return Direct(L, bs, weight, ls.norm, ls, f_l, pdf_l, scale)
        L = mi.Spectrum(0.0)
        if n_l > 0:
            L = self.light_estimate(scene, sel, sampler, ctx, si, bsdf, smooth)
        s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
        if bsdf is None:
            return Direct(L, *no_bsdf_sample(), None, None, None, None)
        bs, weight = bsdf.sample(ctx, si, s1, s2, active)
        return Direct(L, bs, weight, None, None, None, None)

    @record_once
    @dr.syntax
    def extra_light_samples(self, scene, sel, sampler, ctx, si, bsdf, active, m, first):
        """The light samples beyond the first where the lane's light-sample count ``m`` (an
        integer-valued Float, see :meth:`direct`) exceeds one: m - 1 more, strata 1..m-1 of
        the first one's uniforms ``first`` (:meth:`stratum`), each at effective density m p_l
        and divided by m (nothing where m <= 1)."""
        L = mi.Spectrum(0.0)
        if dr.hint(not self.allocates, mode="scalar"):
            return L
        more = active & (m > 1.0)
        count = dr.select(more, mi.UInt32(m), 1)
        j = mi.UInt32(1)
        while dr.hint(more & (j < count), label="extra light samples",
                      exclude=[si, bsdf, ctx, first, m, more, count]):
            ls = self.light_sample(scene, sel, sampler, si, more, bsdf, ctx,
                                   self.stratum(sel, sampler, first, j, m, more))
            f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ls.ds.d), ls.visible)
            L += safe_div(self.light_term(ls, f, [self.n_b * pdf_b], m), m)
            j += 1
        return L

    # ---- 3. emission found by a BSDF sample ------------------------------------------------
    def emission(self, scene, sel, si_prev, si, q_bsdf: Sequence, delta, active, norm=None,
                 index=0, light_scale=None, with_light_pdf: bool = False):
        """L_e at ``si`` (reached from ``si_prev`` by BSDF technique ``index``) times its MIS
        weight over the light technique and the BSDF techniques' densities ``q_bsdf``
        (weight 1 after a delta lobe, or without light sampling).  ``index`` is an int, or,
        with two BSDF techniques, a mask: technique 0 where true, 1 elsewhere.
        ``with_light_pdf``: return (weighted L_e, L_e, the light technique's pdf p_l)."""
        scale = self.n_l if light_scale is None else light_scale
        L_e = emitted(scene, si, active)
        pdf_l = mi.Float(0.0)
        if isinstance(scale, (int, float)) and scale == 0 or sel.count == 0:
            w = self.heur.weights(list(q_bsdf)) if len(q_bsdf) > 1 else [mi.Float(1.0)]
        else:
            pdf_l = sel.pdf_direction(si_prev, si, active & lnot(delta), norm)
            w = self.heur.weights([scale * pdf_l, *q_bsdf])[1:]
        if isinstance(index, bool):      # a mask in scalar variants
            w = w[0] if index else w[1]
        elif isinstance(index, int):
            w = w[index]
        else:
            w = dr.select(index, w[0], w[1])
        weighted = L_e * dr.select(delta, 1.0, w)
        return (weighted, L_e, pdf_l) if with_light_pdf else weighted

    # ---- the path: the vertex estimate at every vertex ----------------------------------------
    @record_once
    @dr.syntax
    def path(self, scene, sampler, sel, ray, si, active, max_depth: int, learner=None):
        """One path's estimate of the light reflected at its first hit ``si`` (the emission
        seen there excluded): at every vertex beta [light estimate + weighted emission found by
        the BSDF sample], then roulette.  ``learner`` (optional) gives each vertex its
        light-sample probability (``learner.light_probability(si, sampler, active)`` -> (p, where
        to record)) and is told what the light sample and the BSDF sample found
        (``record_light``, ``record_hit``), so it can learn that probability per region between
        passes; it also follows the whole path (``path_start``, ``path_vertex``,
        ``record_path``: the path's estimate and cost, the variance and cost of the pixel
        sample that a vertex's decision is one part of), and of the rays it traces on
        (``path_ray``: the lanes whose path goes on from the vertex)."""
        ctx = mi.BSDFContext()
        limit = depth_limit(max_depth)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        active = mi.Bool(active)
        learn = learner is not None

        si = mi.SurfaceInteraction3f(si)      # (the caller's is not changed)
        si.time = widen(si.time, si.p)
        track = learner.path_start(si.p) if learn else None
        while dr.hint(active, label="path", exclude=[limit, ctx]):
            bsdf = bsdf_at(si, ray, active)
            p_l, cell = None, None
            if dr.hint(learn, mode="scalar"):
                p_l, cell = learner.light_probability(si, sampler, active)
                track = learner.path_vertex(track, cell, p_l, active)
            d = self.direct(scene, sel, sampler, ctx, si, bsdf, active, p_l)
            L += beta * d.L
            if dr.hint(learn, mode="scalar"):
                learner.record_light(cell, beta, d, p_l)
                learner.record_pair(scene, sel, sampler, si, bsdf, cell, beta, active)
            beta *= d.weight
            eta *= d.bs.eta
            depth += 1
            beta, active = self.roulette(beta, eta, depth, sampler, active)
            # (a path whose throughput is zero adds nothing more: not traced on, as Mitsuba's
            # own integrators stop it; before the throughput rule's first depth nothing else
            # would)
            active &= dr.any(mi.unpolarized_spectrum(beta) != 0)
            if dr.hint(learn, mode="scalar"):
                track = learner.path_ray(track, active)
            si_prev = si
            ray = si.spawn_ray(si.to_world(d.bs.wo))
            si = scene.ray_intersect(ray, active)
            delta = mi.has_flag(d.bs.sampled_type, mi.BSDFFlags.Delta)
            scale = d.light_scale if learn else None
            L_w, L_e, pdf_e = self.emission(scene, sel, si_prev, si, [self.n_b * d.bs.pdf],
                                            delta, active, d.norm, light_scale=scale,
                                            with_light_pdf=True)
            L += dr.select(active, beta * L_w, 0.0)
            if dr.hint(learn, mode="scalar"):
                learner.record_hit(cell, beta, L_e, pdf_e, d.bs.pdf, p_l,
                                   active & lnot(delta))
            active &= si.is_valid() & (depth + 1 < limit)
        if learn:
            learner.record_path(track, L)
        return L

    # ---- 4. roulette ----------------------------------------------------------------------
    def roulette(self, beta, eta, depth, sampler, active):
        """Russian roulette on the throughput after a vertex: (beta, active)."""
        return self.rr(beta, eta, depth, sampler.next_1d(active), active)
