r"""BSDF ``phong``: the lecture's "mixed material", a modified (energy-normalised) Phong BRDF.

    f(omega_i, omega_o) = rho_d / pi  +  rho_g (e + 2) / (2 pi) cos^e(alpha)

alpha is the angle between the outgoing direction and the mirror direction of the incident one
(the same angle either way round, so f is symmetric).  ``diffuse_reflectance`` = rho_d,
``specular_reflectance`` = rho_g (both textures), ``exponent`` = e.

Normalisation: the glossy lobe's albedo is at most rho_g (exactly rho_g at normal incidence,
less elsewhere because of the horizon and the cosine), so the BSDF conserves energy iff
rho_d + rho_g <= 1, which the constructor enforces (per texture maximum).

Components (ask ``flags(i)``; the numbering is fixed):

* 0 - diffuse lobe, ``DiffuseReflection | FrontSide``, sampled with pdf cos(theta_o) / pi;
* 1 - glossy lobe, ``GlossyReflection | FrontSide``, sampled with pdf
  (e + 1) / (2 pi) cos^e(alpha) around the mirror direction.  Directions below the horizon are
  invalid samples (zero weight), so this pdf integrates to less than one over the hemisphere.

``BSDFContext.component`` and ``type_mask`` select lobes: ``eval`` returns the enabled lobes only;
with one lobe enabled ``pdf`` is that lobe's own pdf (the convention of Mitsuba's ``plastic``);
with both, sampling picks a lobe with probability proportional to its albedo (mean of rho over
the channels) and ``pdf`` is the mixture pdf.  One-sided like ``diffuse``: zero below the
geometric/shading horizon (wrap it in ``twosided`` for two sides).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import channel_mean, safe_div
from ..params import Param, ParameterError, read
from ..registry import plugin

DIFFUSE, GLOSSY = 0, 1


@plugin("phong", "bsdf")
class Phong:
    """Modified Phong BSDF (diffuse + normalised glossy lobe), the lecture's mixed material."""

    PARAMS = (
        Param("diffuse_reflectance", "texture", 0.5, doc="rho_d, diffuse albedo (texture)."),
        Param("specular_reflectance", "texture", 0.2, doc="rho_g, glossy albedo (texture)."),
        Param("exponent", "float", 30.0, min=0.0, max=1e6, doc="Phong exponent e."),
    )

    def __init__(self, props):
        self._base.__init__(self, props)
        p = read("phong", self.PARAMS, props)
        self.exponent = p["exponent"]
        self.kd = props.get_texture("diffuse_reflectance", 0.5)
        self.ks = props.get_texture("specular_reflectance", 0.2)
        for name, tex in (("diffuse_reflectance", self.kd), ("specular_reflectance", self.ks)):
            lo = _texture_min(tex)
            if lo is not None and lo < 0:
                raise ParameterError(f"phong: parameter '{name}' has a negative value; "
                                     "allowed: reflectances in [0, 1]")
        total = float(dr.max(self.kd.max())) + float(dr.max(self.ks.max()))
        if total > 1.0 + 1e-5:
            raise ParameterError(
                f"phong: diffuse_reflectance + specular_reflectance = {total:.4g} exceeds 1 "
                "(max over the texture and channels); allowed: a sum <= 1 (energy conservation)")
        flags_d = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        flags_g = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        self.m_components = [flags_d, flags_g]
        self.m_flags = flags_d | flags_g

    # -- helpers -------------------------------------------------------------------------
    def _enabled(self, ctx):
        return (ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, DIFFUSE),
                ctx.is_enabled(mi.BSDFFlags.GlossyReflection, GLOSSY))

    def _glossy_prob(self, si, active):
        """Probability of picking the glossy lobe when both are enabled (albedo ratio)."""
        wd = channel_mean(self.kd.eval(si, active))
        wg = channel_mean(self.ks.eval(si, active))
        return safe_div(wg, wd + wg)

    def _lobes(self, si, wo):
        """(cos theta_o, cos^e(alpha) with alpha measured from the mirror direction)."""
        r = mi.reflect(si.wi)
        cos_alpha = dr.dot(r, wo)
        # e = 0 gives a constant lobe on the hemisphere around the mirror direction
        lobe = dr.select(cos_alpha > 0, dr.power(dr.maximum(cos_alpha, 1e-30), self.exponent), 0.0)
        return mi.Frame3f.cos_theta(wo), lobe

    def _pdfs(self, si, wo):
        cos_o, lobe = self._lobes(si, wo)
        pdf_d = dr.maximum(cos_o, 0.0) * dr.inv_pi
        pdf_g = (self.exponent + 1.0) * dr.inv_two_pi * lobe
        return pdf_d, pdf_g

    def _pdf(self, ctx, si, wo, active):
        en_d, en_g = self._enabled(ctx)
        if not (en_d or en_g):
            return mi.Float(0.0)
        active = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        pdf_d, pdf_g = self._pdfs(si, wo)
        if en_d and en_g:
            pg = self._glossy_prob(si, active)
            pdf = (1.0 - pg) * pdf_d + pg * pdf_g
        else:
            pdf = pdf_d if en_d else pdf_g
        return dr.select(active, pdf, 0.0)

    # -- BSDF interface ------------------------------------------------------------------
    def eval(self, ctx, si, wo, active=True):
        en_d, en_g = self._enabled(ctx)
        if not (en_d or en_g):
            return mi.Spectrum(0.0)
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o, lobe = self._lobes(si, wo)
        active = active & (cos_i > 0) & (cos_o > 0)
        value = mi.Spectrum(0.0)
        if en_d:
            value += self.kd.eval(si, active) * dr.inv_pi
        if en_g:
            value += self.ks.eval(si, active) * ((self.exponent + 2.0) * dr.inv_two_pi * lobe)
        return dr.select(active, value * cos_o, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        return self._pdf(ctx, si, wo, active)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self._pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        en_d, en_g = self._enabled(ctx)
        bs = dr.zeros(mi.BSDFSample3f)
        if not (en_d or en_g):
            return bs, mi.Spectrum(0.0)
        active = active & (mi.Frame3f.cos_theta(si.wi) > 0)
        if en_d and en_g:
            pick_glossy = sample1 < self._glossy_prob(si, active)
        else:
            # full-width mask, so every field of the sample has the width of the query
            pick_glossy = (sample1 >= 0.0) if en_g else (sample1 < 0.0)
        wo_d = mi.warp.square_to_cosine_hemisphere(sample2)
        # glossy: cos(alpha) = u^(1/(e+1)) around the mirror direction
        cos_a = dr.power(sample2.x, 1.0 / (self.exponent + 1.0))
        sin_a = dr.safe_sqrt(1.0 - cos_a * cos_a)
        s, c = dr.sincos(dr.two_pi * sample2.y)
        wo_g = mi.Frame3f(mi.reflect(si.wi)).to_world(mi.Vector3f(sin_a * c, sin_a * s, cos_a))
        bs.wo = dr.select(pick_glossy, wo_g, wo_d)
        bs.eta = 1.0
        bs.sampled_component = dr.select(pick_glossy, mi.UInt32(GLOSSY), mi.UInt32(DIFFUSE))
        bs.sampled_type = dr.select(pick_glossy, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        value, pdf = self.eval_pdf(ctx, si, bs.wo, active)
        bs.pdf = pdf
        active = active & (pdf > 0) & (mi.Frame3f.cos_theta(bs.wo) > 0)
        weight = dr.select(active, value / dr.select(pdf > 0, pdf, 1.0), 0.0)
        bs.pdf = dr.select(active, pdf, 0.0)
        return bs, weight

    def eval_diffuse_reflectance(self, si, active=True):
        return self.kd.eval(si, active)

    def traverse(self, callback):
        callback.put("diffuse_reflectance", self.kd, mi.ParamFlags.Differentiable)
        callback.put("specular_reflectance", self.ks, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        pass

    def to_string(self):
        return (f"Phong[\n  diffuse_reflectance = {self.kd},\n"
                f"  specular_reflectance = {self.ks},\n  exponent = {self.exponent}\n]")


def _texture_min(tex):
    """Smallest value of a constant texture (None when it varies spatially)."""
    if tex.is_spatially_varying():
        return None
    si = dr.zeros(mi.SurfaceInteraction3f)
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(550.0)
    value = np.array(mi.unpolarized_spectrum(tex.eval(si)), dtype=np.float64)
    return float(value.min())
