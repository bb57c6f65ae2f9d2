"""direct_mis against closed forms: Lambert's polygon formula and point lights.

Each check: H0 "the estimator is unbiased" (batch means have the closed-form mean), Student t on
32 batch means, Sidak over RGB, rejected at alpha = 1e-4 (see integrators.testing); every check
also asserts a relative standard error below 0.5 %, so a 3 % bias would give t > 6.
Negative controls: a MIS weight that sums to 1.05 and Mitsuba's own ``direct`` with
``emitter_samples=4`` on a point light (mitsuba3 #1861) must both be rejected.
"""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.sampling import mis
from integrators.sampling.mis import HEURISTICS
from integrators.testing import assert_unbiased, check_unbiased
from integrators.testing.scenes import POINTS, plane_scene

# every check: one per sensor, 32 batches of 8192 spp (unless stated); a noisier estimator gets
# more samples (max_spp = 64 spp): the size is chosen from a pilot run and the test uses only
# fresh batches (new seeds), so the choice cannot bias the test
SPP = 8192


def check(scene_dict, expected, integrator, batches=32, spp=SPP):
    return assert_unbiased(scene_dict, expected, integrator, sensor=range(len(expected)),
                           batches=batches, spp=spp, max_spp=64 * spp)


@pytest.mark.parametrize("selection", ["uniform", "power"])
@pytest.mark.parametrize("heuristic", HEURISTICS)
def test_lambert_every_heuristic(heuristic, selection):
    d, expected = plane_scene()
    check(d, expected, {"type": "direct_mis", "heuristic": heuristic,
                        "light_selection": selection, "light_samples": 2, "bsdf_samples": 1})


@pytest.mark.parametrize("n_l,n_b", [(1, 0), (0, 1), (1, 1), (4, 3)])
def test_lambert_sample_counts(n_l, n_b):
    d, expected = plane_scene()
    check(d, expected, {"type": "direct_mis", "heuristic": "power",
                        "light_samples": n_l, "bsdf_samples": n_b})


# placed so that no light shadows another from any sensor point
POINT_LIGHTS = [((0.3, -0.2, 1.0), 2.0), ((-0.8, -0.9, 1.5), 5.0)]


@pytest.mark.parametrize("n_l", [1, 4, 10])
def test_point_lights_any_light_samples(n_l):
    d, expected = plane_scene(rects=[], points=POINT_LIGHTS)
    check(d, expected, {"type": "direct_mis", "light_samples": n_l, "bsdf_samples": 1},
          batches=16, spp=1024)


def test_point_and_area_lights_power_selection():
    d, expected = plane_scene(points=POINT_LIGHTS)
    check(d, expected, {"type": "direct_mis", "light_samples": 3, "bsdf_samples": 2,
                        "light_selection": "power", "heuristic": "balance"})


def test_negative_control_mitsuba_direct_point_light_bug():
    """Mitsuba's direct with emitter_samples=4 makes point lights 4x too bright (#1861):
    the same check must reject it."""
    d, [expected] = plane_scene(rects=[], points=POINT_LIGHTS, sensors_at=POINTS[:1])
    r = check_unbiased(d, expected, {"type": "direct", "emitter_samples": 4, "bsdf_samples": 1},
                       batches=16, spp=1024, max_spp=64 * 1024)
    assert not r.passed, r


def test_negative_control_weights_summing_to_105(monkeypatch):
    orig = mis.Heuristic.weights
    monkeypatch.setattr(mis.Heuristic, "weights",
                        lambda self, q: [w * 1.05 for w in orig(self, q)])
    d, [expected] = plane_scene(sensors_at=POINTS[:1])
    r = check_unbiased(d, expected, {"type": "direct_mis", "heuristic": "balance"}, spp=SPP,
                       max_spp=64 * SPP)
    assert not r.passed, r


def test_delta_bsdf_direct_light_through_mirror():
    """A perfect mirror under the small light: only BSDF sampling can reach the light through
    the delta lobe (weight 1, no MIS), so the meter sees exactly the light's radiance, 12."""
    target, origin = (0.2, 0.1, 0.0), (0.25, 0.12, 0.5)  # reflected ray hits (0.1, 0.06, 1)
    d, _ = plane_scene(sensors_at=[], bsdf={"type": "conductor", "material": "none"})
    d["sensor"] = testing.radiancemeter(target, origin, 1024)
    scene = mi.load_dict(d)
    for n_l, n_b in [(1, 1), (3, 2)]:
        x = testing.batch_means(scene, mi.load_dict(
            {"type": "direct_mis", "light_samples": n_l, "bsdf_samples": n_b}), 4, 1024)
        assert np.allclose(x, 12.0, rtol=1e-5), x


def test_no_emitters_renders_black_with_warning():
    d = {"type": "scene", "plane": {"type": "rectangle"},
         "sensor": testing.radiancemeter((0, 0, 0), (0, 0, 1), 16)}
    scene = mi.load_dict(d)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        img = mi.render(scene, integrator=mi.load_dict({"type": "direct_mis"}), spp=16)
    assert np.all(np.array(img) == 0)
    assert any("no emitters" in str(x.message) for x in w)
