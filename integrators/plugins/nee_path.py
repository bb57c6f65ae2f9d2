r"""Integrator ``nee_path``: path tracing with next-event estimation and MIS at every vertex.

The lecture's estimator with each degree of freedom of its last slide as a parameter:

    L = L_e(x_0) + sum_k beta_k [ NEE(x_k) + w_b(x_{k+1}) L_e(x_{k+1}) ],  beta_{k+1} = beta_k f cos / p

* **PDFs at each vertex**: one BSDF sample continues the path; ``light_samples`` shadow rays
  estimate the direct light (splitting of the light estimate), combined by ``heuristic``
  (``beta``, ``alpha``) exactly as in ``direct_mis`` (:mod:`integrators.nee`).  Delta lights and
  delta lobes take weight 1.  Vertices without a smooth lobe cast no shadow rays.
* **Light selection**: ``light_selection`` = ``uniform`` | ``power``.
* **Path length**: ``max_depth`` (-1 unlimited), Russian roulette from ``rr_depth`` with
  ``rr`` = ``none`` | ``fixed`` (terminate with probability ``rr_prob``, survivors divided by
  1 - rr_prob) | ``throughput`` (survive with min(max(beta) eta^2, 0.95), as Mitsuba's ``path``
  and pbrt).  All three are unbiased.
* **Splitting**: ``split`` = k independent continuations from each camera ray's first hit, each
  weighted 1/k; the camera ray, the first intersection and its emission are paid once.  The
  integrator traces ``split`` paths per camera sample (``paths_per_sample``), which cost
  comparisons must count.

With ``heuristic=power, light_selection=uniform, rr=throughput, light_samples=1, split=1`` this is
the estimator of Mitsuba's built-in ``path`` (tested statistically on the Cornell box).
"""
from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi

from ..sampling import light_selection, mis, vertex as nee
from ..sampling.roulette import RR_MODES, RR_PARAMS, roulette  # noqa: F401
from .base import MAX_DEPTH, IntegratorTemplate
from ..common import bsdf_at, bsdf_flags, depth_limit, emitted
from ..params import Param
from ..registry import plugin

def split_weight(k: int) -> float:
    """Weight of each of the k continuations of a split: their average is unbiased."""
    return 1.0 / k


@plugin("nee_path", "integrator")
class NEEPath(IntegratorTemplate):
    """Path tracing with next-event estimation, MIS, light selection, Russian roulette, splitting."""

    PARAMS = (
        MAX_DEPTH, *RR_PARAMS,
        dataclasses.replace(mis.PARAMS[0], default="power"), *mis.PARAMS[1:],
        light_selection.PARAM,
        Param("light_samples", "int", 1, min=0, doc="Shadow rays per vertex (NEE splitting)."),
        Param("split", "int", 1, min=1, doc="Independent continuations from the first hit."),
    )

    def setup(self):
        self.heur = mis.Heuristic.from_params(self.params)
        self.selection = light_selection.SelectionCache(self.light_selection)
        self.paths_per_sample = self.split

    @dr.syntax
    def sample(self, scene, sampler, ray, medium=None, active=True):
        active = mi.Bool(active)
        ray = mi.Ray3f(ray)
        sel = self.selection(scene)
        si = scene.ray_intersect(ray, active)
        valid = si.is_valid()
        L = emitted(scene, si, active)
        active = active & valid & (1 < depth_limit(self.max_depth))
        if dr.hint(self.split == 1, mode="scalar"):
            L += self.reflected(scene, sampler, sel, ray, si, active)
        else:
            acc = mi.Spectrum(0.0)
            k = mi.UInt32(0)
            while dr.hint(k < self.split, label="nee_path split"):
                acc += self.reflected(scene, sampler, sel, ray, si, active)
                k += 1
            L += acc * split_weight(self.split)
        return L, valid, []

    @dr.syntax
    def reflected(self, scene, sampler, sel, ray, si, active):
        """One path's estimate of the light reflected at the first hit ``si`` (its emission
        excluded)."""
        ctx = mi.BSDFContext()
        n_l = self.light_samples if sel.count > 0 else 0
        max_depth = depth_limit(self.max_depth)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        active = mi.Bool(active)

        while dr.hint(active, label="nee_path"):
            bsdf = bsdf_at(si, ray, active)
            smooth = mi.has_flag(bsdf_flags(bsdf), mi.BSDFFlags.Smooth)
            norm = None
            if dr.hint(n_l == 1, mode="scalar"):
                # one light sample: evaluate the BSDF for it and sample the continuation in
                # one call, as Mitsuba's path does (measured: ~4 % faster than two calls)
                ds, em_weight, act_l, norm = nee.sample_light(scene, sel, sampler, si,
                                                              active & smooth)
                s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
                f_l, pdf_l, bs, weight = (
                    bsdf.eval_pdf_sample(ctx, si, si.to_local(ds.d), s1, s2, active)
                    if bsdf is not None else
                    (mi.Spectrum(0.0), mi.Float(0.0), dr.zeros(mi.BSDFSample3f),
                     mi.Spectrum(0.0)))
                w_l = nee.light_weight(self.heur, 1, 1, ds, pdf_l)
                L += dr.select(act_l, beta * f_l * em_weight * w_l, 0.0)
            else:
                if dr.hint(n_l > 0, mode="scalar"):
                    L += beta * nee.light_estimate(scene, sel, self.heur, sampler, ctx, si,
                                                   bsdf, n_l, 1, active & smooth)
                s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
                bs, weight = (bsdf.sample(ctx, si, s1, s2, active) if bsdf is not None
                              else (dr.zeros(mi.BSDFSample3f), mi.Spectrum(0.0)))
            beta *= weight
            eta *= bs.eta
            depth += 1
            beta, active = roulette(self.rr, self.rr_depth, self.rr_prob, beta, eta, depth,
                                    sampler.next_1d(active), active)
            si_prev = si
            ray = si.spawn_ray(si.to_world(bs.wo))
            si = scene.ray_intersect(ray, active)
            delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            w = nee.emission_weight(self.heur, sel, n_l, 1, si_prev, si, bs.pdf, delta, active,
                                    norm)
            L += dr.select(active, beta * emitted(scene, si, active) * w, 0.0)
            active &= si.is_valid() & (depth + 1 < max_depth)
        return L
