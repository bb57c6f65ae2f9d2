"""Writes scenes/colour_checker.xml: the 24 patches of the ColorChecker as diffuse rectangles with
their measured reflectance spectra (colour-science's "ColorChecker N Ohta"), under a constant
environment emitting CIE illuminant D65 (colour-science's table), seen by an orthographic
camera.  Run from the repository root: ``.venv/bin/python scenes/tools/make_colour_checker.py``.

Why this scene measures spectral rendering: each patch is a one-sided diffuse plane under a
uniform environment and nothing can occlude or inter-reflect (the patches are coplanar), so the
radiance leaving patch k is exactly L_k(lambda) = rho_k(lambda) E(lambda), E the environment's
spectrum, at every path depth.  A spectral renderer's RGB film integrates L_k against the CIE
1931 colour matching functions (normalised by the integral of y-bar: an equal-energy spectrum 1
has Y = 1, Mitsuba's convention) and converts XYZ to linear sRGB.  The environment is D65
scaled so that a perfect white reflector has Y = 1: the pixels of patch k then hold the linear
sRGB of the patch under D65, which colour-science computes independently from the same spectra
(:func:`expected_srgb`).

Spectra are written at 5 nm from 360 to 830 nm (Mitsuba's spectral range): the patch data
(380-780 nm) and D65 (300-780 nm) are extended with constant values at the ends (colour-science's
default extrapolation); Mitsuba interpolates linearly between the given wavelengths, and
:func:`expected_srgb` integrates the same linearly interpolated spectra at 1 nm.

Layout: 6 x 4 patches in the standard order (row 1: dark skin ... bluish green; row 4: white
9.5 ... black 2), patch 1 unit wide, pitch 1.2; the film is 12 pixels per pitch (72 x 48), so each patch covers 10 x 10 pixels exactly (box filter: no pixel mixes a patch
with its surroundings).  :func:`patch_pixels` gives the pixels of each patch.

Defines: ``integrator`` (default ``nee_path``; any integrator without required parameters),
``spp``, ``illuminant`` (the emitter's spectrum as "wavelength:value, ..." pairs; default D65
normalised as above: negative controls pass another).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "scenes" / "colour_checker.xml"
DATASET = "ColorChecker N Ohta"
COLS, ROWS = 6, 4
PITCH, SIZE = 1.2, 1.0            # world units
PX_PER_PITCH = 12                  # pixels per pitch
LO, HI, STEP = 360, 830, 5         # nm: Mitsuba's spectral range


def _colour():
    import warnings

    import colour
    warnings.filterwarnings("ignore", module="colour")
    return colour


def _aligned(sd, step):
    """``sd`` on LO..HI nm at ``step`` nm: constant beyond its ends, linear in between."""
    colour = _colour()
    return sd.copy().align(colour.SpectralShape(LO, HI, step),
                           interpolator=colour.LinearInterpolator)


def patches():
    """[(name, wavelengths, reflectances)] of the 24 patches, in the standard order, at 5 nm."""
    colour = _colour()
    sds = colour.SDS_COLOURCHECKERS[DATASET]
    out = []
    for name, sd in sds.items():
        a = _aligned(sd, STEP)
        out.append((name, a.wavelengths.copy(), np.clip(a.values.copy(), 0.0, 1.0)))
    return out


def illuminant_sd(name="D65"):
    """colour-science's spectral distribution of illuminant ``name`` ("E": equal energy)."""
    colour = _colour()
    if name == "E":
        return colour.sd_ones(colour.SpectralShape(LO, HI, STEP))
    return colour.SDS_ILLUMINANTS[name]


def _cmfs_1nm():
    colour = _colour()
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return cmfs.copy().align(colour.SpectralShape(LO, HI, 1))


def illuminant_values(name="D65", scale=1.0):
    """(wavelengths at 5 nm, values) of illuminant ``name`` times the factor that gives a
    perfect white reflector Y = 1 in Mitsuba's convention (Y = int S y-bar / int y-bar), times
    ``scale`` (a negative control may pass 0.9: the same as every albedo 10 % low)."""
    a = _aligned(illuminant_sd(name), STEP)
    wl, v = a.wavelengths.copy(), a.values.copy()
    lam1 = np.arange(LO, HI + 1, 1.0)
    ybar = _cmfs_1nm().values[:, 1]
    k = ybar.sum() / (np.interp(lam1, wl, v) * ybar).sum()
    return wl, v * k * scale


def pairs(wl, values) -> str:
    return ", ".join(f"{w:g}:{v:.6g}" for w, v in zip(wl, values))


def expected_srgb(illuminant="D65", scale=1.0) -> np.ndarray:
    """(24, 3) linear sRGB of the patches lit by ``illuminant`` (normalised as in
    :func:`illuminant_values`, times ``scale``), computed by colour-science: ``sd_to_XYZ``
    (integration at 1 nm against CIE 1931 2 degrees, equal-energy normalisation, as the
    renderer's film) of the emitted spectra rho E interpolated linearly like the scene's, then
    ``XYZ_to_RGB`` into sRGB (linear, no adaptation: sRGB's white is D65)."""
    colour = _colour()
    wl_e, e = illuminant_values(illuminant, scale)
    lam1 = np.arange(LO, HI + 1, 1.0)
    shape = colour.SpectralShape(LO, HI, 1)
    cmfs = _cmfs_1nm()
    ones = colour.sd_ones(shape)
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    out = []
    for _, wl, rho in patches():
        emitted = np.interp(lam1, wl, rho) * np.interp(lam1, wl_e, e)
        sd = colour.SpectralDistribution(emitted, lam1)
        xyz = colour.sd_to_XYZ(sd, cmfs, ones, method="Integration") / 100.0
        out.append(colour.XYZ_to_RGB(xyz, srgb, apply_cctf_encoding=False))
    return np.array(out)


def lab(rgb_linear) -> np.ndarray:
    """CIE L*a*b* (D65 white) of linear sRGB values (colour-science)."""
    colour = _colour()
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(np.asarray(rgb_linear, dtype=np.float64), srgb,
                            apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, srgb.whitepoint)


def delta_e2000(rgb_a, rgb_b) -> np.ndarray:
    """CIEDE2000 between linear sRGB values (colour-science's ``delta_E``, method CIE 2000)."""
    return np.asarray(_colour().delta_E(lab(rgb_a), lab(rgb_b), method="CIE 2000"))


def patch_centre(k: int) -> tuple:
    col, row = k % COLS, k // COLS
    return ((col - (COLS - 1) / 2) * PITCH, ((ROWS - 1) / 2 - row) * PITCH)


def film_size() -> tuple:
    return COLS * PX_PER_PITCH, ROWS * PX_PER_PITCH


def patch_pixels(k: int, margin: int = 1) -> tuple:
    """(row slice, column slice) of the pixels entirely inside patch ``k``, ``margin`` pixels
    in from its edges."""
    px = PX_PER_PITCH / PITCH                    # pixels per world unit
    col, row = k % COLS, k // COLS
    first = round(((PITCH - SIZE) / 2) * px) + margin
    n = round(SIZE * px) - 2 * margin
    y0, x0 = row * PX_PER_PITCH + first, col * PX_PER_PITCH + first
    return slice(y0, y0 + n), slice(x0, x0 + n)


def xml() -> str:
    wl_e, e = illuminant_values("D65")
    w, h = COLS * PITCH, ROWS * PITCH
    lines = [
        '<?xml version="1.0"?>',
        '<!-- Generated by scenes/tools/make_colour_checker.py: the 24 ColorChecker patches',
        f'     (colour-science "{DATASET}" reflectance spectra) under a constant environment of',
        '     CIE D65 (normalised: a white reflector has Y = 1), orthographic camera, box filter.',
        '     Render it in a spectral variant (llvm_ad_spectral); each patch covers 10 x 10 pixels',
        '     (see the generator for the layout and the expected sRGB). -->',
        '<scene version="3.0.0">',
        '    <default name="integrator" value="nee_path"/>',
        '    <default name="spp" value="64"/>',
        f'    <default name="illuminant" value="{pairs(wl_e, e)}"/>',
        '    <integrator type="$integrator"/>',
        '    <sensor type="orthographic">',
        '        <transform name="to_world">',
        f'            <scale x="{w / 2:g}" y="{w / 2:g}"/>',
        '            <lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>',
        '        </transform>',
        '        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>',
        '        <film type="hdrfilm">',
        f'            <integer name="width" value="{COLS * PX_PER_PITCH}"/>',
        f'            <integer name="height" value="{ROWS * PX_PER_PITCH}"/>',
        '            <rfilter type="box"/>',
        '        </film>',
        '    </sensor>',
        '    <emitter type="constant">',
        '        <spectrum name="radiance" value="$illuminant"/>',
        '    </emitter>',
    ]
    for k, (name, wl, rho) in enumerate(patches()):
        cx, cy = patch_centre(k)
        lines += [
            f'    <!-- {k + 1}: {name} -->',
            '    <shape type="rectangle">',
            '        <transform name="to_world">',
            f'            <scale value="{SIZE / 2:g}"/><translate x="{cx:.6g}" y="{cy:.6g}"/>',
            '        </transform>',
            f'        <bsdf type="diffuse"><spectrum name="reflectance" value="{pairs(wl, rho)}"/>'
            '</bsdf>',
            '    </shape>',
        ]
    lines.append('</scene>')
    return "\n".join(lines) + "\n"


def main():
    OUT.write_text(xml())
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
