"""White furnaces: lossless, transmitting and back-facing surfaces in a constant environment,
for every integrator, every ``hemisphere`` mode of ``bsdf_path``, every roulette mode.

Closed forms (radiancemeter at an oblique angle, cos 0.36, on a unit sphere in an environment of
radiance 1; :mod:`integrators.testing.scenes`):

* a smooth ``dielectric`` sphere (eta 1.5) and a ``thindielectric`` sphere: lossless, so L = 1
  at unlimited depth; at ``max_depth`` D, L = r + (1-r)^2 sum_{k<D-2} r^k with r the (thin)
  Fresnel reflectance (every chord of a sphere meets it at the same angle);
* a perfect mirror sphere (``conductor``, ``material`` none): L = 1 from D = 2 on;
* the back side of a ``twosided`` BSDF (front albedo 0.2, back 0.7) on a sphere with inward
  normals seen from outside: L = 0.7 from D = 2 on (convex); a one-sided diffuse: L = 0.

Roulette starts at depth 1 (``rr_depth`` 1), so every vertex of every path goes through it.
H0 per check: the estimator is unbiased (Student t on 32 batch means, Sidak over RGB, the kit's
DEFAULT_ALPHA; relative s.e. < 0.5 %, the sample count grown 4x while noisier).

Where energy is lost (``roughdielectric``, ``roughconductor``: single-scattering microfacet
models) there is no closed form: H0 "the same expected image as Mitsuba's ``path`` at the same
``max_depth``" (Welch t on the batch means of both), on a rough dielectric plane seen from the
outside and from the inside (the ``uniform`` and ``cosine`` modes then sample the whole sphere
of directions) and on rough spheres.

Throughput roulette through glass (not statistical): q = min(max(beta) eta^2, 0.95) is 0.95 at
every vertex of a lossless dielectric path, so every sample is 0 or 0.95^-m.

Negative controls / mutants (``tests/mutation.py``): hemisphere-back-side-ignored,
hemisphere-never-transmits, hemisphere-sphere-pdf-not-halved, hemisphere-delta-eta-dropped,
rr-eta-dropped, rr-compensation-without-eta, rr-throughput-not-clamped,
path-eta-not-accumulated.  Fast set about 30 s; the whole cross of integrators and closed
forms, and uniform / cosine sampling of rough glass, are marked slow.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.testing import (assert_unbiased, back_face_furnace, dielectric_furnace,
                                 mirror_furnace, radiancemeter, sample_values)
from integrators.testing.scenes import FURNACE_VIEW, OBLIQUE_VIEW, furnace_scene

# every path integrator, with Russian roulette from the first vertex
INTEGRATORS = {
    "bsdf_path-uniform": {"type": "bsdf_path", "hemisphere": "uniform", "rr_depth": 1},
    "bsdf_path-cosine": {"type": "bsdf_path", "hemisphere": "cosine", "rr_depth": 1},
    "bsdf_path-bsdf": {"type": "bsdf_path", "hemisphere": "bsdf", "rr_depth": 1},
    "nee_path-none": {"type": "nee_path", "rr": "none"},
    "nee_path-fixed": {"type": "nee_path", "rr": "fixed", "rr_prob": 0.3, "rr_depth": 1},
    "nee_path-throughput": {"type": "nee_path", "rr": "throughput", "rr_depth": 1},
    "mis3-fixed": {"type": "mis3", "selection": "fixed", "rr_depth": 1},
    "mis3-adaptive": {"type": "mis3", "selection": "adaptive", "rr_depth": 1},
}

# (case, closed form builder): each truncation where it differs from the whole series
CASES = {
    "glass-d2": lambda spp: dielectric_furnace(max_depth=2, spp=spp),
    "glass-d3": lambda spp: dielectric_furnace(max_depth=3, spp=spp),
    "glass-inf": lambda spp: dielectric_furnace(max_depth=-1, spp=spp),
    "thin-d3": lambda spp: dielectric_furnace(max_depth=3, thin=True, spp=spp),
    "thin-inf": lambda spp: dielectric_furnace(max_depth=-1, thin=True, spp=spp),
    "mirror-inf": lambda spp: mirror_furnace(max_depth=-1, spp=spp),
    "twosided-back-d2": lambda spp: back_face_furnace(max_depth=2, spp=spp),
    "onesided-back-inf": lambda spp: back_face_furnace(twosided=False, spp=spp),
}
DEPTH = {"d2": 2, "d3": 3, "inf": -1}
# 32 batches of 2048 spp, 4x more (fresh seeds) while the relative s.e. is above 0.5 %
SPP, MAX_SPP = 2048, 16 * 2048


def _depth(case):
    return DEPTH[case.rsplit("-", 1)[1]]


# the fast set: every integrator through unlimited glass (roulette with eta) and on a back face,
# each hemisphere mode and roulette mode on a truncation; the whole cross is marked slow
FAST = ({(n, c) for n in INTEGRATORS for c in ("glass-inf", "twosided-back-d2")} |
        {("bsdf_path-uniform", "thin-d3"), ("bsdf_path-cosine", "thin-d3"),
         ("bsdf_path-bsdf", "glass-d3"), ("nee_path-fixed", "glass-d3"),
         ("nee_path-throughput", "thin-inf"), ("nee_path-none", "thin-d3"),
         ("mis3-fixed", "glass-d3"), ("mis3-adaptive", "thin-d3"),
         ("bsdf_path-uniform", "mirror-inf"), ("nee_path-none", "mirror-inf"),
         ("mis3-fixed", "mirror-inf"),
         ("bsdf_path-uniform", "onesided-back-inf"), ("bsdf_path-cosine", "onesided-back-inf"),
         ("nee_path-throughput", "onesided-back-inf"), ("mis3-adaptive", "onesided-back-inf")})


def cross(names, cases, fast):
    """pytest params over names x cases; those not in ``fast`` are marked slow."""
    return [pytest.param(n, c, id=f"{n}-{c}", marks=() if (n, c) in fast else (pytest.mark.slow,))
            for n in names for c in cases]


PAIRS = cross(INTEGRATORS, CASES, FAST)


@pytest.mark.parametrize("name,case", PAIRS)
def test_white_furnace_closed_form(name, case):
    scene, expected = CASES[case](SPP)
    integ = dict(INTEGRATORS[name], max_depth=_depth(case))
    assert_unbiased(scene, expected, integ, spp=SPP, max_spp=MAX_SPP)


DIRECT = {
    "glass": lambda spp: dielectric_furnace(max_depth=2, spp=spp),
    "thin": lambda spp: dielectric_furnace(max_depth=2, thin=True, spp=spp),
    "mirror": lambda spp: mirror_furnace(max_depth=2, spp=spp),
    "twosided-back": lambda spp: back_face_furnace(max_depth=2, spp=spp),
}


@pytest.mark.parametrize("heuristic,case", cross(
    ["balance", "power"], DIRECT, {("balance", "glass"), ("balance", "thin"), ("power", "mirror"),
                                   ("power", "twosided-back")}))
def test_direct_mis_white_furnace(heuristic, case):
    """``direct_mis`` is one bounce of light: the closed forms at max_depth 2 (glass: the
    Fresnel reflectance alone; thin glass likewise; mirror 1; the back face 0.7)."""
    scene, expected = DIRECT[case](SPP)
    assert_unbiased(scene, expected, {"type": "direct_mis", "heuristic": heuristic,
                                      "light_samples": 2, "bsdf_samples": 1},
                    spp=SPP, max_spp=MAX_SPP)


# ---- energy-losing or not exactly white surfaces: the same image as Mitsuba's path ------------
def plane(bsdf, below: bool, spp: int):
    """A large plane z = 0 with ``bsdf`` in an environment of 1, seen from above (the front,
    outside) or from below (the back: the inside of a dielectric)."""
    origin = (0.3, 0.2, -0.5) if below else (0.3, 0.2, 0.5)
    return {"type": "scene", "env": {"type": "constant", "radiance": 1.0},
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(50.0),
                      "bsdf": bsdf},
            "sensor": radiancemeter((0.0, 0.0, 0.0), origin, spp)}


#: a rough dielectric (glossy reflection and transmission; loses energy at this roughness)
ROUGH_GLASS = {"type": "roughdielectric", "alpha": 0.7, "int_ior": 1.5, "ext_ior": 1.0}
#: diffuse reflection (20 %) and diffuse transmission (80 %) (principledthin: albedo about 1,
#: not a closed form): the uniform and cosine modes sample the whole sphere here with little
#: variance
DIFFUSE_TRANSMITTER = {"type": "principledthin", "base_color": 1.0, "spec_trans": 0.0,
                       "diff_trans": 0.8, "roughness": 1.0}
SIDES = {"outside": False, "inside": True}


@pytest.mark.parametrize("name,side", cross(
    ["bsdf_path-uniform", "bsdf_path-cosine", "mis3-fixed", "mis3-adaptive",
     "nee_path-throughput"], SIDES,
    {("bsdf_path-uniform", "outside"), ("bsdf_path-uniform", "inside"),
     ("bsdf_path-cosine", "outside"), ("bsdf_path-cosine", "inside")}))
def test_diffuse_transmitter_plane_same_as_path(name, side):
    """One bounce (max_depth 2) off a plane that reflects and transmits diffusely, seen from
    either side: H0 the same expected radiance as Mitsuba's path."""
    assert_unbiased(plane(DIFFUSE_TRANSMITTER, SIDES[side], 4096),
                    {"type": "path", "max_depth": 2}, dict(INTEGRATORS[name], max_depth=2),
                    spp=4096)


@pytest.mark.parametrize("name,side", cross(
    ["bsdf_path-bsdf", "mis3-fixed", "mis3-adaptive", "nee_path-throughput"], SIDES,
    {("mis3-fixed", "inside"), ("nee_path-throughput", "inside"), ("mis3-adaptive", "outside")}))
def test_rough_dielectric_plane_same_as_path(name, side):
    """One bounce (max_depth 2) off a rough dielectric plane, seen from outside and from inside
    the glass: reflection and transmission (radiance scaled by eta^2 across the interface)."""
    assert_unbiased(plane(ROUGH_GLASS, SIDES[side], 4096), {"type": "path", "max_depth": 2},
                    dict(INTEGRATORS[name], max_depth=2), spp=4096)


# uniform / cosine sampling of a rough dielectric: per-sample relative s.d. 4-6 (measured over
# 2M samples), so 0.5 % relative s.e. takes about 1M samples per side
@pytest.mark.slow
@pytest.mark.parametrize("side", SIDES)
@pytest.mark.parametrize("name", ["bsdf_path-uniform", "bsdf_path-cosine"])
def test_rough_dielectric_plane_hemisphere_modes(name, side):
    assert_unbiased(plane(ROUGH_GLASS, SIDES[side], 65536), {"type": "path", "max_depth": 2},
                    dict(INTEGRATORS[name], max_depth=2), spp=65536)


ROUGH_SPHERES = {
    "roughglass": ({"type": "roughdielectric", "alpha": 0.3, "int_ior": 1.5}, False),
    "roughmirror": ({"type": "roughconductor", "material": "none", "alpha": 0.4}, False),
    "twosided-roughmirror-back": ({"type": "twosided",
                                   "front": {"type": "diffuse", "reflectance": 0.2},
                                   "back": {"type": "roughconductor", "material": "none",
                                            "alpha": 0.4}}, True),
}


@pytest.mark.parametrize("name,case", cross(
    ["bsdf_path-bsdf", "nee_path-throughput", "mis3-fixed", "mis3-adaptive"], ROUGH_SPHERES,
    {("mis3-adaptive", "roughglass"), ("nee_path-throughput", "roughglass"),
     ("mis3-fixed", "twosided-roughmirror-back"), ("bsdf_path-bsdf", "roughmirror")}))
def test_rough_sphere_same_as_path(name, case):
    """Rough glass at unlimited depth (paths inside refract and reflect many times), a rough
    mirror, and the back side of a two-sided rough mirror on a flipped sphere, against
    Mitsuba's path at the same max_depth."""
    bsdf, flip = ROUGH_SPHERES[case]
    depth = -1 if case == "roughglass" else 2
    scene = furnace_scene(bsdf, spp=4096, flip_normals=flip, view=OBLIQUE_VIEW)
    assert_unbiased(scene, {"type": "path", "max_depth": depth},
                    dict(INTEGRATORS[name], max_depth=depth), spp=4096)


# ---- throughput roulette through glass: q = 0.95 at every vertex ------------------------------
@pytest.mark.parametrize("name", ["bsdf_path-uniform", "bsdf_path-bsdf", "nee_path-throughput",
                                  "mis3-fixed", "mis3-adaptive"])
@pytest.mark.parametrize("eta", [1.5, 1 / 1.5])
def test_throughput_roulette_through_glass(name, eta):
    """In a lossless dielectric the radiance throughput times eta^2 stays 1 (the BSDF weight of
    a refraction is 1/eta^2, the eta of the sample undoes it), so the throughput roulette
    survives with q = min(max(beta) eta^2, 0.95) = 0.95 at every vertex from rr_depth on and
    every sample is 0 or 0.95^-m for a whole m >= 0 (a roulette that ignores eta, or divides by
    another q than it survives with, gives other values).  Both eta > 1 (glass) and eta < 1 (a
    bubble: the throughput grows entering it)."""
    view = OBLIQUE_VIEW if eta > 1 else FURNACE_VIEW    # no total reflection at the first hit
    scene, _ = dielectric_furnace(eta=eta, max_depth=-1, view=view)
    scene = mi.load_dict(scene)
    integ = mi.load_dict(dict(INTEGRATORS[name], max_depth=-1))
    v = sample_values(scene, integ, (0.0, 0.0, 1.0), np.add((0.0, 0.0, 1.0), view),
                      n=1 << 14, seed=3)[:, 0]
    nz = v[v != 0]
    assert nz.size > 0.5 * v.size
    m = np.log(nz) / -np.log(0.95)
    assert np.all(np.abs(m - np.round(m)) < 1e-3), np.unique(np.round(nz, 5))[:10]
    assert np.all(np.round(m) >= 0)
