r"""Statistical testing of estimators against closed forms.

Method (used by the test suite and meant for users' own integrators):

* **Measurement.** A ``radiancemeter`` sensor (one ray, 1x1 film, box filter) looks at a point
  whose radiance is known in closed form.  The scene is rendered ``batches`` times with distinct
  seeds and ``spp`` samples each, giving K independent batch means x_1..x_K per channel.
* **Null hypothesis H0:** the estimator is unbiased, E[x_k] = mu (the closed form).
* **Statistic:** Student's t = (mean(x) - mu) / (s / sqrt(K)) with K-1 degrees of freedom,
  per colour channel.  Batch means of thousands of samples are close to normal even where
  single samples are heavy-tailed (Russian roulette, rare light hits), which is why we test batch
  means and not per-sample values.
* **Significance:** a check is rejected when the Sidak-combined p-value over its channels,
  1 - (1 - min p)^C, is below ``alpha`` (default 1.5e-5 per check).  The default suite makes
  about 220 such checks (the count is printed at the end of every run), 0.33 % together.
* **Suite budget (at most 1 % false failures per full run, union bound):** t / Welch checks
  0.33 %; phong chi-square, albedo <= 1, albedo vs quadrature and normal-incidence families
  0.1 % each (0.4 %); light-sampling chi-square 0.1 %; adaptive-pmf chi-square 0.1 % (two
  loop modes at 0.05 % each); two
  Wilcoxon variance-order tests 0.02 %; about 15 one-sided variance (Veach bound) tests at 4
  standard errors, 0.05 %.  Total about 1.0 %.  All seeds are fixed, so a given checkout passes
  or fails deterministically; the rate is over the choice of seeds.
* **Rounding:** the standard error has a floor of 1e-4 x expected (single-precision
  accumulation), so zero-variance estimators are not rejected for float rounding.
* **Power:** each check also reports the relative standard error of the mean; tests assert it is
  below 0.5 %, so a 5 % bias gives |t| >= 10 against a critical value of about 6 (the
  mutation harness, tests/mutation.py, plants such biases and all are caught), and a check
  cannot pass merely because it is too noisy to see anything.

Closed forms: :func:`lambert_polygon_irradiance` (Lambert's formula for a uniformly emitting
polygon), :func:`point_light_irradiance`, :func:`closed_sphere_radiance` (the geometric series).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy import stats

DEFAULT_ALPHA = 1.5e-5

#: number of mean_test / image_test checks made in this process (the suite reports it)
CHECKS = {"count": 0}


# ---------------------------------------------------------------------------------------------
# closed forms
def lambert_polygon_irradiance(p, n, vertices) -> float:
    """Irradiance at ``p`` (normal ``n``) from a polygon of unit radiance (Lambert 1760).

    E = 1/2 sum_i Theta_i (n . g_i), Theta_i the angle the i-th edge subtends at p and g_i the
    unit normal of the plane through p and that edge.  The polygon must lie entirely above the
    tangent plane of p (no clipping is done) and face p."""
    p, n = np.asarray(p, float), np.asarray(n, float)
    r = [np.asarray(v, float) - p for v in vertices]
    r = [v / np.linalg.norm(v) for v in r]
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        theta = math.acos(float(np.clip(np.dot(a, b), -1, 1)))
        g = np.cross(a, b)
        g /= np.linalg.norm(g)
        total += theta * float(np.dot(n, g))
    return abs(0.5 * total)


def rectangle_vertices(to_world: "mi.ScalarTransform4f"):
    """World-space corners of Mitsuba's ``rectangle`` shape ([-1,1]^2 at z=0) under to_world."""
    corners = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    return [np.array(to_world @ mi.ScalarPoint3f(*c), dtype=float) for c in corners]


def point_light_irradiance(p, n, light_pos, intensity: float) -> float:
    d = np.asarray(light_pos, float) - np.asarray(p, float)
    dist2 = float(np.dot(d, d))
    cos = float(np.dot(np.asarray(n, float), d)) / math.sqrt(dist2)
    return intensity * max(cos, 0.0) / dist2


def closed_sphere_radiance(le: float, rho: float, max_depth: int = -1) -> float:
    """Radiance inside a closed diffuse sphere (albedo rho) emitting le everywhere.

    Every bounce sees the same emission: L = le sum_{k < max_depth} rho^k (-1: le / (1-rho))."""
    if max_depth < 0:
        return le / (1.0 - rho)
    return le * sum(rho ** k for k in range(max_depth))


# ---------------------------------------------------------------------------------------------
# measurement
def radiancemeter(target, origin, spp: int) -> dict:
    """Sensor dict measuring the radiance leaving ``target`` towards ``origin``."""
    target, origin = np.asarray(target, float), np.asarray(origin, float)
    d = target - origin
    return {"type": "radiancemeter", "origin": origin.tolist(),
            "direction": (d / np.linalg.norm(d)).tolist(),
            "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp}}


def batch_means(scene, integrator, batches: int = 32, spp: int = 8192, seed0: int = 0,
                sensor: int = 0) -> np.ndarray:
    """(batches, channels) array of independent per-render means (distinct seeds)."""
    out = []
    for k in range(batches):
        img = mi.render(scene, integrator=integrator, spp=spp, seed=seed0 + k, sensor=sensor)
        out.append(np.array(img, dtype=np.float64).reshape(-1, np.array(img).shape[-1]).mean(0))
    return np.array(out)


class _Verdict:
    """A test result: passed when its p-value is at least its significance level."""

    @property
    def passed(self) -> bool:
        return self.p_value >= self.alpha


@dataclass
class MeanTest(_Verdict):
    mean: np.ndarray
    expected: np.ndarray
    rel_se: float          # largest relative standard error over channels
    p_value: float         # Sidak-combined over channels
    alpha: float

    def __str__(self):
        return (f"mean {np.array2string(self.mean, precision=5)} vs expected "
                f"{np.array2string(self.expected, precision=5)}: p = {self.p_value:.3g} "
                f"(alpha {self.alpha:g}), relative s.e. {100 * self.rel_se:.3f} %")


FLOAT32_RTOL = 1e-4


def mean_test(x: np.ndarray, expected, alpha: float = DEFAULT_ALPHA,
              rounding_rtol: float = FLOAT32_RTOL) -> MeanTest:
    """Student t-test of H0: E[x] = expected, per channel, Sidak-combined over channels.

    Renders accumulate in single precision, so a zero-variance estimator (cosine sampling of
    a diffuse furnace) is off by rounding alone: the standard error gets a floor of
    ``rounding_rtol * |expected|`` (1e-4, far below the few-percent biases the tests target)."""
    CHECKS["count"] += 1
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    k, c = x.shape
    expected = np.broadcast_to(np.asarray(expected, dtype=np.float64), (c,))
    mean = x.mean(0)
    se = np.sqrt((x.std(0, ddof=1) / math.sqrt(k)) ** 2 + (rounding_rtol * expected) ** 2)
    if not np.all(np.isfinite(x)):
        return MeanTest(mean, expected, float("inf"), 0.0, alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (mean - expected) / se
    p = np.where(se > 0, 2 * stats.t.sf(np.abs(t), df=k - 1),
                 np.where(np.isclose(mean, expected, rtol=1e-6, atol=1e-9), 1.0, 0.0))
    p_comb = 1.0 - (1.0 - float(np.min(p))) ** c
    scale = np.maximum(np.abs(expected), 1e-12)
    return MeanTest(mean, expected, float(np.max(se / scale)), p_comb, alpha)


# ---------------------------------------------------------------------------------------------
# image against image (two estimators of the same image, each with its own variance)
def batch_images(scene, integrator, batches: int = 16, spp: int = 256, seed0: int = 0):
    """(batches, H, W, C) array of independent renders (distinct seeds)."""
    return np.array([np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed0 + k))
                     for k in range(batches)], dtype=np.float64)


@dataclass
class ImageTest(_Verdict):
    p_value: float          # Sidak-combined over all blocks and channels
    worst_block: tuple      # (row, col, channel) of the smallest p
    rel_diff: float         # relative difference of the image means
    alpha: float

    def __str__(self):
        return (f"p = {self.p_value:.3g} (alpha {self.alpha:g}), worst block {self.worst_block}, "
                f"image means differ by {100 * self.rel_diff:.3f} %")


def image_test(a: np.ndarray, b: np.ndarray, block: int = 4,
               alpha: float = DEFAULT_ALPHA) -> ImageTest:
    """H0: two estimators have the same expected image.

    Pixels are averaged over ``block`` x ``block`` blocks (so heavy-tailed single pixels do not
    break the normal approximation), Welch's t-test compares the batch means of each block and
    channel, and the smallest p-value is Sidak-corrected over all blocks and channels.  Each
    side's own variance enters, so a noisy reference does not cause false failures."""
    CHECKS["count"] += 1

    def blocks(x):
        k, h, w, c = x.shape
        h2, w2 = h // block, w // block
        x = x[:, :h2 * block, :w2 * block].reshape(k, h2, block, w2, block, c)
        return x.mean(axis=(2, 4))
    ba, bb = blocks(a), blocks(b)
    ma, mb = ba.mean(0), bb.mean(0)
    va, vb = ba.var(0, ddof=1) / ba.shape[0], bb.var(0, ddof=1) / bb.shape[0]
    floor = (FLOAT32_RTOL * np.maximum(np.abs(ma), np.abs(mb))) ** 2
    se2 = va + vb + floor
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ma - mb) / np.sqrt(se2)
        dof = se2 ** 2 / (va ** 2 / (ba.shape[0] - 1) + vb ** 2 / (bb.shape[0] - 1) + 1e-300)
    dof = np.clip(np.nan_to_num(dof, nan=1.0), 1.0, 1e6)
    p = np.where(se2 > 0, 2 * stats.t.sf(np.abs(np.nan_to_num(t)), dof),
                 np.where(ma == mb, 1.0, 0.0))
    i = np.unravel_index(int(np.argmin(p)), p.shape)
    p_comb = float(-np.expm1(p.size * np.log1p(-min(float(p[i]), 1 - 1e-16))))
    rel = float(abs(a.mean() - b.mean()) / max(abs(b.mean()), 1e-12))
    return ImageTest(p_comb, tuple(int(x) for x in i), rel, alpha)


# ---------------------------------------------------------------------------------------------
# per-sample values (variance studies)
def sample_values(scene, integrator, target, origin, n: int = 1 << 20, seed: int = 0):
    """(n, channels) array of independent single-sample estimates of the radiance leaving
    ``target`` towards ``origin``: ``integrator.sample`` called directly on n copies of the ray,
    with an independent sampler (works for ours and Mitsuba's built-in integrators)."""
    target, origin = np.asarray(target, float), np.asarray(origin, float)
    d = target - origin
    d = d / np.linalg.norm(d)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    ray = mi.Ray3f(mi.Point3f(*[dr.full(mi.Float, float(v), n) for v in origin]),
                   mi.Vector3f(*[float(v) for v in d]))
    spec, _, _ = integrator.sample(scene, sampler, ray, None, mi.Bool(True))
    return np.array(mi.unpolarized_spectrum(spec), dtype=np.float64).T


def variance_upper_test(v_a: np.ndarray, v_b: np.ndarray, slack: float, z: float = 4.0):
    """One-sided check of H0 "Var[a] <= Var[b] + slack" from per-sample values (first channel):
    the difference of the two sample variances, with its standard error from 64 groups, must not
    exceed the slack by more than ``z`` standard errors.  Returns (passed, details)."""
    a, b = v_a[:, 0], v_b[:, 0]
    ga = np.array_split(a, 64)
    gb = np.array_split(b, 64)
    diffs = np.array([x.var() - y.var() for x, y in zip(ga, gb)])
    diff = a.var() - b.var()
    se = diffs.std(ddof=1) / math.sqrt(len(diffs))
    stat = (diff - slack) / max(se, 1e-300)
    return stat <= z, dict(var_a=a.var(), var_b=b.var(), slack=slack, z=stat)
