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

Closed forms live in :mod:`integrators.testing.closed_forms` (re-exported here), the scenes in
:mod:`integrators.testing.scenes`, the one-call checks in :mod:`integrators.testing.unbiased` and
:mod:`integrators.testing.chi2`.

False-failure accounting: every check made through this kit (``mean_test``, ``image_test``,
``chi2_test``) is added to :data:`CHECKS` with its significance level; the pytest plugin prints
:func:`checks_summary` at the end of a run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy import stats

from .closed_forms import (closed_box_radiance, closed_sphere_radiance,  # noqa: F401
                           furnace_radiance, lambert_polygon_irradiance,
                           point_light_irradiance, rectangle_vertices)

DEFAULT_ALPHA = 1.5e-5

#: checks made in this process (the pytest plugin reports them): ``count`` t / Welch checks
#: (mean_test, image_test), ``chi2`` chi-square checks (chi2_test), ``alpha_sum`` the sum of
#: the significance levels of all of them (the union bound on a false failure)
CHECKS = {"count": 0, "chi2": 0, "alpha_sum": 0.0}


def count_check(alpha: float, kind: str = "count") -> None:
    """Add one check at level ``alpha`` to :data:`CHECKS` (``kind``: "count" or "chi2")."""
    CHECKS[kind] = CHECKS.get(kind, 0) + 1
    CHECKS["alpha_sum"] = CHECKS.get("alpha_sum", 0.0) + float(alpha)


def checks_summary() -> str:
    """One line: how many statistical checks ran and the false-failure bound they imply
    (empty when none ran)."""
    n, m = CHECKS.get("count", 0), CHECKS.get("chi2", 0)
    if not n and not m:
        return ""
    bound = 100 * CHECKS.get("alpha_sum", 0.0)
    line = f"statistical checks (t / Welch) in this run: {n} at alpha {DEFAULT_ALPHA:g} each"
    if m:
        line += f", plus {m} chi-square"
    return line + f": false-failure bound {bound:.3g} %"


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

    #: H0 of this test, in words
    h0 = "unbiased, E[batch mean] = expected (Student t, Sidak over channels)"

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
    count_check(alpha)
    return _mean_test(x, expected, alpha, rounding_rtol)


def _mean_test(x, expected, alpha=DEFAULT_ALPHA, rounding_rtol=FLOAT32_RTOL) -> MeanTest:
    """:func:`mean_test` without counting it (pilot runs that choose a sample size)."""
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
    #: median over blocks and channels of the relative standard error of the block difference
    #: (blocks black on both sides left out): below 0.005, a 5 % bias over the image gives
    #: |t| >= 10 in at least half of the blocks
    rel_se: float = float("nan")

    #: H0 of this test, in words
    h0 = "unbiased, the same expected image (Welch t per block and channel, Sidak)"

    def __str__(self):
        return (f"p = {self.p_value:.3g} (alpha {self.alpha:g}), worst block {self.worst_block}, "
                f"image means differ by {100 * self.rel_diff:.3f} %, median relative s.e. of a "
                f"block {100 * self.rel_se:.3f} %")


def image_test(a: np.ndarray, b: np.ndarray, block: int = 4,
               alpha: float = DEFAULT_ALPHA) -> ImageTest:
    """H0: two estimators have the same expected image.

    ``a`` and ``b`` are (batches, H, W, C) arrays of independent renders; ``b`` may also be one
    (H, W, C) image taken as exact (a closed-form or converged image: no variance on its side).
    Pixels are averaged over ``block`` x ``block`` blocks (so heavy-tailed single pixels do not
    break the normal approximation; ``block`` is clamped to the image size), Welch's t-test
    compares the batch means of each block and channel, and the smallest p-value is
    Sidak-corrected over all blocks and channels.  Each side's own variance enters, so a noisy
    reference does not cause false failures."""
    count_check(alpha)
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 4 or b.ndim not in (3, 4):
        raise ValueError(f"image_test: want (batches, H, W, C) arrays (the reference may be one "
                         f"(H, W, C) image), got shapes {a.shape} and {b.shape}")
    exact = b.ndim == 3
    if exact:
        b = b[None]
    if b.shape[1:] != a.shape[1:]:
        raise ValueError(f"image_test: image shapes differ: {a.shape[1:]} and {b.shape[1:]}")
    block = max(1, min(block, a.shape[1], a.shape[2]))

    def blocks(x):
        k, h, w, c = x.shape
        h2, w2 = h // block, w // block
        x = x[:, :h2 * block, :w2 * block].reshape(k, h2, block, w2, block, c)
        return x.mean(axis=(2, 4))
    ba, bb = blocks(a), blocks(b)
    ma, mb = ba.mean(0), bb.mean(0)
    va = ba.var(0, ddof=1) / ba.shape[0]
    vb = np.zeros_like(mb) if exact else bb.var(0, ddof=1) / bb.shape[0]
    floor = (FLOAT32_RTOL * np.maximum(np.abs(ma), np.abs(mb))) ** 2
    se2 = va + vb + floor
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ma - mb) / np.sqrt(se2)
        vb_term = 0.0 if exact else vb ** 2 / (bb.shape[0] - 1)
        dof = se2 ** 2 / (va ** 2 / (ba.shape[0] - 1) + vb_term + 1e-300)
        lit = (ma != 0) | (mb != 0)
        rel = np.sqrt(va + vb)[lit] / np.maximum(np.abs(mb), np.abs(ma))[lit]
    rel_se = float(np.median(rel)) if rel.size else float("inf")
    dof = np.clip(np.nan_to_num(dof, nan=1.0), 1.0, 1e6)
    p = np.where(se2 > 0, 2 * stats.t.sf(np.abs(np.nan_to_num(t)), dof),
                 np.where(ma == mb, 1.0, 0.0))
    i = np.unravel_index(int(np.argmin(p)), p.shape)
    p_comb = float(-np.expm1(p.size * np.log1p(-min(float(p[i]), 1 - 1e-16))))
    rel = float(abs(a.mean() - b.mean()) / max(abs(b.mean()), 1e-12))
    return ImageTest(p_comb, tuple(int(x) for x in i), rel, alpha, rel_se)


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
