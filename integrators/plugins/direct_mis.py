r"""Integrator ``direct_mis``: the direct-light integral Omega_direct with multi-sample MIS.

At the first surface seen by a camera ray (plus the emission seen directly):

    L_o = L_e + 1/N_l \sum_j w_l f L_e G / (p(k_j) p_{k_j}(x_j))  +  1/N_b \sum_j w_b f cos L_e / p_b

* ``light_samples`` N_l light samples: a light k chosen by ``light_selection``, a point on it
  (Mitsuba's ``Emitter.sample_direction``: area form converted to solid angle), a shadow ray;
* ``bsdf_samples`` N_b BSDF samples: a direction from ``BSDF.sample``, emission added when it
  hits a light (or the environment);
* the weights come from ``heuristic`` over the effective densities q_l = N_l p(k) p_k(omega)
  and q_b = N_b p_b(omega) (see :mod:`integrators.mis`).  ``partition`` gives a direction that
  hits a light to light sampling alone (the lecture's stratification).

Delta lights (point, spot, directional) are reachable by light sampling only and delta BSDF
lobes by BSDF sampling only: their samples take weight 1, without MIS.  Each light sample is
divided by N_l, delta lights included (Mitsuba's ``direct`` does not divide its delta-light
samples by ``emitter_samples`` and makes point lights N times too bright: mitsuba3 #1861).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..sampling import light_selection, mis, vertex as nee
from .base import IntegratorTemplate
from ..common import bsdf_at, bsdf_flags, emitted, is_jit
from ..params import Param
from ..registry import plugin


@plugin("direct_mis", "integrator")
class DirectMIS(IntegratorTemplate):
    """Direct illumination by light sampling and BSDF sampling combined with MIS."""

    PARAMS = (
        Param("light_samples", "int", 1, min=0, doc="N_l, light samples per camera sample."),
        Param("bsdf_samples", "int", 1, min=0, doc="N_b, BSDF samples per camera sample."),
        *mis.PARAMS,
        light_selection.PARAM,
    )

    def setup(self):
        self.heur = mis.Heuristic.from_params(self.params)
        self.selection = light_selection.SelectionCache(self.light_selection)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        ctx = mi.BSDFContext()
        active = mi.Bool(active)
        si = scene.ray_intersect(ray, active)
        L = emitted(scene, si, active)
        valid = si.is_valid()
        active = active & valid
        sel = self.selection(scene)
        bsdf = bsdf_at(si, ray, active)
        n_l = self.light_samples if sel.count > 0 else 0
        # a surface without a smooth lobe (a mirror) gets nothing from light samples
        smooth = mi.has_flag(bsdf_flags(bsdf), mi.BSDFFlags.Smooth)
        if n_l == 1 and self.bsdf_samples == 1 and bsdf is not None:
            # one sample of each: evaluate the BSDF for the light sample and draw the BSDF
            # sample in one call (as Mitsuba's direct and path do)
            ds, em_weight, act_l, norm = nee.sample_light(scene, sel, sampler, si,
                                                          active & smooth)
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            f_l, pdf_l, bs, weight = bsdf.eval_pdf_sample(ctx, si, si.to_local(ds.d), s1, s2,
                                                          active)
            w_l = nee.light_weight(self.heur, 1, 1, ds, pdf_l)
            L += dr.select(act_l, f_l * em_weight * w_l, 0.0)
            L += self.bsdf_hit(scene, sel, si, bs, weight, n_l, active, norm)
            return L, valid, []
        if n_l > 0:
            L += nee.light_estimate(scene, sel, self.heur, sampler, ctx, si, bsdf, n_l,
                                    self.bsdf_samples, active & smooth)
        if self.bsdf_samples > 0:
            L += self.bsdf_estimate(scene, sel, sampler, ctx, si, bsdf, n_l, active)
        return L, valid, []

    def bsdf_hit(self, scene, sel, si, bs, weight, n_l, active, norm=None):
        """Emission found by one BSDF sample, MIS-weighted (not divided by N_b)."""
        act = active & dr.any(weight != 0)
        si_l = scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), act)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        w = nee.emission_weight(self.heur, sel, n_l, self.bsdf_samples, si, si_l, bs.pdf,
                                delta, act, norm)
        return dr.select(act, weight * emitted(scene, si_l, act) * w, 0.0)

    @dr.syntax
    def bsdf_estimate(self, scene, sel, sampler, ctx, si, bsdf, n_l, active):
        n_b = self.bsdf_samples
        L = mi.Spectrum(0.0)
        j = mi.UInt32(0)
        while dr.hint(j < n_b, label="direct_mis BSDF samples"):
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            if is_jit() or active:
                bs, weight = bsdf.sample(ctx, si, s1, s2, active)
                L += self.bsdf_hit(scene, sel, si, bs, weight, n_l, active)
            j += 1
        return L / n_b
