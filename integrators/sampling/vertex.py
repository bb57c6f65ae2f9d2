r"""Next-event estimation pieces shared by every integrator that samples lights.

* :func:`light_estimate` - the MIS-weighted light-sampling estimate at a surface point,
      1/N_l sum_j w_l(omega_j) f(omega_j) L_e G / (p(k_j) p_{k_j}(x_j)),
  with w_l from the heuristic over q_l = N_l p(k) p_k(omega) and q_b = N_b p_b(omega).
  Delta lights take w_l = 1.
* :func:`emission_weight` - the matching weight of emission found by a BSDF-sampled direction,
  heuristic over the same two densities (1 after a delta lobe, where light sampling cannot
  produce the direction).

``direct_mis`` uses them once at the first hit (N_b = ``bsdf_samples``); ``nee_path`` at every
vertex (N_b = 1: the one BSDF sample that continues the path).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import is_jit, lnot


def sample_light(scene, sel, sampler, si, active):
    """One light sample at ``si``: (ds, weight L_e G / (p(k) p_k), mask of visible samples,
    the selection's ``norm`` at ``si`` for :func:`emission_weight`)."""
    s1, s2 = sampler.next_1d(active), sampler.next_2d(active)
    ds, em_weight, norm = sel.sample_direction(si, s1, s2, active)
    act = active & dr.any(em_weight != 0)
    act &= lnot(scene.ray_test(si.spawn_ray_to(ds.p), act))
    return ds, em_weight, act, norm


def light_weight(heur, n_l: int, n_b: int, ds, bsdf_pdf):
    """MIS weight of a light sample (1 for a delta light)."""
    return dr.select(ds.delta, 1.0, heur.weight(0, [n_l * ds.pdf, n_b * bsdf_pdf]))


@dr.syntax
def light_estimate(scene, sel, heur, sampler, ctx, si, bsdf, n_l: int, n_b: int, active):
    """MIS-weighted estimate of direct light at ``si`` from ``n_l`` light samples."""
    L = mi.Spectrum(0.0)
    j = mi.UInt32(0)
    while dr.hint(j < n_l, label="light samples"):
        if is_jit() or active:
            ds, em_weight, act, _ = sample_light(scene, sel, sampler, si, active)
            f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), act)
            w = light_weight(heur, n_l, n_b, ds, pdf_b)
            L += dr.select(act, f * em_weight * w, 0.0)
        else:
            sampler.next_1d()
            sampler.next_2d()
        j += 1
    return L / n_l


def emission_weight(heur, sel, n_l: int, n_b: int, si_prev, si, bsdf_pdf, bsdf_delta, active,
                    norm=None):
    """MIS weight of emission at ``si`` reached from ``si_prev`` by BSDF sampling (``norm``:
    from a light sample at ``si_prev``, saves the adaptive selection a pass)."""
    if n_l == 0:
        return mi.Float(1.0)
    pdf_l = sel.pdf_direction(si_prev, si, active & lnot(bsdf_delta), norm)
    return dr.select(bsdf_delta, 1.0, heur.weight(1, [n_l * pdf_l, n_b * bsdf_pdf]))
