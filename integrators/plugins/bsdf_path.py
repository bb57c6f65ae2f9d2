r"""Integrator ``bsdf_path``: the lecture's "general path tracing" (no light sampling).

    beta = 1;  at every vertex: L += beta L_e;  draw omega from p;  beta *= f cos / p

Emitted radiance is added whenever the path hits an emitter (or escapes to an environment
emitter); there is no next-event estimation, so small lights are found only by chance.  The
direction at each vertex comes from ``hemisphere``:

* ``uniform``: p = 1 / (2 pi) over the hemisphere on the side of the incident direction;
* ``cosine``: p = cos(theta) / pi over that hemisphere;
* ``bsdf``: the BSDF's own importance sampling (``BSDF.sample``), the default.

With ``uniform`` or ``cosine``, a BSDF that transmits gets the whole sphere (each hemisphere with
probability 1/2), and a BSDF with a delta (specular) lobe is sampled with ``BSDF.sample`` at that
vertex, since no density over directions can hit a delta lobe.

Path length: ``max_depth`` (-1 unlimited) and throughput-based Russian roulette from ``rr_depth``
(survival min(max(beta) eta^2, 0.95), throughput divided by it: unbiased).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import bsdf_at, depth_limit, emitted, record_once
from ..params import Param
from ..registry import plugin
from ..sampling.roulette import RR_DEPTH, Roulette
from ..sampling.techniques import HEMISPHERE, hemisphere_sample
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate, has_delta_lights


@plugin("bsdf_path", "integrator")
class BSDFPath(IntegratorTemplate):
    """Path tracing that finds light only by hitting it (uniform, cosine or BSDF sampling)."""

    PARAMS = (
        MAX_DEPTH, RR_DEPTH, HIDE_EMITTERS,
        Param("hemisphere", "choice", "bsdf", choices=HEMISPHERE,
              doc="Direction sampling at each vertex."),
    )

    def setup(self):
        self.russian_roulette = Roulette("throughput", self.rr_depth)

    def scene_warnings(self, scene):
        if has_delta_lights(scene):
            return ["bsdf_path: BSDF sampling cannot reach the scene's point, spot or directional "
                    "lights, so they add nothing to the image (nee_path samples them)"]
        return []

    @record_once
    @dr.syntax
    def sample(self, scene, sampler, ray, medium=None, active=True):
        ctx = mi.BSDFContext()
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        max_depth = depth_limit(self.max_depth)
        self.prepare(scene)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        active &= valid & (1 < max_depth)

        while dr.hint(active, label="bsdf_path", exclude=[max_depth, ctx]):
            bsdf = bsdf_at(si, ray, active)
            s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
            wo, weight, eta_v = hemisphere_sample(self.hemisphere, ctx, bsdf, si, s1, s2, active)
            beta *= weight
            eta *= eta_v
            depth += 1
            beta, active = self.russian_roulette(beta, eta, depth, sampler.next_1d(active), active)
            ray = si.spawn_ray(si.to_world(wo))
            si = scene.ray_intersect(ray, active)
            L += dr.select(active, beta * emitted(scene, si, active), 0.0)
            active &= si.is_valid() & (depth + 1 < max_depth)

        return L, valid, []
