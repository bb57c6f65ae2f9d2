r"""Integrator ``mis3``: the lecture's three-PDF one-sample MIS, recursively.

At every vertex one technique I is chosen with probability p(I):

1. the **cosine lobe**: ``BSDF.sample`` restricted to the BSDF's diffuse components,
2. the **glossy lobe**: ``BSDF.sample`` restricted to its glossy and delta components,
3. **light sampling**: a light by ``light_selection``, a point on it (area form converted to
   solid angle), a shadow ray.

**Component rule** (:mod:`integrators.sampling.techniques`): any Mitsuba BSDF is split by its
component flags; p_1(omega) and p_2(omega) are the BSDF's pdfs with only the diffuse or only the
glossy and delta components enabled, p_3(omega) = p(light) p_light(omega), zero for a direction
that hits no light.  Light samples, emission weights and roulette are the shared per-vertex
estimator's (:mod:`integrators.sampling.vertex`) with one-sample densities q_I = p(I) p_I.

**Estimator.** The integrand f L cos is split into the emitted part (f L_e cos) and the
reflected part (f L_r cos).  With q_k = p(k) p_k(omega):

* emitted light found by technique I (a BSDF direction that hits a light, or a light sample)
  adds  beta f cos L_e w_I(q_1, q_2, q_3) / (p(I) p_I);
* the path continues only after techniques 1 and 2, with
  beta *= f cos w'_I(q_1, q_2) / (p(I) p_I), where w' is the heuristic over the two BSDF
  techniques (light sampling cannot continue a path, so it takes no share of the reflected part);
  choosing I = 3 ends the path after its shadow ray.
Both sums of weights are one wherever a technique can produce omega, so the estimator is
unbiased for any p-vector (this is the lecture's scheme, where a BSDF direction in Omega_direct
contributes L_e with weight w_I and one in Omega_indirect continues the recursion; here a light
that also reflects continues the path as well).  Delta lights and delta lobes take weight 1.

**Technique probabilities** (``selection``): ``fixed`` uses (``p_cosine``, ``p_glossy``,
``p_light``) normalised.  ``adaptive`` chooses p(I) per vertex from what is there: the cosine
technique gets p_cosine * a_d if the BSDF has a diffuse component (a_d = mean diffuse albedo
from ``eval_diffuse_reflectance``, 1/2 when a BSDF does not report it), the glossy technique
p_glossy * (1 - a_d) if it has a glossy or delta component (p_glossy alone without a diffuse
one), light sampling p_light if the scene has lights and the BSDF a smooth component; then
normalised.  A diffuse surface never draws from the glossy pdf and a scene without lights never
draws light samples.
"""
from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi

from ..common import any_flag, bsdf_at, bsdf_flags, channel_mean, depth_limit, is_jit, lnot, \
    safe_div
from ..params import Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, mis, roulette
from ..sampling.techniques import DIFFUSE, GLOSSY, lobe_contexts, lobe_densities
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate


def _prob(name, default, doc):
    return Param(name, "float", default, min=0.0, max=1.0, doc=doc)


@plugin("mis3", "integrator")
class MIS3(IntegratorTemplate):
    """One-sample MIS over a cosine lobe, a glossy lobe and light sampling, at every vertex."""

    PARAMS = (
        _prob("p_cosine", 1 / 3, "Weight of the cosine-lobe technique."),
        _prob("p_glossy", 1 / 3, "Weight of the glossy-lobe technique."),
        _prob("p_light", 1 / 3, "Weight of light sampling."),
        Param("selection", "choice", "fixed", choices=("fixed", "adaptive"),
              doc="Technique probabilities: the fixed p-vector or adapted per vertex."),
        dataclasses.replace(mis.PARAMS[0], default="balance"), *mis.PARAMS[1:],
        light_selection.PARAM,
        MAX_DEPTH, *roulette.RR_PARAMS, HIDE_EMITTERS,
    )

    def setup(self):
        total = self.p_cosine + self.p_glossy + self.p_light
        if not total > 0:
            raise ParameterError("mis3: p_cosine + p_glossy + p_light = 0; allowed: "
                                 "probabilities in [0, 1] with a positive sum")
        self.p_fixed = (self.p_cosine / total, self.p_glossy / total, self.p_light / total)
        self.heur = mis.Heuristic.from_params(self.params)
        self.lights = light_selection.SelectionCache(self.light_selection)
        self.vertex = VertexEstimator(self.heur, 1, 1, roulette.Roulette.from_params(self.params))

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

    @dr.syntax
    def sample(self, scene, sampler, ray, medium=None, active=True):
        ctx, ctx_d, ctx_g = lobe_contexts()
        vx = self.vertex
        sel = self.prepare(scene)
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

        while dr.hint(active, label="mis3"):
            bsdf = bsdf_at(si, ray, active)
            p1, p2, p3 = self.technique_probs(bsdf, si, has_lights, active)
            u = sampler.next_1d(active)
            use_l = (p3 > 0) & (u >= p1 + p2)
            use_1 = lnot(use_l) & (u < p1)

            # ---- technique 3: light sampling (ends the path) ----
            norm = None   # the light selection's normaliser at si, reused by technique 1/2
            if is_jit() or (active and use_l and has_lights):
                ls = vx.light_sample(scene, sel, sampler, si, active & use_l)
                norm = ls.norm
                wo = si.to_local(ls.ds.d)
                f = bsdf.eval(ctx, si, wo, ls.visible)
                q_b = lobe_densities(bsdf, ctx_d, ctx_g, si, wo, p1, p2, ls.visible)
                L += beta * safe_div(vx.light_term(ls, f, q_b, light_scale=p3), p3)
            else:
                sampler.next_1d()
                sampler.next_2d()

            # ---- techniques 1 and 2: a lobe of the BSDF (continues the path) ----
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            act_b = active & lnot(use_l)
            if is_jit() or act_b:
                bs_d, _ = bsdf.sample(ctx_d, si, s1, s2, act_b & use_1)
                bs_g, w_g = bsdf.sample(ctx_g, si, s1, s2, act_b & lnot(use_1))
                wo = dr.select(use_1, bs_d.wo, bs_g.wo)
                delta = lnot(use_1) & mi.has_flag(bs_g.sampled_type, mi.BSDFFlags.Delta)
                act_b &= dr.select(use_1, bs_d.pdf, bs_g.pdf) > 0
                smooth_b = act_b & lnot(delta)
                f = bsdf.eval(ctx, si, wo, smooth_b)
                q1, q2 = lobe_densities(bsdf, ctx_d, ctx_g, si, wo, p1, p2, smooth_b)
                # f cos / (p(I) p_I): delta lobes give the BSDF's own weight / p(2)
                ratio = dr.select(delta, safe_div(w_g, p2),
                                  safe_div(f, dr.select(use_1, q1, q2)))
                w_ind = self.heur.weights([q1, q2])
                w_ind = dr.select(delta, 1.0, dr.select(use_1, w_ind[0], w_ind[1]))
                ray_b = si.spawn_ray(si.to_world(wo))
                si_b = scene.ray_intersect(ray_b, act_b)
                L_e = vx.emission(scene, sel, si, si_b, [q1, q2], delta, act_b, norm,
                                  index=use_1, light_scale=p3)
                L += dr.select(act_b, beta * ratio * L_e, 0.0)
                beta = dr.select(act_b, beta * ratio * w_ind, 0.0)
                eta *= dr.select(use_1, bs_d.eta, bs_g.eta)
                ray = ray_b
                si = si_b
            depth += 1
            active = act_b
            beta, active = vx.roulette(beta, eta, depth, sampler, active)
            active &= si.is_valid() & (depth + 1 < max_depth)
        return L, valid, []
