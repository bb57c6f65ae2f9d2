"""One-call unbiasedness checks: render, test, and fail with the verdict.

:func:`assert_unbiased` renders ``batches`` independent batches (distinct seeds) of a scene and
tests H0 "the estimator is unbiased" against what ``expected`` is:

* a number, or one number per channel: the closed-form value of the film's mean (a
  ``radiancemeter`` scene: the radiance along its ray).  Student t on the batch means, Sidak
  over channels (:func:`integrators.testing.mean_test`);
* a numpy array: an (H, W, C) image taken as exact, or a (batches, H, W, C) array of reference
  renders (with their own variance).  Block-wise Welch t, Sidak over blocks and channels
  (:func:`integrators.testing.image_test`);
* a reference integrator (a name such as ``"path"``, a dict for ``mi.load_dict`` or a loaded
  integrator): rendered with the same budget and fresh seeds, then compared as above.

It fails (AssertionError, one line stating H0, alpha and the numbers) when the test rejects H0,
and also when the estimate is too noisy to see a 5 % bias: its relative standard error (of the
mean, or of an image block, median over blocks) above ``max_rel_se`` (default 0.005: a 5 % bias
then gives |t| >= 10 against a critical value of about 6), so that a test cannot pass by being
noisy.  ``max_rel_se=None`` switches that guard off.  :func:`check_unbiased` does the same and
returns the verdict without raising (for negative controls: ``assert not r.passed``).
"""
from __future__ import annotations

import numpy as np

from .stats import (DEFAULT_ALPHA, _mean_test, batch_images, batch_means, count_check,
                    image_test)

MAX_REL_SE = 0.005
#: seed offset of a reference integrator's renders (distinct from the tested ones)
REFERENCE_SEED0 = 1_000_003


class UnbiasedFailure(AssertionError):
    """Raised by :func:`assert_unbiased`; ``.verdict`` holds the test result."""

    def __init__(self, message, verdict):
        super().__init__(message)
        self.verdict = verdict


def _load(obj, what):
    import mitsuba as mi
    if obj is None:
        return None
    if isinstance(obj, str):
        if what == "scene":
            return mi.load_file(obj)
        return mi.load_dict({"type": obj})
    if isinstance(obj, dict):
        return mi.load_dict(obj)
    return obj


def _label(integrator) -> str:
    if integrator is None:
        return "the scene's integrator"
    if isinstance(integrator, str):
        return integrator
    if isinstance(integrator, dict):
        return ", ".join(f"{k}={v}" for k, v in integrator.items()) if integrator else "{}"
    try:
        return type(integrator).__name__ if not hasattr(integrator, "class_name") \
            else integrator.class_name()
    except Exception:                                       # pragma: no cover
        return repr(integrator)


def _is_reference_integrator(expected) -> bool:
    if isinstance(expected, (str, dict)):
        return True
    try:
        import mitsuba as mi
        return isinstance(expected, mi.Integrator)
    except Exception:                                       # pragma: no cover
        return False


def _sensors(sensor, expected) -> list:
    sensors = list(sensor)
    if len(sensors) != len(expected):
        raise ValueError(f"{len(sensors)} sensors but {len(expected)} expected values: give "
                         "one expected value per sensor")
    return sensors


def check_unbiased(scene, expected, integrator=None, *, spp: int = 4096, batches: int = 32,
                   alpha: float = DEFAULT_ALPHA, max_rel_se: float | None = MAX_REL_SE,
                   max_spp: int | None = None, sensor: int = 0, seed0: int = 0,
                   block: int = 4, rounding_rtol: float | None = None):
    """The test of :func:`assert_unbiased` without the assertion: returns the verdict
    (:class:`~integrators.testing.stats.MeanTest` or
    :class:`~integrators.testing.stats.ImageTest`), with ``.passed``, ``.p_value``, ``.alpha``,
    ``.rel_se``, ``.h0`` and the budget of the tested renders, ``.spp`` and ``.batches``.
    Same arguments as :func:`assert_unbiased`."""
    scene_obj = _load(scene, "scene")
    integ = _load(integrator, "integrator")
    if not isinstance(sensor, (int, np.integer)):     # several sensors: one check each
        return [check_unbiased(scene_obj, mu, integ, spp=spp, batches=batches, alpha=alpha,
                               max_rel_se=max_rel_se, max_spp=max_spp, sensor=j, seed0=seed0,
                               block=block, rounding_rtol=rounding_rtol)
                for j, mu in zip(_sensors(sensor, expected), expected)]
    if _is_reference_integrator(expected):
        ref = _load(expected, "integrator")
        expected = batch_images(scene_obj, ref, batches=batches, spp=spp,
                                seed0=seed0 + REFERENCE_SEED0)
        ours = batch_images(scene_obj, integ, batches=batches, spp=spp, seed0=seed0)
        return _budget(image_test(ours, expected, block=block, alpha=alpha), spp, batches)
    if isinstance(expected, np.ndarray) and expected.ndim >= 2:
        ours = batch_images(scene_obj, integ, batches=batches, spp=spp, seed0=seed0)
        return _budget(image_test(ours, expected, block=block, alpha=alpha), spp, batches)

    # a closed-form mean: grow the sample count (fresh seeds each time) while the estimate is
    # too noisy, up to max_spp; only the last batch set is tested
    kw = {} if rounding_rtol is None else {"rounding_rtol": rounding_rtol}
    n, seed = spp, seed0
    while True:
        x = batch_means(scene_obj, integ, batches=batches, spp=n, sensor=sensor, seed0=seed)
        r = _mean_test(x, expected, alpha, **kw)
        if max_spp is None or max_rel_se is None or r.rel_se < max_rel_se or n >= max_spp:
            break
        n, seed = 4 * n, seed + batches
    count_check(alpha)
    return _budget(r, n, batches)


def _budget(r, spp, batches):
    r.spp, r.batches = spp, batches       # what the tested renders used
    return r


def assert_unbiased(scene, expected, integrator=None, *, spp: int = 4096, batches: int = 32,
                    alpha: float = DEFAULT_ALPHA, max_rel_se: float | None = MAX_REL_SE,
                    max_spp: int | None = None, sensor: int = 0, seed0: int = 0,
                    block: int = 4, rounding_rtol: float | None = None):
    """Assert that ``integrator`` renders ``scene`` without bias; return the verdict.

    ``scene``: a dict for ``mi.load_dict``, a file name, or a loaded scene.  ``expected``: a
    number or per-channel numbers (the film's mean, e.g. a radiancemeter's radiance), an image
    (H, W, C: exact) or batch of reference renders (K, H, W, C), or a reference integrator
    (name, dict or object: rendered with the same ``spp`` and ``batches``, other seeds).
    ``integrator``: a dict for ``mi.load_dict``, a plugin name, a loaded integrator, or None
    (the scene's own).

    H0: the estimator is unbiased.  ``batches`` renders of ``spp`` samples with seeds
    ``seed0``, ``seed0 + 1``, ...; rejected at level ``alpha`` (Sidak-corrected over channels,
    or blocks and channels).  Also fails when the relative standard error exceeds
    ``max_rel_se`` (None: never).  With ``max_spp``, a too-noisy closed-form check is repeated
    with 4x the samples and fresh seeds, up to ``max_spp``.  ``sensor`` picks the scene's
    sensor; a sequence of sensors (e.g. ``range(3)``) with one expected value each makes one
    check per sensor and returns their verdicts.  ``block`` is the block size of image
    checks."""
    if not isinstance(sensor, (int, np.integer)):     # several sensors: one check each
        scene = _load(scene, "scene")
        return [assert_unbiased(scene, mu, integrator, spp=spp, batches=batches, alpha=alpha,
                                max_rel_se=max_rel_se, max_spp=max_spp, sensor=j, seed0=seed0,
                                block=block, rounding_rtol=rounding_rtol)
                for j, mu in zip(_sensors(sensor, expected), expected)]
    r = check_unbiased(scene, expected, integrator, spp=spp, batches=batches, alpha=alpha,
                       max_rel_se=max_rel_se, max_spp=max_spp, sensor=sensor, seed0=seed0,
                       block=block, rounding_rtol=rounding_rtol)
    what = f"{_label(integrator)}" + (f" (sensor {sensor})" if sensor else "") + f": H0 {r.h0}"
    if not r.passed:
        raise UnbiasedFailure(f"{what} rejected at alpha {alpha:g}: {r}", r)
    if max_rel_se is not None and not (r.rel_se <= max_rel_se):
        raise UnbiasedFailure(
            f"{what} not rejected, but the test is too weak to see a 5 % bias: relative "
            f"standard error {100 * r.rel_se:.3f} % > {100 * max_rel_se:g} % (more spp or "
            f"batches): {r}", r)
    return r
