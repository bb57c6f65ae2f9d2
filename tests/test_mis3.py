"""mis3 (three-PDF one-sample MIS): unbiased for any p-vector and for adaptive selection.

Closed forms (H0 unbiased, Student t on 32 batch means, Sidak over RGB, alpha = 1e-4, relative
s.e. < 0.5 %): the closed emitting box (all bounces) and Lambert's formula (max_depth 2, direct
light only).  Images (H0 same expected image, block Welch test, alpha = 1e-4): the demo scene with
its phong plates and sphere lights against Mitsuba's ``path``.  Negative control: MIS weights
summing to 1.05."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.sampling import mis
from integrators.testing import assert_unbiased, check_unbiased
from integrators.testing.scenes import closed_box_scene, plane_scene

ROOT = Path(__file__).resolve().parents[1]
MAX_REL_SE = 0.005
P_VECTORS = [(1 / 3, 1 / 3, 1 / 3), (0.8, 0.1, 0.1), (0.1, 0.1, 0.8), (0.5, 0.0, 0.5),
             (0.5, 0.5, 0.0)]
# closed box: 32 batches of 4096 spp, 4x more (fresh seeds) for noisier p-vectors up to 64x
CLOSED = {"spp": 4096, "max_spp": 64 * 4096}


@pytest.mark.parametrize("p", P_VECTORS)
def test_closed_box_any_p_vector(p):
    assert_unbiased(closed_box_scene(0.5, 1.0), 2.0,
                    {"type": "mis3", "p_cosine": p[0], "p_glossy": p[1], "p_light": p[2]},
                    **CLOSED)


@pytest.mark.parametrize("heuristic", mis.HEURISTICS)
def test_closed_box_adaptive_every_heuristic(heuristic):
    assert_unbiased(closed_box_scene(0.5, 1.0), 2.0,
                    {"type": "mis3", "selection": "adaptive", "heuristic": heuristic}, **CLOSED)


@pytest.mark.parametrize("p", P_VECTORS[:3] + ["adaptive"])
def test_lambert_direct_light(p):
    d, expected = plane_scene()
    integ = {"type": "mis3", "max_depth": 2, "light_selection": "power"}
    integ.update({"selection": "adaptive"} if p == "adaptive" else
                 {"p_cosine": p[0], "p_glossy": p[1], "p_light": p[2]})
    assert_unbiased(d, expected, integ, sensor=range(len(expected)), batches=32, spp=16384,
                    max_rel_se=2 * MAX_REL_SE)


@pytest.fixture(scope="module")
def veach():
    return mi.load_file(str(ROOT / "scenes" / "veach_mis.xml"), width="48", height="27")


@pytest.fixture(scope="module")
def veach_path(veach):
    return testing.batch_images(veach, mi.load_dict({"type": "path", "max_depth": 4}),
                                batches=16, spp=1024, seed0=500)


@pytest.mark.parametrize("selection", ["learned", "fixed", "adaptive"])
def test_demo_same_image_as_mitsuba_path(veach, veach_path, selection):
    # no power guard (max_rel_se=None): the demo's blocks are too noisy at this budget
    assert_unbiased(veach, veach_path, {"type": "mis3", "max_depth": 4, "selection": selection},
                    batches=16, spp=1024, block=3, max_rel_se=None)


def test_negative_control_weights_summing_to_105(monkeypatch):
    orig = mis.Heuristic.weights
    monkeypatch.setattr(mis.Heuristic, "weights",
                        lambda self, q: [w * 1.05 for w in orig(self, q)])
    r = check_unbiased(closed_box_scene(0.5, 1.0), testing.closed_sphere_radiance(1.0, 0.5, 3),
                       {"type": "mis3", "max_depth": 3}, batches=32, spp=4096)
    assert not r.passed, r


@pytest.mark.slow
def test_veach_regions_no_half_percent_bias():
    """Issue 14's report: on Veach's plates (sphere lights, max_depth 3) mis3 with its defaults
    read about 1 % low in one region against Mitsuba's path.  H0: the same expected image, per
    16 x 16 block (6 regions of the 48 x 27 image) and channel, Welch t on 32 batches of
    20480 spp each side, Sidak over the 18 tests at alpha DEFAULT_ALPHA (false-failure rate
    1.5e-5; critical |t| about 5.7).  The median block's relative s.e. must be below 0.07 %, so
    a 0.5 % bias in a region is t > 7 and rejected with probability above 0.9.  (At 8192 spp
    the blocks' s.e. was 0.105 % for the defaults and 0.131 % for selection=fixed, p = 0.97 and
    0.98, image means within 0.01 % and 0.1 %: no bias at that resolution.)"""
    scene = mi.load_file(str(ROOT / "scenes" / "veach_mis.xml"), width="48", height="27")
    ref = testing.batch_images(scene, mi.load_dict({"type": "path", "max_depth": 3}),
                               batches=32, spp=20480, seed0=900)
    assert_unbiased(scene, ref, {"type": "mis3", "max_depth": 3},
                    batches=32, spp=20480, block=16, max_rel_se=0.0007)
