r"""The per-vertex estimator: what every integrator computes at a surface interaction.

At a vertex x with throughput beta, a path-tracing estimator with light sampling does four things
(the role of pbrt-v4's ``SampleLd`` with its emission weighting, or Tungsten's ``TraceBase``):

1. **Light samples** (``N_l`` of them): a light k picked by the light selection with p(k), a
   point on it, a shadow ray, and the MIS-weighted estimate

       1/N_l sum_j w_l(omega_j) f(omega_j) L_e G / (p(k_j) p_{k_j}(x_j)),

   :meth:`VertexEstimator.light_estimate` (:meth:`light_sample` + :meth:`light_weight`).
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

from ..common import bsdf_flags, emitted, is_jit, lnot
from .mis import Heuristic
from .roulette import Roulette


class LightSample(NamedTuple):
    ds: "mi.DirectionSample3f"   # ds.pdf = p(k) p_k(omega); ds.delta for delta lights
    weight: "mi.Spectrum"        # L_e G / (p(k) p_k), no visibility
    visible: "mi.Bool"           # lanes whose sample is unoccluded and non-zero
    norm: object                 # the selection's normaliser at x (see light_selection)


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

    # ---- 1. light samples -----------------------------------------------------------------
    @staticmethod
    def light_sample(scene, sel, sampler, si, active) -> LightSample:
        """One light sample at ``si`` with its shadow ray."""
        s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
        ds, em_weight, norm = sel.sample_direction(si, s1, s2, active)
        act = active & dr.any(em_weight != 0)
        act &= lnot(scene.ray_test(si.spawn_ray_to(ds.p), act))
        return LightSample(ds, em_weight, act, norm)

    def light_weight(self, ls: LightSample, q_bsdf: Sequence, light_scale=None):
        """MIS weight of a light sample against the BSDF techniques' effective densities
        ``q_bsdf`` at its direction (1 for a delta light)."""
        scale = self.n_l if light_scale is None else light_scale
        return dr.select(ls.ds.delta, 1.0, self.heur.weight(0, [scale * ls.ds.pdf, *q_bsdf]))

    def light_term(self, ls: LightSample, f, q_bsdf: Sequence, light_scale=None):
        """f L_e G / (p(k) p_k) w_l of one light sample, zero where it is occluded."""
        return dr.select(ls.visible, f * ls.weight * self.light_weight(ls, q_bsdf, light_scale),
                         0.0)

    @dr.syntax
    def light_estimate(self, scene, sel, sampler, ctx, si, bsdf, active):
        """1/N_l sum over N_l light samples (densities against N_b BSDF samples)."""
        L = mi.Spectrum(0.0)
        j = mi.UInt32(0)
        while dr.hint(j < self.n_l, label="light samples"):
            if is_jit() or active:
                ls = self.light_sample(scene, sel, sampler, si, active)
                f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ls.ds.d), ls.visible)
                L += self.light_term(ls, f, [self.n_b * pdf_b])
            else:
                sampler.next_1d()
                sampler.next_2d()
            j += 1
        return L / self.n_l

    # ---- 2. light samples and the BSDF sample together --------------------------------------
    def direct(self, scene, sel, sampler, ctx, si, bsdf, active):
        """The light-sample estimate at ``si`` and one BSDF sample.

        Returns (L_light, bs, f cos / p_b, norm); ``norm`` goes to :meth:`emission` for the
        emission that ``bs`` finds.  No shadow rays where the BSDF has no smooth lobe."""
        n_l = self.n_l if sel.count > 0 else 0
        smooth = active & mi.has_flag(bsdf_flags(bsdf), mi.BSDFFlags.Smooth)
        if n_l == 1:
            ls = self.light_sample(scene, sel, sampler, si, smooth)
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            if bsdf is None:
                return (mi.Spectrum(0.0), *no_bsdf_sample(), ls.norm)
            f_l, pdf_l, bs, weight = bsdf.eval_pdf_sample(ctx, si, si.to_local(ls.ds.d),
                                                          s1, s2, active)
            return self.light_term(ls, f_l, [self.n_b * pdf_l]), bs, weight, ls.norm
        L = mi.Spectrum(0.0)
        if n_l > 0:
            L = self.light_estimate(scene, sel, sampler, ctx, si, bsdf, smooth)
        s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
        if bsdf is None:
            return (L, *no_bsdf_sample(), None)
        bs, weight = bsdf.sample(ctx, si, s1, s2, active)
        return L, bs, weight, None

    # ---- 3. emission found by a BSDF sample ------------------------------------------------
    def emission(self, scene, sel, si_prev, si, q_bsdf: Sequence, delta, active, norm=None,
                 index=0, light_scale=None):
        """L_e at ``si`` (reached from ``si_prev`` by BSDF technique ``index``) times its MIS
        weight over the light technique and the BSDF techniques' densities ``q_bsdf``
        (weight 1 after a delta lobe, or without light sampling).  ``index`` is an int, or,
        with two BSDF techniques, a mask: technique 0 where true, 1 elsewhere."""
        scale = self.n_l if light_scale is None else light_scale
        L_e = emitted(scene, si, active)
        if isinstance(scale, (int, float)) and scale == 0 or sel.count == 0:
            if len(q_bsdf) == 1:
                return L_e
            w = self.heur.weights(list(q_bsdf))
        else:
            q_l = scale * sel.pdf_direction(si_prev, si, active & lnot(delta), norm)
            w = self.heur.weights([q_l, *q_bsdf])[1:]
        if isinstance(index, bool):      # a mask in scalar variants
            w = w[0] if index else w[1]
        elif isinstance(index, int):
            w = w[index]
        else:
            w = dr.select(index, w[0], w[1])
        return L_e * dr.select(delta, 1.0, w)

    # ---- 4. roulette ----------------------------------------------------------------------
    def roulette(self, beta, eta, depth, sampler, active):
        """Russian roulette on the throughput after a vertex: (beta, active)."""
        return self.rr(beta, eta, depth, sampler.next_1d(active), active)
