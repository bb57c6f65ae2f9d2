"""Scene features every integrator must honour or refuse: null boundaries, hidden emitters,
participating media, delta-only lights, bad emitter values.

H0 of the image checks: the same expected image as Mitsuba's own integrator with the same
settings (``path``; ``direct`` for ``direct_mis``), block-wise Welch t, Sidak over blocks
(:func:`integrators.testing.assert_unbiased` with a reference integrator, alpha 1.5e-5 each).
Each check must also be strong enough to see a 5 % bias (median relative s.e. of a block below
1 %: these images are small and noisy, so the guard is 1 %, not the kit's 0.5 %; a 5 % bias
still gives |t| >= 5 per block).  Negative controls: hidden emitters ignored is rejected
here; a null boundary treated as an occluder (the old ``mis3``) and ``hide_emitters`` ignored
by the camera hit are mutants in ``tests/mutation.py``.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.plugins.base import SceneError
from integrators.testing import assert_unbiased, check_unbiased

T = mi.ScalarTransform4f
OURS_PATH = ("nee_path", "mis3", "bsdf_path")
MAX_REL_SE = 0.01


def room(extra=None, res=12):
    """A diffuse floor and back wall, a small area light, a dim environment."""
    d = {"type": "scene",
         "env": {"type": "constant", "radiance": 0.3},
         "light": {"type": "rectangle", "emitter": {"type": "area", "radiance": 8.0},
                   "to_world": T().translate([0.0, 0.2, 0.9]).scale(0.25)},
         "floor": {"type": "rectangle", "to_world": T().translate([0, -0.6, 0]).rotate([1, 0, 0], -90)
                   .scale(2.0), "bsdf": {"type": "diffuse", "reflectance": 0.6}},
         "wall": {"type": "rectangle", "to_world": T().translate([0, 0, -0.5]).scale(2.0),
                  "bsdf": {"type": "diffuse", "reflectance": 0.5}},
         "sensor": {"type": "perspective", "fov": 50,
                    "to_world": T().look_at([0, 0.3, 3.2], [0, -0.1, 0], [0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": res, "height": res,
                             "rfilter": {"type": "box"}}}}
    d.update(extra or {})
    return d


def reference(name, **kw):
    return {"type": "direct" if name == "direct_mis" else "path", **kw}


def ours(name, **kw):
    d = {"type": name, **kw}
    if name == "direct_mis":
        d.pop("max_depth", None)
    return d


# ---- hide_emitters ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", OURS_PATH + ("direct_mis",))
def test_hide_emitters_matches_mitsuba(name):
    scene = mi.load_dict(room())
    kw = {"hide_emitters": True, "max_depth": 3}
    ref = reference(name, **({"hide_emitters": True} if name == "direct_mis" else kw))
    assert_unbiased(scene, ref, ours(name, **kw), spp=256, batches=16, max_rel_se=MAX_REL_SE)


def test_hide_emitters_shows_what_is_behind_the_light():
    scene = mi.load_dict(room())
    seen = np.array(mi.render(scene, integrator=mi.load_dict({"type": "nee_path"}), spp=64))
    hidden = np.array(mi.render(scene, integrator=mi.load_dict(
        {"type": "nee_path", "hide_emitters": True}), spp=64))
    assert seen.max() >= 8.0 > 2.0 > hidden.max()


def test_negative_control_hide_emitters_ignored():
    scene = mi.load_dict(room())
    r = check_unbiased(scene, {"type": "path", "hide_emitters": True, "max_depth": 3},
                       {"type": "nee_path", "max_depth": 3}, spp=256, batches=16)
    assert not r.passed, r


# ---- null boundaries -------------------------------------------------------------------------
NULL_BOX = {"nullbox": {"type": "cube", "bsdf": {"type": "null"},
                        "to_world": T().translate([0.0, 0.0, 0.6]).scale(0.7)}}


@pytest.mark.parametrize("name", OURS_PATH + ("direct_mis",))
def test_null_boundary_matches_mitsuba(name):
    """A null-BSDF box around the light and between it and the camera: every integrator passes
    through it as Mitsuba's do (shadow rays are blocked by it in Mitsuba's integrators too)."""
    scene = mi.load_dict(room(NULL_BOX))
    kw = {"max_depth": 5}
    assert_unbiased(scene, reference(name, **({} if name == "direct_mis" else kw)),
                    ours(name, **kw), spp=256, batches=16, max_rel_se=MAX_REL_SE)


@pytest.mark.parametrize("selection", ["fixed", "adaptive"])
def test_mis3_null_boundary_is_not_an_occluder(selection):
    scene = mi.load_dict(room(NULL_BOX))
    img = np.array(mi.render(scene, integrator=mi.load_dict(
        {"type": "mis3", "selection": selection}), spp=64))
    assert img.max() >= 8.0   # the light is seen through the null box


# ---- participating media ---------------------------------------------------------------------
@pytest.mark.parametrize("name", OURS_PATH + ("direct_mis",))
@pytest.mark.parametrize("where", ["interior", "sensor"])
def test_media_are_refused_in_one_line(name, where):
    medium = {"type": "homogeneous", "albedo": 0.5, "sigma_t": 1.0}
    if where == "interior":
        extra = {"fog": {"type": "sphere", "radius": 0.3, "bsdf": {"type": "null"},
                         "interior": medium}}
        scene = room(extra)
    else:
        scene = room()
        scene["sensor"]["medium"] = medium
    scene = mi.load_dict(scene)
    with pytest.raises(Exception) as info:
        mi.render(scene, integrator=mi.load_dict({"type": name}), spp=1)
    err = info.value
    while err is not None and not isinstance(err, SceneError):
        err = err.__cause__
    assert err is not None, info.value
    msg = str(err)
    assert "\n" not in msg and "participating medium" in msg and "volpath" in msg, msg


# ---- delta-only lights -----------------------------------------------------------------------
def delta_scene():
    d = room()
    del d["light"]
    d["env"] = {"type": "constant", "radiance": 0.0}
    d["point"] = {"type": "point", "position": [0.3, 0.6, 0.8], "intensity": 2.0}
    d["spot"] = {"type": "spot", "intensity": 6.0, "cutoff_angle": 35,
                 "to_world": T().look_at([-0.5, 1.2, 1.0], [0, -0.6, 0], [0, 1, 0])}
    return d


@pytest.mark.parametrize("name", ("nee_path", "mis3", "direct_mis"))
def test_delta_only_lights_match_mitsuba(name):
    scene = mi.load_dict(delta_scene())
    kw = {"max_depth": 3}
    assert_unbiased(scene, reference(name, **({} if name == "direct_mis" else kw)),
                    ours(name, **kw), spp=256, batches=16, max_rel_se=MAX_REL_SE)


def test_bsdf_path_warns_once_about_delta_lights():
    scene = mi.load_dict(delta_scene())
    integ = mi.load_dict({"type": "bsdf_path"})
    with pytest.warns(RuntimeWarning, match="cannot reach the scene's point, spot or directional") \
            as rec:
        img = mi.render(scene, integrator=integ, spp=4)
        mi.render(scene, integrator=integ, spp=4, seed=1)
    assert len([w for w in rec if "cannot reach" in str(w.message)]) == 1
    assert "\n" not in str(rec[0].message)
    assert np.array(img).max() == 0.0


# ---- bad values in Mitsuba's own plugins -----------------------------------------------------
@pytest.mark.parametrize("radiance", [float("nan"), float("inf"), -1.0])
def test_bad_emitter_radiance_is_refused(radiance):
    d = room()
    d["light"]["emitter"]["radiance"] = radiance
    scene = mi.load_dict(d)
    with pytest.raises(Exception) as info:
        mi.render(scene, integrator=mi.load_dict({"type": "nee_path"}), spp=1)
    err = info.value
    while err is not None and not isinstance(err, SceneError):
        err = err.__cause__
    assert err is not None and "emitter 'light'" in str(err) and "radiance" in str(err), \
        info.value
