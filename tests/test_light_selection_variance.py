"""All three light selections are unbiased on the many-light plane (closed form: the sum of 64
Lambert terms), and their variance falls from uniform to power to adaptive.

Means: H0 unbiased, Student t on 32 batch means, Sidak over RGB, alpha = 1e-4, relative s.e.
< 0.5 %.  Variance order, over the pixels of an image of the floor: H0 "the median per-pixel log
variance ratio is <= 0" rejected by a one-sided Wilcoxon signed-rank test at alpha = 1e-4; the
test asserts the rejection, i.e. var(uniform) > var(power) > var(adaptive) is significant.
(At single points near the edge of the light grid power need not beat uniform.)  Also the chi-square test of the
adaptive selection: the index it draws at a fixed point follows its own pmf."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy import stats

import integrators  # noqa: F401
from integrators import testing
from integrators.sampling.light_selection import AdaptiveLightSelection
from integrators.testing import assert_unbiased
from integrators.testing.scenes import light_rect, plane_scene

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("make_many_lights",
                                               ROOT / "scenes" / "tools" / "make_many_lights.py")
many = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(many)

RHO = 0.5
POINTS = [(0.1, 0.2, 0.0), (1.9, -1.3, 0.0), (-2.6, 2.4, 0.0)]


def many_light_plane(spp=4096):
    """The diffuse floor (albedo RHO) under the 64 lights; (scene dict, expected per point)."""
    rects = [(light_rect(c, (hx, hy)), le) for c, (hx, hy), le in many.lights()]
    return plane_scene(rects, sensors_at=POINTS, spp=spp, rho=RHO, view=(0.2, -0.3, 0.4))


@pytest.fixture(scope="module")
def plane():
    d, expected = many_light_plane()
    return mi.load_dict(d), expected


@pytest.fixture(scope="module")
def batches(plane):
    scene, _ = plane
    out = {}
    for sel in ("uniform", "power", "adaptive"):
        integ = mi.load_dict({"type": "direct_mis", "light_samples": 1, "bsdf_samples": 1,
                              "heuristic": "balance", "light_selection": sel})
        out[sel] = [testing.batch_means(scene, integ, batches=32, spp=32768, sensor=j,
                                        seed0=100 * j) for j in range(len(POINTS))]
    return out


@pytest.mark.parametrize("sel", ["uniform", "power", "adaptive"])
def test_every_selection_unbiased(plane, batches, sel):
    _, expected = plane
    for j, mu in enumerate(expected):
        r = testing.mean_test(batches[sel][j], mu)
        assert r.passed and r.rel_se < 0.005, (sel, j, r)


def floor_from_above(spp: int):
    """The lit floor seen from above by a 32x32-pixel camera (scene)."""
    d, _ = many_light_plane()
    for k in [k for k in d if k.startswith("sensor")]:
        del d[k]
    d["camera"] = {"type": "perspective", "fov": 70,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 1.2], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 32, "height": 32,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}}
    return mi.load_dict(d)


@pytest.fixture(scope="module")
def pixel_variances():
    """Per-pixel variance over 16 renders of the lit floor seen from above (32x32 pixels)."""
    scene = floor_from_above(16)
    out = {}
    for sel in ("uniform", "power", "adaptive"):
        integ = mi.load_dict({"type": "direct_mis", "light_selection": sel})
        imgs = testing.batch_images(scene, integ, batches=16, spp=16)
        out[sel] = imgs[..., 0].var(axis=0, ddof=1).ravel()
    return out


@pytest.mark.parametrize("better,worse", [("power", "uniform"), ("adaptive", "power")])
def test_variance_falls(pixel_variances, better, worse):
    """H0: per-pixel log(var_worse / var_better) has median <= 0 (Wilcoxon signed-rank,
    one-sided, over 1024 pixels), rejected at alpha = 1e-4."""
    ratio = np.log(pixel_variances[worse] / pixel_variances[better])
    p = stats.wilcoxon(ratio, alternative="greater").pvalue
    assert p < 1e-4, (better, worse, float(np.median(ratio)), p)


# the adaptive pass over the 64 lights is traced unrolled (UNROLL = 64) or, with UNROLL = 0,
# as the symbolic loop of gathers used for larger scenes: both are checked
LOOP_MODES = {"unrolled": AdaptiveLightSelection.UNROLL, "loop": 0}


@pytest.mark.parametrize("mode", LOOP_MODES)
@pytest.mark.parametrize("nee", ["nee_path", "mis3"])
def test_path_integrators_unbiased_with_adaptive(plane, nee, mode, monkeypatch):
    monkeypatch.setattr(AdaptiveLightSelection, "UNROLL", LOOP_MODES[mode])
    scene, expected = plane
    integ = mi.load_dict({"type": nee, "light_selection": "adaptive", "max_depth": 2})
    assert_unbiased(scene, expected[1], integ, batches=32, spp=16384, sensor=1,
                    max_rel_se=0.01)


@pytest.mark.parametrize("mode", LOOP_MODES)
def test_adaptive_pmf_chi2(plane, mode, monkeypatch):
    """The drawn light index at a fixed shading point follows pmf_at (chi-square, alpha 5e-4
    per loop mode: 0.1 % of the suite's false-failure budget for the two)."""
    monkeypatch.setattr(AdaptiveLightSelection, "UNROLL", LOOP_MODES[mode])
    scene, _ = plane
    sel = AdaptiveLightSelection(scene)
    n = 1 << 20
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.p = mi.Point3f(0.4, -0.7, 0.0)
    si.n = mi.Vector3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    rng = np.random.default_rng(3)
    u = mi.Float(rng.random(n).astype(np.float32))
    ds, _, _ = sel.sample_direction(si, u, mi.Point2f(0.5, 0.5))
    ids = np.array(dr.reinterpret_array(mi.UInt32, ds.emitter))
    index = np.array(dr.gather(mi.UInt32, sel.index_by_id, mi.UInt32(ids)))
    counts = np.bincount(index, minlength=sel.count)
    # pmf of every light at that point
    one = dr.zeros(mi.SurfaceInteraction3f, sel.count)
    one.p = mi.Point3f(0.4, -0.7, 0.0)
    one.n = mi.Vector3f(0, 0, 1)
    pmf = np.array(sel.pmf_at(one, sel.emitters_dr), dtype=np.float64)
    assert pmf.sum() == pytest.approx(1.0, abs=1e-4)
    assert np.all(pmf > 0)
    expected = pmf / pmf.sum() * n
    keep = expected > 5
    chi2 = float(((counts[keep] - expected[keep]) ** 2 / expected[keep]).sum())
    p = stats.chi2.sf(chi2, int(keep.sum()) - 1)
    assert p > 5e-4, (chi2, p)


# ---- stratified next-event estimation: the light samples of a vertex are strata of one --------
@pytest.mark.parametrize("sel", ["power", "ris"])
def test_stratified_light_samples_unbiased(plane, sel):
    """Three light samples per vertex, strata of the first one's uniforms (``VertexEstimator.
    stratum``; for ris its candidates' strata too): H0 unbiased against the closed form (Student
    t on 32 batch means, Sidak over RGB, alpha 1e-4)."""
    scene, expected = plane
    integ = mi.load_dict({"type": "direct_mis", "light_samples": 3, "bsdf_samples": 1,
                          "light_selection": sel})
    assert_unbiased(scene, expected[0], integ, batches=32, spp=8192, sensor=0,
                    max_rel_se=0.005)


def test_stratified_light_samples_lower_variance(monkeypatch):
    """Four light samples per vertex: stratified (the default) against four independent ones
    (``STRATIFY = False``) on the floor under the 64 lights.  H0: the median per-pixel
    log(var_independent / var_stratified) is <= 0 (one-sided Wilcoxon signed-rank over 1024
    pixels), rejected at alpha = 1e-4; with independent samples on both sides the test is not
    rejected (mutant in tests/mutants_light_tree.py).  Measured there: the mean pixel variance
    of independent samples is 1.74x the stratified one's (power, whose cumulative pmf runs
    along a Morton curve of the lights; 1.61x bvh, 1.26x ris, 1.06x adaptive, whose pmf at a
    point is already concentrated on few lights).  Before that order was fixed, power's
    cumulative pmf followed Mitsuba's emitter order, which changes between processes, and
    the gain went from 1.0x to 1.9x with it (this test then failed in 6 of 27 runs)."""
    from integrators.sampling.vertex import VertexEstimator
    scene = floor_from_above(4)
    var = {}
    for stratify in (True, False):
        monkeypatch.setattr(VertexEstimator, "STRATIFY", stratify)
        integ = mi.load_dict({"type": "direct_mis", "light_samples": 4, "bsdf_samples": 1,
                              "light_selection": "power"})
        imgs = testing.batch_images(scene, integ, batches=16, spp=4, seed0=7)
        var[stratify] = imgs[..., 0].var(axis=0, ddof=1).ravel()
    ratio = np.log(var[False] / var[True])
    p = stats.wilcoxon(ratio, alternative="greater").pvalue
    assert p < 1e-4, (float(np.median(ratio)), p)
