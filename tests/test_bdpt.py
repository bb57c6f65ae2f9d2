"""Bidirectional path tracing (``bdpt``, issue 17): unbiased, every strategy, through ``render``.

Statistical tests (the kit's: H0 "unbiased", rejected at the kit's DEFAULT_ALPHA, Sidak-corrected
over channels or blocks and channels, so each check falsely fails with probability <= alpha):

* closed emitting box (radiancemeter: strategies s = 0, s = 1 and every s, t >= 2; t = 1 has
  no use for a delta-direction sensor): L = le sum_{k < max_depth} rho^k, with the power and
  the balance heuristic, several depths, fixed and throughput roulette, and paths longer than
  ``bidir_depth`` (unbounded or not: s = 0 and s = 1 alone past it); the test must also be
  strong enough to see a 5 % bias (relative s.e. bound of the kit);
* polygon lights and point lights over a plane (Lambert's closed form, direct light);
* the same expected image as Mitsuba's ``path`` (Welch t per 4x4 block and channel, 16 batch
  means per side) on the Cornell box (every strategy, light tracing onto the film included),
  on a box with a glass and a mirror sphere and glossy walls (delta lobes on both subpaths), on
  the Cornell box lit by a point and a spot light (delta lights) and on the caustic scene;
  the Cornell box at max_depth -1 with a short ``bidir_depth``;
* environment lights: furnaces (a diffuse and a glass sphere in a constant environment, closed
  forms) and the same expected image as path under a constant sky and an envmap; several lights
  (environment, area lamp, point light) with every ``light_selection`` mode; ``hide_emitters``
  against path (Cornell box) and nee_path (a lamp in front of a lit floor: see the test);
* determinism: two renders with the same seed are identical, other seeds differ.  Checked on
  one Dr.Jit thread: the splats are atomic float adds (no update is lost: the expected-image
  tests see every splat), but with several threads their order, and so the last bits of a
  pixel's sum, depends on the schedule (up to 7e-9 relative seen here), as for Mitsuba's own
  film.

Negative controls: tests/mutants_bdpt.py (each planted bug must fail one of these tests).
"""
from __future__ import annotations

import gc

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.plugins.base import SceneError
from integrators.testing import assert_unbiased, check_unbiased, closed_box, polygon_light_plane

T = mi.ScalarTransform4f
RES, BATCHES, SPP = 16, 16, 256


# ---- environment lights, several lights, light selection, hide_emitters -------------------------
@pytest.mark.parametrize("case,depth,extra", [
    ("diffuse", 3, {}),
    ("diffuse", 2, {"heuristic": "balance"}),
    ("glass", 5, {}),
    ("diffuse", -1, {"bidir_depth": 2}),
])
def test_environment_furnaces(case, depth, extra):
    """Closed forms in a constant environment (H0: unbiased): a diffuse sphere, L = rho env
    (light subpaths from the environment, light tracing cannot reach the radiancemeter, so
    s = 0 escapes, next-event estimation and connections carry it); a glass sphere (every
    vertex delta: the camera subpath's escapes alone, weight 1)."""
    if case == "diffuse":
        cf = testing.furnace(rho=0.6, env=1.0, spp=4096)
    else:
        cf = testing.dielectric_furnace(eta=1.5, max_depth=depth, spp=4096)
    assert_unbiased(cf.scene, cf.expected, {"type": "bdpt", "max_depth": depth, **extra},
                    spp=4096, batches=16)


def sky_scene(env, res=RES, ball="glass", lights=False):
    """A floor, a glass (or diffuse) ball and a green diffuse ball under an environment;
    ``lights``: also a small area lamp and a point light (several lights of three kinds)."""
    d = {"type": "scene", "env": env,
         "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(3),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                               "value": [0.6, 0.5, 0.4]}}},
         "ball": {"type": "sphere", "center": [0.5, 0.6, 0], "radius": 0.6,
                  "bsdf": {"type": "dielectric"} if ball == "glass" else {"type": "diffuse"}},
         "ball2": {"type": "sphere", "center": [-0.7, 0.4, 0.3], "radius": 0.4,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                               "value": [0.2, 0.7, 0.3]}}},
         "sensor": {"type": "perspective", "fov": 45,
                    "to_world": T().look_at(origin=[0, 2, 4], target=[0, 0.3, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": res, "height": res,
                             "rfilter": {"type": "gaussian"}}}}
    if lights:
        d["lamp"] = {"type": "rectangle",
                     "to_world": T().translate([-0.3, 1.0, 1.8]).rotate([1, 0, 0], 90).scale(0.3),
                     "emitter": {"type": "area", "radiance": {"type": "rgb",
                                                              "value": [8.0, 6.0, 4.0]}}}
        d["point"] = {"type": "point", "position": [1.2, 1.0, 1.0],
                      "intensity": {"type": "rgb", "value": [2.0, 2.0, 3.0]}}
    return mi.load_dict(d)


def envmap_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("env") / "env.exr"
    rng = np.random.default_rng(1)
    mi.Bitmap(rng.uniform(0.2, 3.0, (16, 32, 3)).astype(np.float32)).write(str(path))
    return str(path)


@pytest.mark.parametrize("env", ["constant", "envmap"])
def test_environment_same_image_as_path(env, tmp_path_factory):
    """A glass ball, a diffuse ball and a floor under a constant sky or a textured envmap:
    the same expected image as Mitsuba's path (every strategy with an infinite light)."""
    emitter = {"type": "constant", "radiance": {"type": "rgb", "value": [0.8, 0.9, 1.0]}} \
        if env == "constant" else {"type": "envmap", "filename": envmap_file(tmp_path_factory)}
    scene = sky_scene(emitter)
    assert_unbiased(scene, reference(env, scene, 5), {"type": "bdpt", "max_depth": 5},
                    batches=BATCHES, spp=SPP)


@pytest.mark.parametrize("mode", ["uniform", "power", "adaptive", "bvh", "ris"])
def test_light_selection_modes_same_image_as_path(mode):
    """An environment, an area lamp and a point light (diffuse balls: path has no caustics
    to miss), each light_selection mode: the same expected image as Mitsuba's path
    (adaptive, bvh and ris: next-event estimation by their pmf, light subpaths by power)."""
    scene = sky_scene({"type": "constant", "radiance": {"type": "rgb",
                                                        "value": [0.2, 0.25, 0.3]}},
                      ball="diffuse", lights=True)
    assert_unbiased(scene, reference("lights", scene, 4),
                    {"type": "bdpt", "max_depth": 4, "light_selection": mode},
                    batches=BATCHES, spp=SPP)


@pytest.mark.parametrize("key", ["cornell", "sky"])
def test_hide_emitters_same_image(key):
    """hide_emitters: area lights transparent to the camera (the ceiling behind the Cornell
    box's light, the floor behind a lamp under a sky; light tracing sees through them too and
    never onto them), the environment black.  Against Mitsuba's path on the Cornell box, and
    against the project's nee_path on the sky with a lamp in front of the lit floor: Mitsuba
    3.9's path does not see through a hidden area light (it scatters off the light's own BSDF;
    measured 1 % off nee_path and bdpt there, which agree), the project's integrators do."""
    if key == "cornell":
        scene, ref = cornell(), {"type": "path"}
    else:
        scene, ref = sky_scene({"type": "constant", "radiance": {"type": "rgb",
                                                                 "value": [0.2, 0.25, 0.3]}},
                               ball="diffuse", lights=True), {"type": "nee_path"}
    if ("hide", key) not in _refs:
        _refs["hide", key] = testing.batch_images(
            scene, mi.load_dict({**ref, "max_depth": 5, "hide_emitters": True}),
            batches=BATCHES, spp=4 * SPP, seed0=71_000)
    assert_unbiased(scene, _refs["hide", key],
                    {"type": "bdpt", "max_depth": 5, "hide_emitters": True},
                    batches=BATCHES, spp=SPP if key == "cornell" else 2 * SPP)


# ---- closed forms ------------------------------------------------------------------------------
@pytest.mark.parametrize("depth,extra", [
    (2, {}),
    (3, {"heuristic": "balance"}),
    (6, {}),
    (6, {"heuristic": "balance", "rr": "fixed", "rr_prob": 0.3, "rr_depth": 2}),
    (5, {"heuristic": "power", "beta": 3.0, "light_selection": "uniform"}),
    # paths longer than bidir_depth: s = 0 and s = 1 only, unbounded (-1) or up to max_depth
    (-1, {}),
    (-1, {"bidir_depth": 3}),
    (7, {"bidir_depth": 2, "heuristic": "balance"}),
])
def test_closed_box(depth, extra):
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=depth, spp=1024)
    assert_unbiased(scene, expected, {"type": "bdpt", "max_depth": depth, **extra},
                    spp=1024, batches=16)


def test_closed_box_direct_only_and_nothing():
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=1, spp=64)
    img = mi.render(mi.load_dict(scene), integrator=mi.load_dict({"type": "bdpt",
                                                                   "max_depth": 1}))
    assert np.allclose(np.array(img), 1.0, rtol=1e-5)     # max_depth 1: the emission seen
    img = mi.render(mi.load_dict(scene), integrator=mi.load_dict({"type": "bdpt",
                                                                   "max_depth": 0}))
    assert np.all(np.array(img) == 0)                      # max_depth 0: nothing


def test_polygon_and_point_lights():
    case = polygon_light_plane(points=(((0.3, 0.2, 0.8), 0.7),), spp=16384)
    assert_unbiased(case.scene, case.expected, {"type": "bdpt", "max_depth": 2},
                    spp=16384, batches=16)


# ---- against Mitsuba's path ---------------------------------------------------------------------
_refs = {}


def reference(key, scene, depth):
    if (key, depth) not in _refs:
        _refs[key, depth] = testing.batch_images(
            scene, mi.load_dict({"type": "path", "max_depth": depth}), batches=BATCHES,
            spp=4 * SPP, seed0=70_000)
    return _refs[key, depth]


def cornell(res=RES, lights="area"):
    d = mi.cornell_box()
    d["sensor"]["film"].update({"width": res, "height": res, "rfilter": {"type": "gaussian"}})
    if lights == "delta":
        del d["light"]
        d["point"] = {"type": "point", "position": [0.3, 0.8, 0.2],
                      "intensity": {"type": "rgb", "value": [2.0, 1.8, 1.5]}}
        d["spot"] = {"type": "spot", "cutoff_angle": 35.0,
                     "to_world": T().look_at(origin=[-0.5, 0.9, -0.3], target=[-0.2, -1, 0],
                                             up=[0, 0, 1]),
                     "intensity": {"type": "rgb", "value": [6.0, 6.0, 8.0]}}
    return mi.load_dict(d)


def test_cornell_box_same_image_as_path():
    scene = cornell()
    assert_unbiased(scene, reference("cornell", scene, 5), {"type": "bdpt", "max_depth": 5},
                    batches=BATCHES, spp=SPP)


def test_cornell_box_unbounded_same_image_as_path():
    """max_depth -1 with bidir_depth 3: paths of 4 or more segments (up to Russian roulette)
    by s = 0 and s = 1 with their own weights, every strategy (light tracing too) below."""
    scene = cornell()
    assert_unbiased(scene, reference("cornell", scene, -1),
                    {"type": "bdpt", "max_depth": -1, "bidir_depth": 3},
                    batches=BATCHES, spp=SPP)


def test_point_and_spot_lights_same_image_as_path():
    scene = cornell(lights="delta")
    assert_unbiased(scene, reference("delta", scene, 5),
                    {"type": "bdpt", "max_depth": 5, "heuristic": "balance"},
                    batches=BATCHES, spp=2 * SPP)


def test_glass_mirror_glossy_same_image_as_path():
    from test_specular import specular_box
    scene = mi.load_dict(specular_box(res=RES, spp=SPP))
    assert_unbiased(scene, reference("specular", scene, 5), {"type": "bdpt", "max_depth": 5},
                    batches=BATCHES, spp=SPP)


@pytest.mark.slow
def test_caustic_scene_same_image_as_path():
    scene = mi.load_file("scenes/caustic.xml", res=8)
    ref = testing.batch_images(scene, mi.load_dict({"type": "path", "max_depth": 6}),
                               batches=BATCHES, spp=65536, seed0=80_000)
    # one 8x8 block: path's caustic noise needs the whole image for a 0.5 % relative s.e.
    assert_unbiased(scene, ref, {"type": "bdpt", "max_depth": 6}, batches=BATCHES, spp=4096,
                    block=8)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ajar_door", "glass_shade"])
def test_scenes_same_image_as_path(name):
    scene = mi.load_file(f"scenes/{name}.xml", res=8)
    ref = testing.batch_images(scene, mi.load_dict({"type": "path", "max_depth": 6}),
                               batches=BATCHES, spp=65536, seed0=90_000)
    assert_unbiased(scene, ref, {"type": "bdpt", "max_depth": 6}, batches=BATCHES, spp=4096)


# ---- strategy images -------------------------------------------------------------------------
def strategy_parts(images, n):
    """(batches, H, W, n, 3) strategy layers of renders with strategy_images (film: RGB)."""
    return images[..., 3:].reshape(*images.shape[:3], n, 3)


def test_strategy_images_sum_to_the_image():
    from integrators.plugins.bdpt import strategy_list
    scene = cornell(res=8)
    img = np.array(mi.render(scene, integrator=mi.load_dict(
        {"type": "bdpt", "max_depth": 4, "strategy_images": True}), spp=16, seed=2))
    plain = np.array(mi.render(scene, integrator=mi.load_dict({"type": "bdpt", "max_depth": 4}),
                               spp=16, seed=2))
    parts = strategy_parts(img[None], len(strategy_list(4)))[0]
    assert img.shape[-1] == 3 + 3 * len(strategy_list(4))
    assert np.allclose(parts.sum(-2), img[..., :3], rtol=1e-4, atol=1e-6)
    assert np.allclose(img[..., :3], plain, rtol=1e-4, atol=1e-6)


def test_each_unweighted_strategy_estimates_its_path_length():
    """Where every strategy can produce every path (diffuse box, area light, pinhole), each
    unweighted strategy image of path length k has the expected image of all paths of length
    k, which is the sum of the MIS-weighted strategy images of length k; so the unweighted
    images of one length sum to (k + 1) x that (the check of the MIS weights' partition of
    unity and of every strategy's own estimate).  Image tests per strategy (k = 2, 3)."""
    from integrators.plugins.bdpt import strategy_list
    scene = cornell(res=8)
    names = strategy_list(3)
    un = strategy_parts(testing.batch_images(scene, mi.load_dict(
        {"type": "bdpt", "max_depth": 3, "heuristic": "none", "strategy_images": True}),
        batches=BATCHES, spp=2 * SPP, seed0=1_000), len(names))
    mis = strategy_parts(testing.batch_images(scene, mi.load_dict(
        {"type": "bdpt", "max_depth": 3, "strategy_images": True}),
        batches=BATCHES, spp=2 * SPP, seed0=2_000), len(names))
    for k in (2, 3):
        idx = [j for j, (s, t) in enumerate(names) if s + t - 1 == k]
        assert len(idx) == k + 1
        ref = mis[..., idx, :].sum(-2)
        for j in idx:
            r = testing.image_test(un[..., j, :], ref)
            assert r.passed, (names[j], r)


def test_negative_control_one_bounce_short():
    """The comparison sees a missing bounce: bdpt at max_depth 4 against path at 5."""
    scene = cornell()
    r = check_unbiased(scene, reference("cornell", scene, 5), {"type": "bdpt", "max_depth": 4},
                       batches=BATCHES, spp=SPP)
    assert not r.passed, r


# ---- determinism, the render command, bad input -------------------------------------------------
@pytest.fixture
def one_thread():
    import drjit as dr
    n = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(n)


def test_same_seed_same_image(one_thread):
    scene = mi.load_file("scenes/caustic.xml", res=16)
    integ = mi.load_dict({"type": "bdpt"})
    a = np.array(mi.render(scene, integrator=integ, spp=8, seed=5))
    b = np.array(mi.render(scene, integrator=integ, spp=8, seed=5))
    c = np.array(mi.render(scene, integrator=integ, spp=8, seed=6))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_chunks_equal_passes_in_expectation(monkeypatch):
    """A render split into chunks (memory budget) is still an unbiased render of all its spp."""
    import integrators.plugins.bdpt as bdpt
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=4, spp=512)
    # light vertices of one sample at max_depth 4: 2 x (27 + 3) x 4 bytes: 125 spp per chunk
    monkeypatch.setattr(bdpt, "MEMORY_BUDGET", 125 * 240)
    assert_unbiased(scene, expected, {"type": "bdpt", "max_depth": 4}, spp=512, batches=16)


def test_progressive_render_and_merge(tmp_path, one_thread):
    from integrators.app import progressive
    scene = mi.load_file("scenes/glass_shade.xml", res=8)
    acc = progressive.render(scene, spp=16, seed=3)
    assert acc.spp == 16 and acc.passes >= 2
    assert np.isfinite(acc.mean()).all() and acc.mean().mean() > 0
    again = progressive.render(scene, spp=16, seed=3)
    assert np.array_equal(acc.mean(), again.mean())
    other = progressive.render(scene, spp=16, seed=3 + acc.passes)
    merged = acc.merge(other)
    assert merged.spp == 32


def test_cli_render(tmp_path):
    import subprocess
    import sys
    out = tmp_path / "caustic.exr"
    r = subprocess.run([sys.executable, "-m", "integrators", "render", "scenes/caustic.xml",
                        "-o", str(out), "--spp", "4", "-D", "res=8", "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert out.exists()


@pytest.mark.parametrize("props,needle", [
    ({"max_depth": -2}, "max_depth"),
    ({"bidir_depth": 1}, "bidir_depth"),
    ({"bidir_depth": 65}, "bidir_depth"),
    ({"strategy_images": True}, "max_depth"),
    ({"strategy_images": True, "max_depth": 9, "bidir_depth": 8}, "max_depth"),
    ({"heuristic": "cutoff"}, "heuristic"),
    ({"light_selection": "tree"}, "light_selection"),
])
def test_bad_parameters_one_line(props, needle):
    with pytest.raises(Exception) as e:
        mi.load_dict({"type": "bdpt", **props})
    msg = str(e.value)
    assert needle in msg and "allowed" in msg.lower()


def test_directional_refused_in_one_line():
    scene = mi.load_dict({"type": "scene", "sun": {"type": "directional",
                                                   "direction": [0, -1, 0]},
                          "s": {"type": "sphere"},
                          "sensor": {"type": "perspective",
                                     "to_world": T().look_at(origin=[0, 0, 4], target=[0, 0, 0],
                                                             up=[0, 1, 0]),
                                     "film": {"type": "hdrfilm", "width": 4, "height": 4}}})
    with pytest.raises(Exception) as e:
        mi.render(scene, integrator=mi.load_dict({"type": "bdpt"}))
    err = e.value
    while err is not None and not isinstance(err, SceneError):   # mi.render wraps it
        err = err.__cause__ or err.__context__
    msg, ok = str(e.value), err is not None and "\n" not in str(err) and "infinite" in str(err)
    # the traceback's frames hold the scene in a reference cycle: free it now, not whenever
    # the cyclic collector runs (a scene freed while a later test records its kernels aborts)
    del e, err
    gc.collect()
    assert ok, msg
