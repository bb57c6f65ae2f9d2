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

from ..common import bsdf_at, is_jit, record_once
from ..params import MAX_COUNT, Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, mis
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, IntegratorTemplate


@plugin("direct_mis", "integrator")
class DirectMIS(IntegratorTemplate):
    """Direct illumination by light sampling and BSDF sampling combined with MIS."""

    PARAMS = (
        Param("light_samples", "int", 1, min=0, max=MAX_COUNT,
              doc="N_l, light samples per camera sample (strata of one: stratified over the "
                  "lights and their surfaces)."),
        Param("bsdf_samples", "int", 1, min=0, max=MAX_COUNT, doc="N_b, BSDF samples per camera sample."),
        *mis.PARAMS,
        light_selection.PARAM, light_selection.CANDIDATES_PARAM, HIDE_EMITTERS,
    )

    def setup(self):
        if self.light_samples == 0 and self.bsdf_samples == 0:
            raise ParameterError("direct_mis: parameters 'light_samples' = 0 and 'bsdf_samples' "
                                 "= 0 estimate nothing; allowed: at least one of them >= 1")
        self.heur = mis.Heuristic.from_params(self.params)
        self.lights = light_selection.SelectionCache.of(self)
        self.vertex = VertexEstimator(self.heur, self.light_samples, self.bsdf_samples)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        ctx = mi.BSDFContext()
        active = mi.Bool(active)
        sel = self.prepare(scene)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        active = active & valid
        bsdf = bsdf_at(si, ray, active)
        vx, n_b = self.vertex, self.bsdf_samples
        if n_b == 0:
            if sel.count > 0 and self.light_samples > 0:
                L += vx.light_estimate(scene, sel, sampler, ctx, si, bsdf, active)
            return L, valid, []
        # the light samples and the first BSDF sample, then the other N_b - 1 BSDF samples
        d = vx.direct(scene, sel, sampler, ctx, si, bsdf, active)
        L_b = self.bsdf_hit(scene, sel, si, d.bs, d.weight, active, d.norm)
        if n_b > 1:
            L_b += self.more_bsdf_samples(scene, sel, sampler, ctx, si, bsdf, active)
        return L + d.L + L_b / n_b, valid, []

    def bsdf_hit(self, scene, sel, si, bs, weight, active, norm=None):
        """Emission found by one BSDF sample, MIS-weighted (not divided by N_b)."""
        act = active & dr.any(weight != 0)
        si_l = scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), act)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        L_e = self.vertex.emission(scene, sel, si, si_l, [self.bsdf_samples * bs.pdf], delta,
                                   act, norm)
        return dr.select(act, weight * L_e, 0.0)

    @record_once
    @dr.syntax
    def more_bsdf_samples(self, scene, sel, sampler, ctx, si, bsdf, active):
        """The sum over BSDF samples 2..N_b of their weighted emission."""
        L = mi.Spectrum(0.0)
        j = mi.UInt32(1)
        while dr.hint(j < self.bsdf_samples, label="direct_mis BSDF samples",
                      exclude=[si, bsdf, ctx]):
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            if dr.hint(is_jit() or active, mode="scalar"):   # (scalar: a bool)
                bs, weight = bsdf.sample(ctx, si, s1, s2, active)
                L += self.bsdf_hit(scene, sel, si, bs, weight, active)
            j += 1
        return L
