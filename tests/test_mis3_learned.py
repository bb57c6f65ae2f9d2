"""mis3 selection=learned: unbiased whatever was learned.

The light-sample probability of each region is learned between passes; the estimator weights
every light sample and every emission hit for the probability it was drawn with (and above one,
an expected number of light samples: floor or ceil of it, averaged, at the drawn count's
effective density), so any table of values in [0.05, 4] must give an unbiased image.  Checks (the kit's alpha 1.5e-5,
relative s.e. < 0.5 %):
* closed emitting box, H0 L = 2: learning across passes (each batch is a pass that updates the
  table), and a frozen table of random probabilities;
* Lambert's formula for rectangle and point lights (delta lights need the floor): frozen random
  tables;
* ``scenes/specular_box.xml`` against Mitsuba's ``path`` (H0 same expected image) after
  learning on it.
"""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.testing import assert_unbiased
from integrators.testing.scenes import closed_box_scene, plane_scene

ROOT = Path(__file__).resolve().parents[1]
LEARNED = {"type": "mis3", "selection": "learned"}


def frozen_random(scene, integ_dict, seed):
    """A learned-mode integrator whose table holds random values, frozen: light-sample
    probabilities below one and expected light-sample counts up to 4 (log-uniform)."""
    integ = mi.load_dict(integ_dict)
    mi.render(scene, integrator=integ, spp=1)          # builds the grid for this scene
    rng = np.random.default_rng(seed)
    table = np.exp(rng.uniform(np.log(0.05), np.log(4.0), integ.grid.size))
    integ.grid.set_table(table.astype(np.float32))
    integ.learning = False
    return integ


def test_closed_box_while_learning():
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    assert_unbiased(scene, 2.0, mi.load_dict(LEARNED), spp=4096, max_spp=16 * 4096)


@pytest.mark.parametrize("seed", [1, 2])
def test_closed_box_random_frozen_table(seed):
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    integ = frozen_random(scene, LEARNED, seed)
    assert_unbiased(scene, 2.0, integ, spp=4096, max_spp=16 * 4096)


def test_lambert_random_frozen_table_with_point_lights():
    d, expected = plane_scene(points=[((0.5, -0.4, 0.8), 0.7)])
    scene = mi.load_dict(d)
    integ = frozen_random(scene, {**LEARNED, "max_depth": 2}, 3)
    assert_unbiased(scene, expected, integ, sensor=range(len(expected)), batches=32,
                    spp=16384, max_rel_se=0.01)


def test_specular_box_after_learning():
    scene = mi.load_file(str(ROOT / "scenes" / "specular_box.xml"), res="24")
    integ = mi.load_dict({**LEARNED, "max_depth": 6})
    for k in range(4):                                   # learn first
        mi.render(scene, integrator=integ, spp=2048, seed=10_000 + k)
    assert (integ.grid.table() > 0).any()
    ref = testing.batch_images(scene, mi.load_dict({"type": "path", "max_depth": 6}),
                               batches=16, spp=1024, seed0=777)
    assert_unbiased(scene, ref, integ, spp=2048, batches=16, block=8, max_rel_se=0.01)


def test_run_record_says_how_it_learned(tmp_path):
    """``render`` writes the integrator's ``run_notes()`` into the run record: for the learned
    allocation, how many passes recorded statistics, whether learning settled, how many regions
    learned, the spread of what they chose, and the objective (the image's relMSE x cost once
    the pixels were measured, with the image's variance and cost per camera sample)."""
    from integrators.app import progressive
    scene = mi.load_dict({**closed_box_scene(0.5, 1.0), "integrator": {"type": "mis3"}})
    acc = progressive.render(scene, spp=256)
    notes = acc.run_record().notes
    assert notes["selection"] == "learned" and notes["recorded_passes"] >= 1, notes
    assert {"settled", "regions_learned"} <= set(notes), notes
    assert notes["objective"] == "image relMSE x cost", notes
    assert notes["image_rel_variance_per_sample"] > 0 and notes["cost_per_sample"] >= 2, notes


def _trapezoid(y, x):
    return float(np.sum((y[1:] + y[:-1]) * np.diff(x)) / 2)


@pytest.mark.parametrize("c", [0.35, 1.0, 1.5, 2.0, 4.0])
def test_allocation_variance_is_the_estimators_variance(c):
    """The variance model the learned allocation minimises (``allocation_variance``) equals
    the variance of the estimator it models, on a 1-D integrand with a light and a BSDF
    density: c <= 1 light samples with probability c, c > 1 floor(c) or ceil(c) light samples
    by stochastic rounding (as ``VertexEstimator.direct`` draws them), and one BSDF sample,
    balance heuristic (with m light samples each sample adds f / (m p_l + p_b)).  H0: the
    sample variance of 400,000 estimates has the model's expectation; the sample variance's
    relative s.e. is below 1 % here, so 5 % (5 s.e.) fails at about 3e-7.  Negative control:
    the old model M - mu^2 is rejected (here it is negative for every c, -0.4 to -1.4 against
    variances of 0.03-0.37: clamped to zero, every allocation looked free of variance)."""
    from integrators.plugins.mis3 import allocation_variance
    x = np.linspace(0.0, 1.0, 200_001)[1:-1]
    f = 1.0 + 4.0 * np.exp(-((x - 0.8) / 0.05) ** 2)           # a bump the light sees
    p_l = 6.0 * x * (1.0 - x) * 0.3 + 0.7 * np.exp(-((x - 0.8) / 0.07) ** 2) / 0.1240
    p_l /= _trapezoid(p_l, x)
    p_b = np.ones_like(x)
    cands = [1.0, 1.5, 2.0] if c == 1.5 else [c]
    second, mean_l = [], []
    for k in cands:
        q = k * p_l + p_b
        second.append(_trapezoid(f * f / q, x))
        mean_l.append(_trapezoid(f * k * p_l / q, x))
    mean = _trapezoid(f, x)
    model = float(allocation_variance([second], [mean], [mean_l], cands)[0, cands.index(c)])

    rng = np.random.default_rng(11)
    n = 400_000
    cdf = np.cumsum(p_l)
    cdf /= cdf[-1]

    def estimate(m):        # c <= 1: m = c (one light sample with probability c)
        q = m * p_l + p_b
        est = np.interp(rng.random(n), x, f / q)                    # the BSDF sample
        if m <= 1.0:
            take = rng.random(n) < m
            light = (f / q)[np.clip(np.searchsorted(cdf, rng.random(n)), 0, x.size - 1)]
            return est + np.where(take, light, 0.0)
        for _ in range(int(m)):
            est = est + (f / q)[np.clip(np.searchsorted(cdf, rng.random(n)), 0, x.size - 1)]
        return est
    if c > 1.0 and c != int(c):
        lo = int(np.floor(c))
        est = np.where(rng.random(n) < c - lo, estimate(lo + 1), estimate(lo))
    else:
        est = estimate(c)
    assert abs(est.mean() - mean) < 5 * est.std() / np.sqrt(n)      # the estimator is right
    assert abs(est.var() / model - 1.0) < 0.05, (est.var(), model)
    old = second[cands.index(c)] - mean ** 2
    assert old < 0.9 * est.var(), (old, est.var())


def _region_statistics(k, v_rest, spread=1.0, n=1000, n_paths=500, weight=1.0):
    """One region's statistics (the layout of mis3's RegionGrid): a vertex whose light
    technique carries the whole mean mu = 1, pooled second moment M(c) = 2 / c over points
    whose light share's squared mean averages ``spread`` (per-point noise (2 - spread) / c at
    c >= 1 light samples: spread 1, variance 1 / c; spread 1.9, 0.1 / c and the rest variation
    of the mean between points); recorded paths whose variance is the pooled one at one light
    sample plus v_rest, their cost 2 vertices more than the vertex's own; every visit's pixel
    of relMSE weight ``weight``."""
    from integrators.plugins import mis3 as M
    cand = np.array(M.LEARNED_P)
    st = np.zeros(M.WEIGHT + 2)
    st[:k] = n * 2.0 / cand                                         # M(c)
    st[k], st[k + 1], st[k + 2] = n * 1.0, n, n                     # mean, visits, hits
    st[k + 3:M.PATH_STATS] = n * 1.0                                # mu_l(c) = mu
    v_pix, c_pix, mean = 1.0 + v_rest, 1.0 + M.LIGHT_COST + 2.0, 2.0
    st[M.PATH_STATS:M.PATH_STATS + 4] = [n_paths * (v_pix + mean ** 2), n_paths * mean,
                                         n_paths * c_pix, n_paths]
    st[M.PAIRS:M.WEIGHT] = n * spread                               # E[m_l(x; c)^2]
    st[M.WEIGHT:] = n * weight, n                                   # pixel weights
    return st


def test_learned_objective_weighs_the_pixel_sample_and_the_noise():
    """The allocation minimises variance x cost of the whole pixel sample, the rest of the
    path measured per region from the recorded paths, and counts as the vertex's variance only
    its noise (the pooled statistics less the variation of the light share's mean between the
    region's points, measured by pairs of light samples).  Five regions, deterministic
    (variance 1/c + v_rest, cost 1 + c/2 + 2):
    * no variance elsewhere on the paths: 4 light samples;
    * 20x the vertex's variance elsewhere: one (more would cost more than they save);
    * 0.2 elsewhere: 4;
    * 0.9 elsewhere: 3, whose variance x cost is 0.83 of one light sample's (the margin that
      protects one light sample holds only against candidates below one);
    * 0.2 elsewhere, but 95 % of the pooled variance is variation between points (noise
      0.1/c): 2.
    Negative controls: without the recorded paths (the LEARN_REST_VAR stand-in) the first
    region takes 3; with the pooled variance taken as noise the last takes 4 (and mutant
    ``learned-margin-above-one`` keeps one in the fourth)."""
    from integrators.plugins import mis3 as M
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    integ = mi.load_dict(LEARNED)
    mi.render(scene, integrator=integ, spp=1)            # builds the grid for this scene
    k = len(M.LEARNED_P)
    st = np.zeros((integ.grid.size, M.WEIGHT + 2))
    for r, (v_rest, spread) in enumerate([(0.0, 1.0), (20.0, 1.0), (0.2, 1.0), (0.9, 1.0),
                                          (0.2, 1.9)]):
        st[r] = _region_statistics(k, v_rest, spread)

    def learned(stats):
        integ.grid.set_table(np.full(integ.grid.size, -1.0, np.float32))
        integ.grid.stats = mi.Float(stats.ravel())
        integ.learn()
        return list(integ.grid.table()[:5])
    assert learned(st) == [4.0, 1.0, 4.0, 3.0, 2.0]
    stand_in = st.copy()
    stand_in[:, M.PATH_STATS + 3] = 0.0                  # no paths recorded
    assert learned(stand_in)[0] == 3.0   # (1/c + 0.3) (1 + c/2): 3 instead of 4
    pooled = st.copy()
    pooled[:, M.PAIRS:] = 0.0                            # (read as the squared pooled mean)
    assert learned(pooled)[4] == 4.0


def test_learned_objective_trades_at_the_images_rate():
    """With the pixels measured (``PixelStats``), a region's allocation minimises the image's
    relMSE x time: w_r V(c) + (V / C) cost(c), w_r its visits' mean pixel weight 1 / (I_p^2 +
    eps), V / C the image's relative variance per unit of cost as it will be under the new
    decisions.  Regions of variance 1 / c per visit at c light samples:
    * the image's V / C = 0.5, visits too rare to change it: c = sqrt(2 w_r / 0.5), so pixel
      weights 0.25, 1 and 4 take 1, 2 and 4 light samples;
    * one region of weight 1 with a visit per camera sample, V = 1, C = 2: at 2 light samples
      V / C would fall to 0.5 / 2.5, at 3 to 0.33 / 3: the fixed point takes 4.
    Negative controls: each pixel sample's own variance x cost (the objective without the
    pixels) gives the three regions one allocation; mutants ``learned-image-weight-ignored``
    and ``learned-image-rate-not-iterated`` (2 in the last case)."""
    from types import SimpleNamespace

    from integrators.plugins import mis3 as M
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    integ = mi.load_dict(LEARNED)
    mi.render(scene, integrator=integ, spp=1)            # builds the grid for this scene
    k = len(M.LEARNED_P)
    n = 1000

    def learned(stats, pixels, recorded=1e12):
        # (recorded: the camera samples of the recording passes, visits / it = f_r x fraction)
        integ.grid.set_table(np.full(integ.grid.size, -1.0, np.float32))
        integ.grid.stats = mi.Float(stats.ravel())
        integ.pixels, integ._recorded = pixels, recorded
        try:
            integ.learn()
        finally:
            integ.pixels = None
        return list(integ.grid.table()[:len(stats)][:3])

    st = np.zeros((integ.grid.size, M.WEIGHT + 2))
    for r, w in enumerate([0.25, 1.0, 4.0]):
        st[r] = _region_statistics(k, 0.0, n=n, weight=w)
    image = SimpleNamespace(image=lambda: (1.0, 2.0))
    assert learned(st, image) == [1.0, 2.0, 4.0]
    assert integ.run_notes()["objective"] == "image relMSE x cost"
    own = learned(st, None)
    assert own[0] == own[1] == own[2]
    assert integ.run_notes()["objective"] == "pixel sample variance x cost"
    one = np.zeros_like(st)
    one[0] = _region_statistics(k, 0.0, n=n, weight=1.0)
    # (f_r = visits / (LEARN_FRACTION x camera samples) = 1)
    assert learned(one, image, recorded=n / M.LEARN_FRACTION)[0] == 4.0


def test_learning_measures_the_pixels_and_weighs_the_visits():
    """A first learning render measures its pixels before any vertex records (half the
    learning share, ``LEARN_PIXELS``), then each recording visit adds its pixel's relMSE
    weight: on the closed emitting box at max_depth 3 (L = 1 + 0.5 + 0.25 = 1.75 everywhere,
    one pixel) the visits' mean weight is 1 / (1.75^2 + 0.01) within 3 % (the pixel's mean
    from 1,024 samples or more), and a camera sample costs the camera ray and two vertices of
    at most 4 light samples each, 1 + 2 x (1 + LIGHT_COST p) (the recording passes' paths, the
    second with the learned p).  Mutant: ``learned-image-visit-unweighted``."""
    from integrators.plugins import mis3 as M
    from integrators.sampling.learning import PIXEL_EPS
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    integ = mi.load_dict({**LEARNED, "max_depth": 3})
    mi.render(scene, integrator=integ, spp=1 << 16)
    px = integ.pixels
    # (the pixels, then the recording passes: the second one runs while the decisions move)
    first = int((1 << 16) * M.LEARN_SHARE)
    pre = int(first * M.LEARN_PIXELS)
    assert px.count == first + 2 * (first - pre) and px.cost_samples == px.count - pre
    assert integ._recorded == px.cost_samples
    st = integ.grid.statistics()
    w = st[:, M.WEIGHT].sum() / st[:, M.WEIGHT + 1].sum()
    assert st[:, M.WEIGHT + 1].sum() == st[:, len(M.LEARNED_P) + 1].sum()   # (every visit)
    assert abs(w * (1.75 ** 2 + PIXEL_EPS) - 1.0) < 0.03, w
    v, c = px.image()
    assert v > 0 and 3.0 <= c <= 1.0 + 2.0 * (1.0 + M.LIGHT_COST * max(M.LEARNED_P))


def test_pixel_stats_follow_the_view(monkeypatch):
    """The pixels' statistics the recording visits are weighed by (``PixelStats``) belong to
    one view: a second sensor with the same film and pose keeps them, one moved starts them
    again, its first learning call measuring its pixels first as a first render does (the
    regions' table, in world space, is kept).  Mutant: ``learned-pixels-other-view``."""
    from integrators.plugins import mis3 as M
    monkeypatch.setattr(M, "LEARN_SETTLED", -1.0)      # (every call learns: none settles)
    scene = mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res="8")
    integ = mi.load_dict({**LEARNED, "max_depth": 3})
    mi.render(scene, integrator=integ, spp=256, seed=0)
    px, first = integ.pixels, integ.pixels.count
    assert first > 0

    def sensor(to_world):
        s = mi.load_dict({"type": "perspective", "film": {
            "type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "gaussian"}}})
        s.m_to_world = to_world
        return s
    pose = scene.sensors()[0].world_transform()
    mi.render(scene, integrator=integ, sensor=sensor(pose), spp=256, seed=1)
    assert integ.pixels is px and px.count > first
    moved = mi.Transform4f().translate([0.05, 0.0, 0.0]) @ pose
    mi.render(scene, integrator=integ, sensor=sensor(moved), spp=256, seed=2)
    assert integ.pixels is not px and integ.pixels.count == first


def test_pixel_layout_is_mitsubas():
    """``PixelStats.pixel`` (lane // spp) is the pixel Mitsuba's render gives each lane of a
    pass: a Python integrator that returns its lane's computed pixel index renders the image of
    the indices.  Box filter: exactly.  A Gaussian filter with the border sampled (the lanes
    laid out over the film with its border): the filter averages indices that are linear in
    x and y, so each pixel reads its own index within the averaging's noise (a layout without
    the border would be off by 24 or more)."""
    from integrators.sampling.learning import PixelStats

    class Lanes(mi.SamplingIntegrator):
        def sample(self, scene, sampler, ray, medium=None, active=True):
            pix = self.stats.pixel(sampler.wavefront_size(), self.spp)
            return mi.Color3f(mi.Float(pix), 0.0, 0.0), True, []

    for border, filt, spp, tol in ((False, "box", 4, 0.0), (True, "gaussian", 1024, 1.0)):
        scene = mi.load_dict({"type": "scene", "s": {
            "type": "perspective", "film": {"type": "hdrfilm", "width": 7, "height": 5,
                                            "sample_border": border,
                                            "rfilter": {"type": filt}}}})
        sensor = scene.sensors()[0]
        b = sensor.film().rfilter().border_size() if border else 0
        assert b == (2 if border else 0)
        integ = Lanes(mi.Properties())
        integ.stats, integ.spp = PixelStats(PixelStats.layout(sensor)), spp
        img = np.array(mi.render(scene, integrator=integ, spp=spp))[..., 0]
        w = 7 + 2 * b
        idx = np.arange(w * (5 + 2 * b)).reshape(5 + 2 * b, w)[b:b + 5, b:b + 7]
        assert np.all(np.abs(img - idx) <= tol), (border, img, idx)


def test_learning_records_whole_paths_and_pairs():
    """While learning, the paths whose vertices record statistics are recorded too (in the cell
    of their first recording vertex), at most one per recording vertex, their cost at least the
    camera ray and one vertex; and each recording vertex's pair of light samples gives a
    squared light share of the right size: on the closed emitting box (L_e = 1 everywhere,
    albedo 0.5, max_depth 2: only the first hit) a point's light share hardly varies within a
    region, so per candidate the squared share per visit is the square of the share per visit
    (within 10 %; one sample squared instead of the product of two would add its variance)."""
    from integrators.plugins import mis3 as M
    scene = mi.load_dict(closed_box_scene(0.5, 1.0))
    integ = mi.load_dict({**LEARNED, "max_depth": 2})
    integ.reset_learning()
    mi.render(scene, integrator=integ, spp=1 << 18)      # about 4,000 recorded visits
    st = integ.grid.statistics()
    k = len(M.LEARNED_P)
    paths, visits = st[:, M.PATH_STATS + 3].sum(), st[:, k + 1].sum()
    assert 0 < paths <= visits, (paths, visits)
    assert st[:, M.PATH_STATS + 2].sum() >= 2.0 * paths
    live = st[:, k + 1] > 0
    n = st[live, k + 1]
    share = st[live, k + 3:M.PATH_STATS] / n[:, None]
    sq = st[live, M.PAIRS:M.PAIRS + k] / n[:, None]
    ratio = (sq.T @ n) / ((share ** 2).T @ n)
    assert np.all(np.abs(ratio - 1.0) < 0.1), ratio
