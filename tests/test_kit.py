"""The public test kit, used as a user would: a user-written Python integrator (a cosine-sampling
path tracer without light sampling) tested with ``integrators.testing`` and the pytest plugin's
fixtures only.

Each ``assert_unbiased`` check: H0 "unbiased", Student t on 32 batch means against a closed form
(Sidak over RGB) or block-wise Welch t against Mitsuba's ``path`` (Sidak over blocks and
channels), alpha = DEFAULT_ALPHA (1.5e-5), and a relative standard error below 0.5 %.  The kit
must pass the correct integrator and reject two deliberately biased variants (every path weight
5 % too high; the 1/pdf factor left out), and fail a check too noisy to see a 5 % bias."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.testing import (CHECKS, DEFAULT_ALPHA, assert_bsdf_sampling, assert_sampling,
                                 assert_unbiased, check_unbiased, chi2_test, closed_box,
                                 polygon_light_plane)

# chi-square tests here at DEFAULT_ALPHA each (the kit's default, 1e-3, would spend half of the
# suite's false-failure budget); their negative control is rejected with p ~ 0 regardless
CHI2 = {"sample_count": 200_000, "alpha": DEFAULT_ALPHA}


# ---------------------------------------------------------------------------------------------
# a user's integrator
class CosinePath(mi.SamplingIntegrator):
    """Path tracer with cosine-weighted hemisphere sampling and no light sampling: emission is
    collected where paths hit emitters.  ``max_depth`` counts intersections like Mitsuba's
    (1: emitters seen directly).  ``weight`` scales every bounce and ``use_pdf`` = false drops
    the 1/pdf factor: the two deliberately biased variants."""

    def __init__(self, props):
        super().__init__(props)
        self.max_depth = props.get("max_depth", 4)
        self.weight = props.get("weight", 1.0)
        self.use_pdf = props.get("use_pdf", True)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        ctx = mi.BSDFContext()
        for _ in range(self.max_depth):          # unrolled: a fixed, small depth
            si = scene.ray_intersect(ray, active)
            L += dr.select(active, beta * si.emitter(scene, active).eval(si, active), 0.0)
            active &= si.is_valid()
            wo = mi.warp.square_to_cosine_hemisphere(sampler.next_2d(active))
            pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            f = si.bsdf(ray).eval(ctx, si, wo, active)            # BSDF x cosine
            beta *= f * self.weight / (dr.select(pdf > 0, pdf, 1.0) if self.use_pdf else 1.0)
            active &= pdf > 0
            ray = si.spawn_ray(si.to_world(wo))
        return L, mi.Bool(True), []

    def aov_names(self):
        return []

    def to_string(self):
        return f"CosinePath[max_depth={self.max_depth}]"


@pytest.fixture(scope="module", autouse=True)
def registered():
    mi.register_integrator("kit_cosine_path", lambda props: CosinePath(props))


MINE = {"type": "kit_cosine_path"}


# ---------------------------------------------------------------------------------------------
# closed forms
def test_closed_box_passes(closed_box, assert_unbiased):
    """Inside the closed emitting box every path weight is rho exactly: L = sum_{k<4} rho^k."""
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=4)
    r = assert_unbiased(scene, expected, {**MINE, "max_depth": 4})
    assert r.passed and r.rel_se <= 0.005


def test_closed_box_biased_weight_fails(closed_box, assert_unbiased):
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=4)
    with pytest.raises(AssertionError, match="rejected at alpha"):
        assert_unbiased(scene, expected, {**MINE, "max_depth": 4, "weight": 1.05})


PLANE_SPP = 65536          # cosine sampling of the lights: enough for a relative s.e. < 0.5 %


def test_polygon_light_plane_passes(polygon_light_plane, assert_unbiased):
    """Direct light on a diffuse plane (Lambert's formula), found by cosine sampling alone."""
    scene, expected = polygon_light_plane(at=(0.7, 0.3, 0.0))
    assert_unbiased(scene, expected, {**MINE, "max_depth": 2}, spp=PLANE_SPP)


@pytest.mark.parametrize("bias", [{"weight": 1.05}, {"use_pdf": False}],
                         ids=["weight-1.05", "missing-1/pdf"])
def test_polygon_light_plane_biased_fails(polygon_light_plane, bias):
    scene, expected = polygon_light_plane(at=(0.7, 0.3, 0.0))
    r = check_unbiased(scene, expected, {**MINE, "max_depth": 2, **bias}, spp=PLANE_SPP)
    assert r.rel_se < 0.005, r          # rejected by the test, not for being noisy
    assert not r.passed, r
    with pytest.raises(AssertionError, match="rejected at alpha"):
        assert_unbiased(scene, expected, {**MINE, "max_depth": 2, **bias}, spp=PLANE_SPP)


def test_too_noisy_to_see_a_bias_fails():
    """64 samples per batch: not rejected, but far too noisy to claim anything."""
    scene, expected = polygon_light_plane(at=(0.7, 0.3, 0.0))
    with pytest.raises(AssertionError, match="too weak to see a 5 % bias"):
        assert_unbiased(scene, expected, {**MINE, "max_depth": 2}, spp=64)


def test_max_spp_grows_the_sample_count():
    """With max_spp a noisy first attempt is repeated with 4x the samples (fresh seeds)."""
    scene, expected = polygon_light_plane(at=(0.7, 0.3, 0.0))
    r = assert_unbiased(scene, expected, {**MINE, "max_depth": 2}, spp=PLANE_SPP // 16,
                        max_spp=PLANE_SPP)
    assert r.spp > PLANE_SPP // 16


def test_exact_image_inside_the_box():
    """A camera inside the closed box: every pixel is exactly 2 (an exact expected image)."""
    scene, _ = closed_box(rho=0.5, le=1.0)
    scene["sensor"] = {"type": "perspective", "fov": 80,
                       "to_world": mi.ScalarTransform4f().look_at([0, 0, -0.5], [0.3, 0.2, 1],
                                                                  [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8,
                                "rfilter": {"type": "box"}}}
    assert_unbiased(scene, np.full((8, 8, 3), 1.875), {**MINE, "max_depth": 4},
                    spp=16, batches=8)
    with pytest.raises(AssertionError, match="rejected at alpha"):
        assert_unbiased(scene, np.full((8, 8, 3), 1.875 * 1.05), {**MINE, "max_depth": 4},
                        spp=16, batches=8)


# ---------------------------------------------------------------------------------------------
# against a reference integrator
def _plane_camera(res=8):
    """The plane under its two lights seen by an 8x8 camera; the lights' own surfaces are
    black, so light bounces only once (plane) and any depth >= 2 gives direct light."""
    scene, _ = polygon_light_plane()
    del scene["sensor0"]
    for key in ("rect0", "rect1"):
        scene[key]["bsdf"] = {"type": "diffuse", "reflectance": 0.0}
    scene["camera"] = {"type": "perspective", "fov": 40,
                       "to_world": mi.ScalarTransform4f().look_at([0.3, -0.4, 1.6],
                                                                  [0.2, 0.3, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": res, "height": res,
                                "rfilter": {"type": "box"}}}
    return scene


def test_same_image_as_mitsuba_path():
    """H0 "same expected image" as Mitsuba's ``path`` at the same max_depth (direct light),
    4x4-pixel blocks, median relative s.e. of a block about 0.33 %."""
    r = assert_unbiased(_plane_camera(), {"type": "path", "max_depth": 2},
                        {**MINE, "max_depth": 2}, spp=16384, batches=16)
    assert r.rel_se <= 0.005


def test_reference_by_name_and_biased_variant():
    """A reference given by name ("path": unlimited depth, which is direct light here), the
    whole 8x8 image as one block; the variant 5 % too bright is rejected."""
    scene = _plane_camera()
    budget = {"spp": 4096, "batches": 16, "block": 8}
    assert_unbiased(scene, "path", {**MINE, "max_depth": 2}, **budget)
    with pytest.raises(AssertionError, match="rejected at alpha"):
        assert_unbiased(scene, "path", {**MINE, "max_depth": 2, "weight": 1.05}, **budget)


# ---------------------------------------------------------------------------------------------
# chi-square
def test_bsdf_sampling_chi2():
    """H0: a BSDF's sample() draws directions with density pdf(): all lobes of
    roughconductor, and plastic's diffuse lobe alone (its other lobe is a delta)."""
    r = assert_bsdf_sampling({"type": "roughconductor", "alpha": 0.3}, wi=45, **CHI2)
    assert r.passed
    assert_bsdf_sampling({"type": "plastic"}, wi=30, component=1, **CHI2)


def test_wrong_pdf_is_rejected():
    """A user's cosine-weighted sampler: right against its own pdf, rejected against the
    uniform hemisphere pdf."""
    def sample(u):
        return mi.warp.square_to_cosine_hemisphere(mi.Point2f(u[0], u[1]))

    def cosine_pdf(wo):
        return dr.maximum(wo.z, 0.0) * dr.inv_pi

    def uniform_pdf(wo):
        return dr.select(wo.z > 0, dr.inv_two_pi, 0.0)

    assert chi2_test(sample, cosine_pdf, sample_dim=2, **CHI2).passed
    with pytest.raises(AssertionError, match="rejected at alpha"):
        assert_sampling(sample, uniform_pdf, sample_dim=2, **CHI2)


def test_checks_are_counted():
    before = CHECKS["count"]
    scene, expected = closed_box(rho=0.5, le=1.0, max_depth=1)
    assert_unbiased(scene, expected, {**MINE, "max_depth": 1}, spp=16, batches=4)
    assert CHECKS["count"] == before + 1
