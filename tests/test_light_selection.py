"""Light selection: the power pmf is proportional to each emitter's closed-form power.

These are deterministic checks (the power estimate is exact for constant emitters, up to
float rounding of the low-discrepancy average), so no significance level is involved."""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.sampling.light_selection import LightSelection, emitter_power, selection_pmf

T = mi.ScalarTransform4f


def scene_dict():
    return {
        "type": "scene",
        "ball": {"type": "sphere", "center": [3, 0, 0], "radius": 0.5,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1, 2, 3]}}},
        "rect": {"type": "rectangle", "to_world": T().translate([0, 0, 4]).scale([0.5, 2.0, 1]),
                 "emitter": {"type": "area", "radiance": 5.0}},
        "point": {"type": "point", "position": [0, 3, 0], "intensity": 7.0},
        # beam_width == cutoff_angle: a hard-edged cone, power I * 2 pi (1 - cos(cutoff))
        "spot": {"type": "spot", "to_world": T().look_at([0, 3, 0], [0, 0, 0], [0, 0, 1]),
                 "intensity": 4.0, "cutoff_angle": 30.0, "beam_width": 30.0},
        "dead": {"type": "sphere", "center": [-3, 0, 0], "radius": 0.2,
                 "emitter": {"type": "area", "radiance": 0.0}},
        "plane": {"type": "rectangle", "to_world": T().scale(6.0)},
    }


def closed_form(name):
    return {
        "ball": math.pi * (4 * math.pi * 0.25) * 2.0,     # pi * area * mean radiance
        "rect": math.pi * (1.0 * 4.0) * 5.0,       # [-1,1]^2 scaled by (0.5, 2)
        "point": 4 * math.pi * 7.0,
        "spot": 4.0 * 2 * math.pi * (1 - math.cos(math.radians(30.0))),
        "dead": 0.0,
    }[name]


def test_emitter_power_closed_forms():
    scene = mi.load_dict(scene_dict())
    names = ["ball", "rect", "point", "spot", "dead"]
    got = {}
    for e in scene.emitters():
        key = {"PointLight": "point", "SpotLight": "spot"}.get(e.class_name())
        if key is None:  # area lights: tell them apart by their shape's area
            area = e.get_shape().surface_area()
            area = float(np.array(area).ravel()[0])
            key = {round(math.pi, 4): "ball", 4.0: "rect"}.get(round(area, 4), "dead")
        got[key] = emitter_power(e)
    for k in names:
        assert got[k] == pytest.approx(closed_form(k), rel=2e-3, abs=1e-6), (k, got[k])


def test_power_pmf_proportional_to_power_and_uniform():
    scene = mi.load_dict(scene_dict())
    powers = np.array([emitter_power(e) for e in scene.emitters()])
    pmf = selection_pmf(scene, "power")
    assert pmf.sum() == pytest.approx(1.0)
    assert np.allclose(pmf, powers / powers.sum(), rtol=1e-6)
    assert np.count_nonzero(pmf == 0) == 1          # the zero-power light is never chosen
    assert np.allclose(selection_pmf(scene, "uniform"), 1.0 / len(powers))


def test_constant_environment_power_uses_bounding_sphere():
    d = {"type": "scene", "ball": {"type": "sphere", "radius": 2.0},
         "env": {"type": "constant", "radiance": 0.5}}
    scene = mi.load_dict(d)
    r = scene.bbox().bounding_sphere().radius
    [e] = scene.emitters()
    assert emitter_power(e) == pytest.approx(math.pi * 0.5 * 4 * math.pi * r * r, rel=1e-3)


def test_textured_emitter_uses_mean_radiance():
    d = {"type": "scene",
         "rect": {"type": "rectangle",
                  "emitter": {"type": "area", "radiance": {
                      "type": "checkerboard", "color0": 1.0, "color1": 3.0}}}}
    scene = mi.load_dict(d)
    [e] = scene.emitters()
    assert emitter_power(e) == pytest.approx(math.pi * 4.0 * 2.0, rel=1e-2)


def test_pmf_lookup_by_emitter_pointer_matches_table():
    """The per-pointer lookup used for BSDF-sampled hits agrees with the pmf table."""
    import drjit as dr
    scene = mi.load_dict(scene_dict())
    sel = LightSelection(scene, "power")
    ptrs = scene.emitters_dr()
    assert np.allclose(np.array(sel.pmf(ptrs)), sel.pmf_np, rtol=1e-6)
    # and sampling draws each emitter with that probability
    n = 1 << 20
    u = (dr.arange(mi.Float, n) + 0.5) / n
    em, p = sel.sample(u)
    ids = np.array(dr.reinterpret_array(mi.UInt32, em))
    index_of = {int(i): j for j, i in enumerate(np.array(dr.reinterpret_array(mi.UInt32, ptrs)))}
    idx = np.array([index_of[int(i)] for i in ids])
    counts = np.bincount(idx, minlength=len(sel.pmf_np)) / n
    assert np.allclose(counts, sel.pmf_np, atol=2.0 / n + 1e-6)
    # the reported probability is the drawn emitter's
    assert np.allclose(np.array(p), sel.pmf_np[idx], rtol=1e-6)


def test_all_zero_power_falls_back_to_uniform():
    d = {"type": "scene",
         "a": {"type": "sphere", "emitter": {"type": "area", "radiance": 0.0}},
         "b": {"type": "point", "position": [0, 0, 3], "intensity": 0.0}}
    assert np.allclose(selection_pmf(mi.load_dict(d), "power"), 0.5)


def test_cumulative_order_is_spatial_and_independent_of_mitsubas_order():
    """The cumulative pmf's order (light_selection.spatial_order) depends on the emitters and
    their positions, not on the order Mitsuba lists them in (which changes between processes:
    plugins load in parallel), so a given uniform picks the same light in every process;
    emitters without a position come first."""
    from integrators.sampling.light_selection import spatial_order
    d = {"type": "scene", "env": {"type": "constant", "radiance": 0.1}}
    for k in range(12):
        d[f"s{k}"] = {"type": "sphere", "center": [float(k % 4), float(k // 4), 2.0],
                      "radius": 0.1, "emitter": {"type": "area", "radiance": 1.0 + k}}
    scene = mi.load_dict(d)
    ems = list(scene.emitters())
    pmf = np.arange(1.0, len(ems) + 1.0)
    first = [ems[j] for j in spatial_order(ems, pmf)]
    perm = np.random.default_rng(1).permutation(len(ems))
    again = [ems[perm[j]] for j in spatial_order([ems[i] for i in perm], pmf[perm])]
    assert [e.ptr for e in first] == [e.ptr for e in again]
    assert first[0].get_shape() is None          # the environment first
