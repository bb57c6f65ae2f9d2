"""Every light-sampling integrator through specular and glossy chains, against Mitsuba's ``path``.

Scene: a small box lit by its whole ceiling, with a mirror sphere, a glass sphere, a
``roughconductor`` wall facing a ``phong`` wall (glossy-glossy chains) and a diffuse floor and
back wall; 16x16 pixels.  Paths through it cross delta lobes (mirror, glass: reflection and
refraction, caustics on the floor), glossy lobes several times in a row, and light sampling at
every smooth vertex.

H0: the same expected image as Mitsuba's ``path`` at the same ``max_depth`` (``direct_mis``:
``path`` at max_depth 2, the direct light, which includes the light seen in the mirror and in
the glass).  Welch t per 4x4 block and channel on 16 batch means per side, Sidak over blocks and
channels, the kit's DEFAULT_ALPHA; the median relative s.e. of a block must stay below 0.5 % (a 5 %
bias in half of the blocks gives |t| >= 10).  Runtime about 12 s.

Negative controls: tests/mutation.py (mis3-delta-lobe-weight, mis3-glossy-continuation-weight)
and the max_depth off-by-one below.
"""
from __future__ import annotations

import mitsuba as mi
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.testing import assert_unbiased, check_unbiased

T = mi.ScalarTransform4f
RES, BATCHES, SPP, DEPTH = 16, 16, 512, 5


def specular_box(res=RES, spp=SPP) -> dict:
    """The test scene (see the module docstring)."""
    def rect(tw, bsdf, **kw):
        return {"type": "rectangle", "to_world": tw, "bsdf": bsdf, **kw}

    def diffuse(r):
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": r}}
    return {
        "type": "scene",
        "floor": rect(T().translate([0, -1, 0]) @ T().rotate([1, 0, 0], -90),
                      diffuse([0.6, 0.6, 0.6])),
        "back": rect(T().translate([0, 0, -1]), diffuse([0.5, 0.4, 0.3])),
        "left": rect(T().translate([-1, 0, 0]) @ T().rotate([0, 1, 0], 90),
                     {"type": "phong", "diffuse_reflectance": 0.2,
                      "specular_reflectance": 0.6, "exponent": 20.0}),
        "right": rect(T().translate([1, 0, 0]) @ T().rotate([0, 1, 0], -90),
                      {"type": "roughconductor", "material": "Al", "alpha": 0.15}),
        "light": rect(T().translate([0, 1, 0]) @ T().rotate([1, 0, 0], 90),
                      diffuse([0.5, 0.5, 0.5]), emitter={"type": "area", "radiance": 3.0}),
        "mirror": {"type": "sphere", "center": [-0.45, -0.65, -0.3], "radius": 0.35,
                   "bsdf": {"type": "conductor", "material": "none"}},
        "glass": {"type": "sphere", "center": [0.45, -0.65, 0.1], "radius": 0.35,
                  "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": T().look_at(origin=[0, 0, 3.2], target=[0, -0.1, 0],
                                           up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
    }


@pytest.fixture(scope="module")
def scene():
    return mi.load_dict(specular_box())


_refs = {}


def reference(scene, depth):
    """Mitsuba's path at ``depth``: 16 batches of 512 spp (seeds distinct from ours)."""
    if depth not in _refs:
        _refs[depth] = testing.batch_images(scene, mi.load_dict({"type": "path",
                                                                 "max_depth": depth}),
                                            batches=BATCHES, spp=SPP, seed0=50_000)
    return _refs[depth]


OURS = {
    "mis3-fixed": ({"type": "mis3", "max_depth": DEPTH, "selection": "fixed"}, DEPTH),
    "mis3": ({"type": "mis3", "max_depth": DEPTH}, DEPTH),
    "mis3-adaptive": ({"type": "mis3", "max_depth": DEPTH, "selection": "adaptive"}, DEPTH),
    "nee_path": ({"type": "nee_path", "max_depth": DEPTH}, DEPTH),
    "direct_mis": ({"type": "direct_mis", "light_samples": 1, "bsdf_samples": 1}, 2),
}


@pytest.mark.parametrize("name", OURS)
def test_same_image_as_path_through_specular_chains(scene, name):
    integ, depth = OURS[name]
    assert_unbiased(scene, reference(scene, depth), integ, batches=BATCHES, spp=SPP)


@pytest.mark.slow
@pytest.mark.parametrize("extra", [{"selection": "adaptive", "heuristic": "power"},
                                   {"p_cosine": 0.6, "p_glossy": 0.2, "p_light": 0.2},
                                   {"p_cosine": 0.1, "p_glossy": 0.8, "p_light": 0.1},
                                   {"selection": "adaptive", "light_selection": "adaptive"}])
def test_mis3_other_settings_through_specular_chains(scene, extra):
    assert_unbiased(scene, reference(scene, DEPTH), {"type": "mis3", "max_depth": DEPTH, **extra},
                    batches=BATCHES, spp=SPP)


@pytest.mark.slow
@pytest.mark.parametrize("extra", [{"rr": "fixed", "rr_prob": 0.2, "rr_depth": 2},
                                   {"light_samples": 3, "heuristic": "balance", "split": 2}])
def test_nee_path_other_settings_through_specular_chains(scene, extra):
    assert_unbiased(scene, reference(scene, DEPTH), {"type": "nee_path", "max_depth": DEPTH,
                                                     **extra}, batches=BATCHES, spp=SPP)


def test_negative_control_one_bounce_short(scene):
    """The test sees what a chain loses: mis3 at max_depth 4 against path at 5 is rejected."""
    r = check_unbiased(scene, reference(scene, DEPTH), {"type": "mis3", "max_depth": DEPTH - 1},
                       batches=BATCHES, spp=SPP)
    assert not r.passed, r
