"""mis3 with every path continuing: unbiased for any technique probabilities, through glass,
mirrors and null boundaries; delta lobes skip the technique choice.

* Closed emitting box (H0: L = le sum rho^k, Student t on batch means, Sidak over RGB, the kit's
  alpha 1.5e-5, relative s.e. < 0.5 %): random p-vectors from a fixed seed, the edges
  p_light = 1 (the continuation is then the BSDF's own sample) and p_light = 0, at unlimited
  depth and truncated at max_depth 3.  The truncated case would read le (1 + rho) if a light
  sample ended the path (the old mis3 with p_light = 1): it checks that every path continues.
* ``scenes/specular_box.xml`` (glass sphere inside a null box, a mirror sphere, a phong box):
  H0 the same expected image as Mitsuba's ``path`` (Welch t per 8x8 block, Sidak over blocks).
* A perfect mirror in a white furnace: every single sample is exactly the environment's
  radiance (zero variance): the delta lobe is not divided by a technique probability.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.testing import assert_unbiased
from integrators.testing.closed_forms import closed_box_radiance
from integrators.testing.scenes import closed_box_scene

RNG = np.random.default_rng(20261201)
RANDOM_P = [tuple(float(x) for x in RNG.dirichlet((1, 1, 1))) for _ in range(3)]
P_VECTORS = RANDOM_P + [(0.0, 0.0, 1.0), (0.5, 0.5, 0.0)]
CLOSED = {"spp": 4096, "max_spp": 64 * 4096}


@pytest.mark.parametrize("p", P_VECTORS, ids=lambda p: "p=%.2f,%.2f,%.2f" % p)
@pytest.mark.parametrize("max_depth", [-1, 3])
def test_closed_box_random_p_vectors(p, max_depth):
    expected = closed_box_radiance(1.0, 0.5, max_depth)
    assert_unbiased(closed_box_scene(0.5, 1.0),
                    expected, {"type": "mis3", "p_cosine": p[0], "p_glossy": p[1],
                               "p_light": p[2], "max_depth": max_depth}, **CLOSED)


@pytest.mark.parametrize("integ", [{"type": "mis3", "selection": "fixed"},
                                   {"type": "mis3", "selection": "adaptive"},
                                   {"type": "mis3", "selection": "adaptive",
                                    "light_selection": "adaptive", "heuristic": "power"}],
                         ids=["fixed", "adaptive", "adaptive-power"])
def test_specular_box_same_image_as_path(specular_box, specular_box_path, integ):
    # 8x8-pixel blocks: caustics make single pixels heavy-tailed; a block's relative s.e.
    # stays below 1 %, so a 5 % bias still gives |t| >= 5
    assert_unbiased(specular_box, specular_box_path, {**integ, "max_depth": 6}, spp=1024,
                    batches=16, block=8, max_rel_se=0.01)


@pytest.mark.parametrize("selection", ["fixed", "adaptive"])
def test_mirror_furnace_has_zero_variance(selection):
    """Every sample of a perfect mirror (Mitsuba's ``conductor``, reflectance 1) in a white
    furnace is exactly 1: no technique probability multiplies the delta lobe."""
    target, origin = (0.0, 0.0, 1.0), (0.5, 0.3, 3.0)
    scene = mi.load_dict({"type": "scene", "env": {"type": "constant", "radiance": 1.0},
                          "ball": {"type": "sphere", "bsdf": {"type": "conductor"}},
                          "sensor": testing.radiancemeter(target, origin, 16)})
    v = testing.sample_values(scene, mi.load_dict({"type": "mis3", "selection": selection}),
                              target, origin, n=4096)
    assert np.allclose(v, 1.0, rtol=1e-5), (v.min(), v.max())


# ---- property: the weights of the techniques that can produce a direction sum to one --------
from hypothesis import given, settings, strategies as st  # noqa: E402

import drjit as dr  # noqa: E402

from integrators.plugins.mis3 import MIS3  # noqa: E402
from integrators.sampling import mis  # noqa: E402

BSDFS = {
    "phong": {"type": "phong", "diffuse_reflectance": 0.4, "specular_reflectance": 0.5,
              "exponent": 30.0},
    "plastic": {"type": "roughplastic", "alpha": 0.2},
    "conductor": {"type": "roughconductor", "alpha": 0.3},
    "diffuse": {"type": "diffuse"},
}


_bsdf_cache = {}


def _bsdf(name):
    if name not in _bsdf_cache:
        _bsdf_cache[name] = mi.load_dict(BSDFS[name])
    return _bsdf_cache[name]


def _np(x, n):
    return np.broadcast_to(np.array(x, dtype=np.float64).reshape(-1), (n,))


@settings(max_examples=30, deadline=None)
@given(name=st.sampled_from(sorted(BSDFS)), heuristic=st.sampled_from(mis.HEURISTICS),
       # 0 or a normal float32 (denormal densities are flushed to zero by the JIT)
       p=st.tuples(*[st.one_of(st.just(0.0), st.floats(1e-6, 1.0))] * 3).filter(
           lambda t: sum(t) > 1e-3),
       seed=st.integers(0, 2 ** 31 - 1))
def test_weights_sum_to_one_for_random_directions(name, heuristic, p, seed):
    """For random directions on a real BSDF, random technique probabilities and a random light
    density, the emission weights over (q_3, q_1, q_2) = (p(3) p_l, pi_1 p_1, pi_2 p_2) sum to
    one wherever some technique can produce the direction (zero elsewhere), and the
    continuation's weights over (q_1, q_2) sum to one wherever a lobe can: what makes the
    estimator unbiased for any probabilities.  H0 exact up to float32 rounding (1e-4)."""
    rng = np.random.default_rng(seed)
    n = 256
    bsdf = _bsdf(name)
    si = mi.SurfaceInteraction3f()
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    si.wi = mi.Vector3f(0.3, -0.2, 0.93)
    v = rng.normal(size=(3, n))
    v /= np.linalg.norm(v, axis=0)
    wo = mi.Vector3f(v[0], v[1], v[2])
    total = sum(p)
    p1, p2, p3 = (x / total for x in p)
    pi1 = p1 / (p1 + p2) if p1 + p2 > 0 else 0.5
    # probabilities as opaque values: one kernel for every example, not one per value
    q_d, q_g = MIS3.lobe_q(bsdf, si, wo, dr.opaque(mi.Float, pi1), mi.Bool(True), True, True)
    q3 = mi.Float(p3 * rng.exponential(1.0, n) * (rng.uniform(size=n) < 0.8))
    heur = mis.Heuristic(heuristic)
    w = [_np(x, n) for x in heur.weights([q3, q_d, q_g])]
    qs = np.array([_np(q3, n), _np(q_d, n), _np(q_g, n)])
    assert np.isfinite(qs).all()
    any_q = qs.sum(axis=0) > 0
    s = sum(w)
    assert np.allclose(s[any_q], 1.0, atol=1e-4), (heuristic, s[any_q].min(), s[any_q].max())
    assert np.all(s[~any_q] == 0)
    w2 = [_np(x, n) for x in heur.weights([q_d, q_g])]
    lobe = qs[1:].sum(axis=0) > 0
    assert np.allclose(sum(w2)[lobe], 1.0, atol=1e-4)
