"""Each of our estimators against Mitsuba's built-in ``path`` (an independent implementation) on
the Cornell box and the demo, with both sides' variance accounted for.

H0: the same expected image.  Block-wise Welch t (integrators.testing.image_test), Sidak over
blocks and channels, alpha = 1e-4 per comparison.  ``direct_mis`` is compared with ``path`` at
``max_depth`` 2 (direct light), the path integrators at the same ``max_depth`` as the reference."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.testing import assert_unbiased

ROOT = Path(__file__).resolve().parents[1]
SCENES = {
    "cornell": (lambda: mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res="24"), 4),
    "demo": (lambda: mi.load_file(str(ROOT / "scenes" / "veach_mis.xml"), width="48",
                                  height="27"), 3),
}
DEPTH = 4
OURS = {
    "bsdf_path": ({"type": "bsdf_path", "max_depth": DEPTH}, DEPTH),
    "direct_mis": ({"type": "direct_mis", "light_samples": 2, "bsdf_samples": 1}, 2),
    "nee_path": ({"type": "nee_path", "max_depth": DEPTH}, DEPTH),
    "nee_path_adaptive": ({"type": "nee_path", "max_depth": DEPTH,
                           "light_selection": "adaptive", "split": 2}, DEPTH),
    "mis3": ({"type": "mis3", "max_depth": DEPTH}, DEPTH),
}
_cache = {}


def reference(scene_name, depth):
    key = (scene_name, depth)
    if key not in _cache:
        scene = SCENES[scene_name][0]()
        _cache[key] = (scene, testing.batch_images(
            scene, mi.load_dict({"type": "path", "max_depth": depth}), batches=16, spp=1024,
            seed0=7000))
    return _cache[key]


# bsdf_path on the demo is left out: BSDF sampling finds its 0.03-radius lights so rarely that
# 16 x 1024 samples per pixel are heavy-tailed (a block's mean and spread jump with the seed range:
# 0.0195 +- 0.00001, then 0.0197 +- 0.0002, at 16x the samples 0.0225 +- 0.0016, reference 0.0205),
# and a t-test cannot be trusted there at any affordable sample count.  bsdf_path is checked
# against closed forms (furnace, closed sphere) and against path on the Cornell box.
PAIRS = [(s, e) for s in SCENES for e in OURS if (s, e) != ("demo", "bsdf_path")]


@pytest.mark.parametrize("scene_name,est", PAIRS)
def test_same_image_as_mitsuba_path(scene_name, est):
    integ, depth = OURS[est]
    scene, ref = reference(scene_name, depth)
    # no power guard (max_rel_se=None): at this budget the median relative s.e. of a block is
    # 0.14-0.82 % (bsdf_path on the Cornell box 1.7 %); the closed-form tests carry the guard
    assert_unbiased(scene, ref, integ, batches=16, spp=1024, block=SCENES[scene_name][1],
                    max_rel_se=None)
