"""Spectral validation: the 24 ColorChecker patches rendered by our integrators in
``llvm_ad_spectral`` have colour-science's sRGB under D65 (scenes/colour_checker.xml, made by
scenes/tools/make_colour_checker.py: measured reflectance spectra, a D65 environment).

What is compared: the mean linear sRGB over each patch's 100 pixels against
``make_colour_checker.expected_srgb()`` (colour-science: the same spectra integrated against
the CIE 1931 colour matching functions, XYZ to sRGB), as CIEDE2000 (colour-science's
``delta_E``, method "CIE 2000", in L*a*b* with sRGB's D65 white).

**The bound: every patch within Delta E00 = 0.5**, half of the just-noticeable difference (about
1).  Why it holds for a correct estimator: the radiance of a patch is exactly rho(lambda)
E(lambda) (coplanar diffuse patches under a uniform environment: no occlusion, no
inter-reflection), so the only differences are Monte Carlo noise and the renderer's own
tabulation of the colour matching functions and sRGB matrix.  Measured with Mitsuba's own
``path`` at 4096 spp: at most 0.07 (mean 0.03).  The noise is bounded before the verdict: every
patch's standard error (from the per-pass spread, 8 passes) must be below 0.5 % of its largest
channel, and Delta E between the estimate and the estimate moved by 3 standard errors must stay
below 0.25, so noise cannot push a correct render past 0.5 (a 3-sigma excursion, about 0.3 % per
channel per patch, and 72 such channel values: a false failure needs a 6-sigma miss of the
remaining margin) and cannot hide a 5 % error.

**It can fail** (negative controls, same render and comparison): every albedo 5 % low (the
emitter scaled by 0.95: Delta E00 up to 1.18 predicted) and the illuminant left as an
equal-energy spectrum instead of D65 (up to 10.6), both rendered by ``nee_path``, must exceed the
bound.  Mitsuba's ``path`` is the positive control: the bound is achievable by the reference.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("colour")

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "colour_checker.xml"
sys.path.insert(0, str(ROOT / "scenes" / "tools"))
import make_colour_checker as cc  # noqa: E402

BOUND = 0.5                # CIEDE2000, every patch
NOISE_BOUND = 0.25         # Delta E00 of a 3-standard-error move, every patch
MAX_REL_SE = 0.005         # per patch and channel
SPP, PASSES = 2048, 8

_SCRIPT = r"""
import json, sys
import numpy as np
import mitsuba as mi
mi.set_variant("llvm_ad_spectral")
import integrators
from integrators.app import progressive
sys.path.insert(0, {tools!r})
import make_colour_checker as cc
out = {{}}
for label, integ, defines in {jobs!r}:
    scene = mi.load_file({scene!r}, integrator=integ, **defines)
    acc = progressive.render(scene, spp={spp}, seed=7)
    assert acc.passes == {passes}, acc.passes
    mean, var = acc.mean(), acc.variance()
    rgb, se = [], []
    for k in range(24):
        rows, cols = cc.patch_pixels(k, margin=0)
        n = mean[rows, cols].shape[0] * mean[rows, cols].shape[1]
        rgb.append(mean[rows, cols].reshape(-1, 3).mean(0).tolist())
        se.append(np.sqrt(var[rows, cols].reshape(-1, 3).sum(0)).tolist())
        se[-1] = [x / n for x in se[-1]]
    out[label] = {{"rgb": rgb, "se": se, "variant": mi.variant()}}
print("RESULT " + json.dumps(out))
"""


def _render(jobs, spp=SPP):
    code = _SCRIPT.format(tools=str(ROOT / "scenes" / "tools"), jobs=jobs, scene=str(SCENE),
                          spp=spp, passes=PASSES)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=ROOT, timeout=1200)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    assert r.returncode == 0 and lines, r.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


def _verdict(res, truth):
    """(max Delta E00 over the patches, max noise Delta E00, max relative SE, per-patch dE)."""
    rgb, se = np.array(res["rgb"]), np.array(res["se"])
    de = cc.delta_e2000(rgb, truth)
    noise = cc.delta_e2000(rgb, rgb + 3 * se)
    rel = se / np.maximum(np.abs(rgb).max(axis=1, keepdims=True), 1e-12)
    return float(de.max()), float(noise.max()), float(rel.max()), de


@pytest.fixture(scope="module")
def renders():
    wl, e95 = cc.illuminant_values("D65", 0.95)
    wl, eE = cc.illuminant_values("E")
    jobs = [("path", "path", {}), ("nee_path", "nee_path", {}), ("mis3", "mis3", {}),
            ("direct_mis", "direct_mis", {}),
            ("albedo_0.95", "nee_path", {"illuminant": cc.pairs(wl, e95)}),
            ("illuminant_E", "nee_path", {"illuminant": cc.pairs(wl, eE)})]
    return _render(jobs)


def test_the_scene_file_is_what_the_generator_writes():
    assert SCENE.read_text() == cc.xml(), "run scenes/tools/make_colour_checker.py"


def test_expected_values_are_colour_sciences_own():
    """The truth integrates the scene's spectra; colour-science's standard route (its own
    interpolation and the ASTM E308 tables) gives the same patches within 0.1 Delta E00."""
    import colour
    truth = cc.expected_srgb()
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    std = []
    for sd in colour.SDS_COLOURCHECKERS[cc.DATASET].values():
        xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"]) / 100
        std.append(colour.XYZ_to_RGB(xyz, srgb, apply_cctf_encoding=False))
    assert cc.delta_e2000(truth, np.array(std)).max() < 0.1
    assert truth[18].min() > 0.8 and np.ptp(truth[18]) < 0.02   # white 9.5 is nearly white
    assert truth[5, 0] < 0 or truth[17, 0] < 0     # cyan lies outside sRGB: negative red


@pytest.mark.parametrize("label", ["path", "nee_path", "mis3", "direct_mis"])
def test_colour_checker_within_the_bound(renders, label):
    res = renders[label]
    assert res["variant"] == "llvm_ad_spectral"
    de_max, noise, rel, de = _verdict(res, cc.expected_srgb())
    assert rel < MAX_REL_SE, f"{label}: too noisy to judge (relative SE {rel:.4f})"
    assert noise < NOISE_BOUND, f"{label}: noise Delta E00 {noise:.3f}"
    assert de_max <= BOUND, (f"{label}: Delta E00 up to {de_max:.3f} (patch "
                             f"{int(np.argmax(de)) + 1}), bound {BOUND}; per patch "
                             f"{np.round(de, 3).tolist()}")


@pytest.mark.parametrize("label,at_least", [("albedo_0.95", 0.8), ("illuminant_E", 5.0)])
def test_negative_controls_are_caught(renders, label, at_least):
    de_max, noise, rel, _ = _verdict(renders[label], cc.expected_srgb())
    assert rel < MAX_REL_SE and noise < NOISE_BOUND
    assert de_max > BOUND and de_max > at_least, f"{label}: Delta E00 only {de_max:.3f}"


@pytest.mark.slow
def test_colour_checker_bsdf_path():
    """BSDF sampling only (``bsdf_path``) under the same bound (slow: its own render)."""
    res = _render([("bsdf_path", "bsdf_path", {})])["bsdf_path"]
    de_max, noise, rel, de = _verdict(res, cc.expected_srgb())
    assert rel < MAX_REL_SE and noise < NOISE_BOUND, (rel, noise)
    assert de_max <= BOUND, (de_max, np.round(de, 3).tolist())


def test_experiments_de2000_metric():
    """benchmarks.metrics' CIEDE2000 (the experiments' colour error): zero for equal images, the
    colour-science value of a known pair, display-referred (values above 1 clipped)."""
    from benchmarks.metrics import Ciede2000, errors
    truth = cc.expected_srgb().reshape(4, 6, 3)
    low = truth * 0.95
    m = Ciede2000()
    assert m.reason is None
    assert m(truth, truth) == 0.0
    want = float(np.mean(cc.delta_e2000(np.clip(truth, 0, 1), np.clip(low, 0, 1))))
    assert m(truth, low) == pytest.approx(want, rel=1e-9) and 0.8 < want < 1.2
    assert m(np.full((2, 2, 3), 5.0), np.full((2, 2, 3), 1.0)) == 0.0      # both clip to white
    e = errors(low, truth, None, None, None, m)
    assert e["de2000"] == pytest.approx(want, rel=1e-9) and e["finite"]
