"""bsdf_path against closed forms: the furnace and the closed emitting sphere.

H0 per check: the estimator is unbiased (batch means have the closed-form mean); Student t on
32 batch means, Sidak over RGB, alpha = 1e-4 (integrators.testing).  Each check also asserts a
relative standard error below 0.5 %.  Negative control: Russian roulette without its 1/q
compensation must be rejected.
"""
from __future__ import annotations

import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.plugins.bsdf_path import HEMISPHERE
from integrators.testing import assert_unbiased, check_unbiased
from integrators.testing.scenes import closed_sphere_scene, furnace_scene

# assert_unbiased: 32 batches of 4096 spp, alpha DEFAULT_ALPHA, relative s.e. < 0.5 %


@pytest.mark.parametrize("hemisphere", HEMISPHERE)
def test_furnace_diffuse_sphere(hemisphere):
    """Convex diffuse sphere (albedo 0.6) in a constant environment of 1: L = 0.6."""
    assert_unbiased(furnace_scene({"type": "diffuse", "reflectance": 0.6}), 0.6,
                    {"type": "bsdf_path", "hemisphere": hemisphere})


@pytest.mark.parametrize("hemisphere", HEMISPHERE)
def test_furnace_phong_sphere_white(hemisphere):
    """phong without its glossy lobe is Lambertian: L = rho_d = 0.8."""
    assert_unbiased(furnace_scene({"type": "phong", "diffuse_reflectance": 0.8,
                                   "specular_reflectance": 0.0}), 0.8,
                    {"type": "bsdf_path", "hemisphere": hemisphere})


@pytest.mark.parametrize("hemisphere", HEMISPHERE)
@pytest.mark.parametrize("max_depth", [-1, 1, 2, 5])
def test_closed_sphere_geometric_series(hemisphere, max_depth):
    """Inside a closed sphere of albedo 0.5 emitting 1: L = sum_{k<max_depth} 0.5^k."""
    rho, le = 0.5, 1.0
    assert_unbiased(closed_sphere_scene(rho, le),
                    testing.closed_sphere_radiance(le, rho, max_depth),
                    {"type": "bsdf_path", "hemisphere": hemisphere, "max_depth": max_depth,
                     "rr_depth": 2})


def test_negative_control_rr_without_compensation(monkeypatch):
    from integrators.sampling import roulette
    orig = roulette.roulette

    def biased(mode, rr_depth, rr_prob, beta, eta, depth, u, active):
        _, active2 = orig(mode, rr_depth, rr_prob, beta, eta, depth, u, active)
        return beta, active2  # survivors not divided by their survival probability

    monkeypatch.setattr(roulette, "roulette", biased)
    r = check_unbiased(closed_sphere_scene(0.5, 1.0), 2.0, {"type": "bsdf_path", "rr_depth": 1})
    assert not r.passed, r
