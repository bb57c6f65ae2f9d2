r"""Integrator ``mis3``: the lecture's three-PDF one-sample MIS, recursively.

At every vertex one technique I is chosen with probability p(I):

1. the **cosine lobe**: ``BSDF.sample`` restricted to the BSDF's diffuse components,
2. the **glossy lobe**: ``BSDF.sample`` restricted to its glossy and delta components,
3. **light sampling**: a light by ``light_selection``, a point on it (area form converted to
   solid angle), a shadow ray.

**Component rule.** Any Mitsuba BSDF is split by its component flags through
``BSDFContext.type_mask``: components with ``DiffuseReflection``/``DiffuseTransmission`` form
the cosine technique; components with ``Glossy*`` or ``Delta*`` flags form the glossy technique.
p_1(omega) and p_2(omega) are the BSDF's pdfs with only those components enabled (for ``phong``,
``plastic``, ``roughplastic``: the lobe's own pdf), p_3(omega) = p(light) p_light(omega), zero
for a direction that hits no light.

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

from ..sampling import light_selection, mis
from ..sampling.roulette import RR_PARAMS, roulette
from .base import MAX_DEPTH, IntegratorTemplate
from ..common import any_flag, bsdf_at, bsdf_flags, channel_mean, depth_limit, emitted, is_jit, lnot
from ..params import Param, ParameterError
from ..registry import plugin

DIFFUSE = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.DiffuseTransmission
GLOSSY = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.GlossyTransmission |
          mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.DeltaTransmission)


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
        MAX_DEPTH, *RR_PARAMS,
    )

    def setup(self):
        total = self.p_cosine + self.p_glossy + self.p_light
        if not total > 0:
            raise ParameterError("mis3: p_cosine + p_glossy + p_light = 0; allowed: "
                                 "probabilities in [0, 1] with a positive sum")
        self.p_fixed = (self.p_cosine / total, self.p_glossy / total, self.p_light / total)
        self.heur = mis.Heuristic.from_params(self.params)
        self.selection = light_selection.SelectionCache(self.light_selection)

    def technique_probs(self, bsdf, si, has_lights: bool, active):
        """(p1, p2, p3) at this vertex, summing to one (zero where nothing is there)."""
        if self.selection_mode_fixed:
            p1, p2, p3 = (mi.Float(p) for p in self.p_fixed)
            return p1, p2, (p3 if has_lights else p3 * 0.0)
        flags = bsdf_flags(bsdf)
        has_d = any_flag(flags, DIFFUSE)
        has_g = any_flag(flags, GLOSSY)
        smooth = mi.has_flag(flags, mi.BSDFFlags.Smooth)
        a_d = mi.Float(0.5)
        if bsdf is not None:
            a_d = channel_mean(bsdf.eval_diffuse_reflectance(si, active & has_d))
            a_d = dr.select(a_d > 0, dr.minimum(a_d, 1.0), 0.5)
        r1 = dr.select(has_d, self.p_cosine * a_d, 0.0)
        r2 = dr.select(has_g, self.p_glossy * dr.select(has_d, 1.0 - a_d, 1.0), 0.0)
        r3 = dr.select(smooth & has_lights, self.p_light, 0.0) if has_lights else mi.Float(0.0)
        total = r1 + r2 + r3
        inv = dr.select(total > 0, dr.rcp(dr.select(total > 0, total, 1.0)), 0.0)
        return r1 * inv, r2 * inv, r3 * inv

    @property
    def selection_mode_fixed(self):
        return self.params["selection"] == "fixed"

    @dr.syntax
    def sample(self, scene, sampler, ray, medium=None, active=True):
        ctx = mi.BSDFContext()
        ctx_d = mi.BSDFContext()
        ctx_d.type_mask = int(DIFFUSE)
        ctx_g = mi.BSDFContext()
        ctx_g.type_mask = int(GLOSSY)
        sel = self.selection(scene)
        has_lights = sel.count > 0
        max_depth = depth_limit(self.max_depth)
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        si = scene.ray_intersect(ray, active)
        valid = si.is_valid()
        L = emitted(scene, si, active)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        active = active & valid & (1 < max_depth)

        while dr.hint(active, label="mis3"):
            bsdf = bsdf_at(si, ray, active)
            p1, p2, p3 = self.technique_probs(bsdf, si, has_lights, active)
            u, s1, s2, s_l = (sampler.next_1d(active), sampler.next_1d(active),
                              sampler.next_2d(active), sampler.next_1d(active))
            use_l = (p3 > 0) & (u >= p1 + p2)
            use_1 = lnot(use_l) & (u < p1)
            use_2 = lnot(use_l) & lnot(use_1)

            # ---- technique 3: light sampling (ends the path) ----
            norm = None   # the light selection's normaliser at si, reused by technique 1/2
            if is_jit() or (active and use_l and has_lights):
                act_l = active & use_l
                ds, em_w, norm = sel.sample_direction(si, s_l, s2, act_l)
                act_l &= dr.any(em_w != 0)
                act_l &= lnot(scene.ray_test(si.spawn_ray_to(ds.p), act_l))
                wo = si.to_local(ds.d)
                f = bsdf.eval(ctx, si, wo, act_l)
                q = [p3 * ds.pdf, p1 * bsdf.pdf(ctx_d, si, wo, act_l),
                     p2 * bsdf.pdf(ctx_g, si, wo, act_l)]
                w = dr.select(ds.delta, 1.0, self.heur.weight(0, q))
                L += dr.select(act_l, beta * f * em_w * w / dr.select(p3 > 0, p3, 1.0), 0.0)

            # ---- techniques 1 and 2: a lobe of the BSDF (continues the path) ----
            act_b = active & lnot(use_l)
            if is_jit() or act_b:
                bs_d, _ = bsdf.sample(ctx_d, si, s1, s2, act_b & use_1)
                bs_g, w_g = bsdf.sample(ctx_g, si, s1, s2, act_b & use_2)
                wo = dr.select(use_1, bs_d.wo, bs_g.wo)
                delta = lnot(use_1) & mi.has_flag(bs_g.sampled_type, mi.BSDFFlags.Delta)
                act_b &= dr.select(use_1, bs_d.pdf, bs_g.pdf) > 0
                smooth_b = act_b & lnot(delta)
                f = bsdf.eval(ctx, si, wo, smooth_b)
                q1 = p1 * bsdf.pdf(ctx_d, si, wo, smooth_b)
                q2 = p2 * bsdf.pdf(ctx_g, si, wo, smooth_b)
                q_i = dr.select(use_1, q1, q2)           # p(I) p_I(omega)
                # f cos / (p(I) p_I): delta lobes give the BSDF's own weight / p(2)
                ratio = dr.select(delta, w_g / dr.select(p2 > 0, p2, 1.0),
                                  dr.select(q_i > 0, f / dr.select(q_i > 0, q_i, 1.0), 0.0))
                w_ind = self.heur.weights([q1, q2])
                w_ind = dr.select(delta, 1.0, dr.select(use_1, w_ind[0], w_ind[1]))
                ray_b = si.spawn_ray(si.to_world(wo))
                si_b = scene.ray_intersect(ray_b, act_b)
                q3 = p3 * sel.pdf_direction(si, si_b, smooth_b, norm)
                w_dir = self.heur.weights([q3, q1, q2])   # light first: partition priority
                w_dir = dr.select(delta, 1.0, dr.select(use_1, w_dir[1], w_dir[2]))
                L += dr.select(act_b, beta * ratio * w_dir * emitted(scene, si_b, act_b), 0.0)
                beta = dr.select(act_b, beta * ratio * w_ind, 0.0)
                eta *= dr.select(use_1, bs_d.eta, bs_g.eta)
                ray = ray_b
                si = si_b
            depth += 1
            active = act_b
            beta, active = roulette(self.rr, self.rr_depth, self.rr_prob, beta, eta, depth,
                                    sampler.next_1d(active), active)
            active &= si.is_valid() & (depth + 1 < max_depth)
        return L, valid, []
