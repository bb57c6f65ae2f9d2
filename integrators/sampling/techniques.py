r"""Direction-sampling techniques at a surface other than the BSDF's own ``sample``.

* :func:`hemisphere_sample` - the lecture's "general path tracing" densities: ``uniform``
  p = 1/(2 pi) or ``cosine`` p = cos(theta)/pi over the hemisphere on the side of the incident
  direction (the whole sphere, each half with probability 1/2, for a BSDF that transmits), or
  ``bsdf``: ``BSDF.sample``.  A BSDF with a delta lobe is sampled with ``BSDF.sample`` at that
  vertex, since no density over directions can hit a delta lobe.
* **Lobe techniques** (``mis3``): any Mitsuba BSDF split by its component flags through
  ``BSDFContext.type_mask``: components with ``DiffuseReflection``/``DiffuseTransmission`` form
  the *cosine* technique; components with ``Glossy*``, ``Delta*`` or ``Null`` flags (a
  ``null`` surface passes the ray on) form the *glossy* technique.  :func:`lobe_contexts` gives
  the two contexts; with one of them a BSDF's ``pdf`` is that lobe's own pdf (``phong``,
  ``plastic``, ``roughplastic``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import is_jit, lnot, safe_div

HEMISPHERE = ("uniform", "cosine", "bsdf")

DIFFUSE = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.DiffuseTransmission
GLOSSY = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.GlossyTransmission |
          mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.Null)
#: delta reflection, delta transmission and null (Mitsuba's ``Delta`` includes ``Null``)
DELTA = mi.BSDFFlags.Delta


def hemisphere_sample(mode: str, ctx, bsdf, si, s1, s2, active):
    """One direction at ``si`` by technique ``mode``: (wo local, f cos / pdf, eta)."""
    if bsdf is None:  # scalar variants, no surface
        return mi.Vector3f(0, 0, 1), mi.Spectrum(0.0), mi.Float(1.0)
    if mode == "bsdf":
        bs, weight = bsdf.sample(ctx, si, s1, s2, active)
        return bs.wo, weight, bs.eta
    flags = bsdf.flags()
    use_bsdf = mi.has_flag(flags, mi.BSDFFlags.Delta)
    sphere = mi.has_flag(flags, mi.BSDFFlags.Transmission)
    if mode == "uniform":
        wo = mi.warp.square_to_uniform_hemisphere(s2)
        pdf = mi.Float(dr.inv_two_pi)
    else:
        wo = mi.warp.square_to_cosine_hemisphere(s2)
        pdf = wo.z * dr.inv_pi
    side = dr.select(mi.Frame3f.cos_theta(si.wi) < 0, -1.0, 1.0)
    flip = sphere & (s1 < 0.5)
    wo.z = wo.z * dr.select(flip, -side, side)
    pdf = pdf * dr.select(sphere, 0.5, 1.0)
    weight = safe_div(bsdf.eval(ctx, si, wo, active & lnot(use_bsdf)), pdf)
    eta = mi.Float(1.0)
    if is_jit() or use_bsdf:
        bs, w_b = bsdf.sample(ctx, si, s1, s2, active & use_bsdf)
        wo = dr.select(use_bsdf, bs.wo, wo)
        weight = dr.select(use_bsdf, w_b, weight)
        eta = dr.select(use_bsdf, bs.eta, eta)
    return wo, weight, eta


def lobe_contexts():
    """(context of every lobe, of the cosine technique, of the glossy technique)."""
    ctx, ctx_d, ctx_g = mi.BSDFContext(), mi.BSDFContext(), mi.BSDFContext()
    ctx_d.type_mask = int(DIFFUSE)
    ctx_g.type_mask = int(GLOSSY)
    return ctx, ctx_d, ctx_g
