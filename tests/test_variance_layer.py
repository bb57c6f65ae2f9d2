"""The progressive variance layer against what it estimates.

:func:`integrators.app.progressive.render` returns an Accumulator whose ``variance()`` is meant to
be the variance of its per-pixel estimate ``mean()``.  Over R independent renders (disjoint seed
ranges) of a small scene, the empirical variance of each pixel's estimate across the renders,
E_i = var_r(x_ri) (unbiased, ddof 1), and the mean of the variance layer, V_i = mean_r(v_ri),
estimate the same number.

H0: E[V_i] = E[E_i] = Var(x_i) for every pixel.  Statistic: D_i = V_i - E_i over the M pixels
(independent: independent sampler, box filter), Student t of mean(D) with M - 1 degrees of freedom,
rejected at the kit's DEFAULT_ALPHA.  Reported as the ratio sum V / sum E with its relative
standard error s(D) / sqrt(M) / mean(E); the test also asserts that relative s.e. is below 2 %, so
that a 12 % scale error gives |t| >= 6 against a critical value of about 4.5 (M = 1024): the
tolerance on the ratio is about 4.5 x 1.0 % = 4.5 % with R = 24 renders of 32x32 pixels (relative
s.d. of one pixel's E_i is sqrt(2 / (R - 1)) = 0.29 for near-normal estimates).

Scene: the camera inside a closed emitting diffuse cube (albedo 0.5, emission 1), ``bsdf_path``
with uniform hemisphere sampling at max_depth 3: every pixel's samples have the same bounded
distribution (1 + 2 rho cos (1 + 2 rho cos'), mean 1.75), whatever point it sees.

Checked for single runs (8 passes each), for runs merged in memory (Accumulator.merge of an
8-pass and an 8-pass run with 1x and 3x the samples), and for runs written to EXR files and merged
from them (progressive.write / progressive.merge: the sums rebuilt from the written estimate and
variance).  Negative control in each: the same data with the variance scaled by 1.12 is
rejected; mutants in tests/mutation.py (variance-layer-scale-12%, merged-variance-passes,
merge-from-file-passes).  Runtime about 8 s.
"""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest
from scipy import stats

import integrators  # noqa: F401
from integrators.app import progressive
from integrators.testing import DEFAULT_ALPHA
from integrators.testing.stats import count_check

RES, RENDERS, SPP = 32, 24, 32
MAX_REL_SE = 0.02


def box_scene(res=RES, spp=SPP):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "bsdf_path", "hemisphere": "uniform", "max_depth": 3},
        "box": {"type": "cube", "flip_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": 0.5},
                "emitter": {"type": "area", "radiance": 1.0}},
        "sensor": {"type": "perspective", "fov": 70,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0.1, 0.2, 0.3],
                                                              target=[0.3, 0.1, -1],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}}})


class VarianceCheck:
    """H0 E[variance layer] = Var(estimate), from R independent (mean, variance) images."""

    def __init__(self, means, variances, alpha=DEFAULT_ALPHA, scale=1.0):
        x = np.asarray(means, np.float64)[..., 0].reshape(len(means), -1)
        v = scale * np.asarray(variances, np.float64)[..., 0].reshape(len(variances), -1)
        emp = x.var(axis=0, ddof=1)          # E_i: empirical variance across renders
        lay = v.mean(axis=0)                 # V_i: mean of the variance layer
        d = lay - emp
        m = d.size
        se = d.std(ddof=1) / math.sqrt(m)
        self.t = float(d.mean() / se)
        self.p_value = float(2 * stats.t.sf(abs(self.t), df=m - 1))
        self.alpha = alpha
        self.ratio = float(lay.mean() / emp.mean())
        self.rel_se = float(se / emp.mean())
        self.renders, self.pixels = len(means), m

    @property
    def passed(self):
        return self.p_value >= self.alpha

    def __str__(self):
        return (f"H0 E[variance layer] = Var(estimate): mean layer / empirical variance = "
                f"{self.ratio:.4f} +- {self.rel_se:.4f} (1 s.e.) over {self.renders} renders x "
                f"{self.pixels} pixels, t = {self.t:.2f}, p = {self.p_value:.3g} "
                f"(alpha {self.alpha:g})")


def assert_variance_layer(means, variances):
    count_check(DEFAULT_ALPHA)
    r = VarianceCheck(means, variances)
    assert r.passed, r
    assert r.rel_se < MAX_REL_SE, f"too weak to see a 12 % scale error: {r}"
    # negative control on the same data: a 12 % scale error is rejected
    bad = VarianceCheck(means, variances, scale=1.12)
    assert not bad.passed, f"a 12 % scale error passes: {bad}"
    return r


@pytest.fixture(scope="module")
def scene():
    return box_scene()


def test_variance_layer_single_runs(scene):
    accs = [progressive.render(scene, spp=SPP, seed=100 * r) for r in range(RENDERS)]
    assert all(a.passes == 8 for a in accs)
    assert_variance_layer([a.mean() for a in accs], [a.variance() for a in accs])


def _two_runs(scene, r):
    """Two independent runs of one replicate: SPP and 3 SPP samples, disjoint seeds."""
    a = progressive.render(scene, spp=SPP, seed=100 * r)
    b = progressive.render(scene, spp=3 * SPP, seed=100 * r + 50)
    return a, b


@pytest.fixture(scope="module")
def pairs(scene):
    return [_two_runs(scene, r) for r in range(RENDERS)]


def test_variance_layer_merged_runs(pairs):
    merged = [a.merge(b) for a, b in pairs]
    assert all(m.spp == 4 * SPP and m.passes == 16 for m in merged)
    assert_variance_layer([m.mean() for m in merged], [m.variance() for m in merged])


def test_variance_layer_merged_from_files(pairs, tmp_path):
    means, variances = [], []
    for r, (a, b) in enumerate(pairs):
        pa, pb = tmp_path / f"a{r}.exr", tmp_path / f"b{r}.exr"
        progressive.write(pa, a)
        progressive.write(pb, b)
        m = progressive.merge([pa, pb])
        assert m.spp == 4 * SPP and m.passes == 16
        means.append(m.mean())
        variances.append(m.variance())
    assert_variance_layer(means, variances)
