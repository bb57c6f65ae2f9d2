r"""Integrator ``nee_path``: path tracing with next-event estimation and MIS at every vertex.

The lecture's estimator with each degree of freedom of its last slide as a parameter:

    L = L_e(x_0) + sum_k beta_k [ NEE(x_k) + w_b(x_{k+1}) L_e(x_{k+1}) ],  beta_{k+1} = beta_k f cos / p

* **PDFs at each vertex**: one BSDF sample continues the path; ``light_samples`` shadow rays
  estimate the direct light (splitting of the light estimate), combined by ``heuristic``
  (``beta``, ``alpha``) exactly as in ``direct_mis`` (:mod:`integrators.nee`).  Delta lights and
  delta lobes take weight 1.  Vertices without a smooth lobe cast no shadow rays.
* **Light selection**: ``light_selection`` = ``uniform`` | ``power`` | ``adaptive``.
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

from ..common import depth_limit
from ..params import MAX_COUNT, Param
from ..registry import plugin
from ..sampling import light_selection, mis, roulette
from ..sampling.vertex import VertexEstimator
from .base import HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate


@plugin("nee_path", "integrator")
class NEEPath(IntegratorTemplate):
    """Path tracing with next-event estimation, MIS, light selection, Russian roulette, splitting."""

    PARAMS = (
        MAX_DEPTH, *roulette.RR_PARAMS,
        dataclasses.replace(mis.PARAMS[0], default="power"), *mis.PARAMS[1:],
        light_selection.PARAM,
        Param("light_samples", "int", 1, min=0, max=MAX_COUNT, doc="Shadow rays per vertex (NEE splitting)."),
        Param("split", "int", 1, min=1, max=MAX_COUNT, doc="Independent continuations from the first hit."),
        HIDE_EMITTERS,
    )

    def setup(self):
        self.heur = mis.Heuristic.from_params(self.params)
        self.lights = light_selection.SelectionCache(self.light_selection)
        self.vertex = VertexEstimator(self.heur, self.light_samples, 1,
                                      roulette.Roulette.from_params(self.params))
        self.paths_per_sample = self.split

    @dr.syntax
    def sample(self, scene, sampler, ray, medium=None, active=True):
        active = mi.Bool(active)
        ray = mi.Ray3f(ray)
        sel = self.prepare(scene)
        si, L = self.camera_hit(scene, ray, active)
        valid = si.is_valid()
        active = active & valid & (1 < depth_limit(self.max_depth))
        if dr.hint(self.split == 1, mode="scalar"):
            L += self.reflected(scene, sampler, sel, ray, si, active)
        else:
            acc = mi.Spectrum(0.0)
            k = mi.UInt32(0)
            while dr.hint(k < self.split, label="nee_path split"):
                acc += self.reflected(scene, sampler, sel, ray, si, active)
                k += 1
            L += acc * roulette.split_weight(self.split)
        return L, valid, []

    def reflected(self, scene, sampler, sel, ray, si, active):
        """One path's estimate of the light reflected at the first hit ``si`` (its emission
        excluded): the shared per-vertex estimator at every vertex."""
        return self.vertex.path(scene, sampler, sel, ray, si, active, self.max_depth)
