"""Every numeric integrator parameter at the edges of its range, unbiased on a closed form.

For each integrator and each numeric parameter (``python -m integrators list``), the minimum and
the maximum of its range (a sane maximum for unbounded counts: 16 samples or continuations, and
for the exponent beta of the power heuristic 0.05 and 50; the typical value, the default, is what
the other test files render) are rendered alone, everything else at its default:

* path integrators in the closed emitting box (albedo 0.5, emission 1): L = sum_{k<D} 0.5^k
  (2 at unlimited depth; ``max_depth`` 0 renders nothing, as Mitsuba's ``path``: L = 0);
* ``direct_mis`` and light-only settings on Lambert's formula (a diffuse plane under two
  rectangle lights, direct light only);
* ``mis3`` with only its glossy technique on a mirror sphere in a constant environment (L = 1).

H0 per check: the estimator is unbiased (Student t on 32 batch means, Sidak over RGB, the kit's
DEFAULT_ALPHA, relative s.e. < 0.5 %, the sample count grown 4x while noisier).  A property
test (hypothesis, fixed seed, 3 examples each) draws whole parameter vectors of ``nee_path`` and
``mis3`` from their ranges, edges included, and checks each the same way.

Mutants (tests/mutation.py): cutoff-alpha-1-drops-all (the cutoff keeps nothing at alpha 1),
power-heuristic-unnormalised (densities raised to beta before normalising: overflow at beta 50).
Fast set about 30 s; the other single edges are marked slow.
"""
from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import integrators  # noqa: F401
from integrators.params import MAX_DEPTH_VALUE
from integrators.testing import (assert_unbiased, closed_box, mirror_furnace,
                                 polygon_light_plane)

BIG = 16                 # sane maximum of unbounded sample counts
CLOSED = {"spp": 2048, "max_spp": 64 * 2048}


def box(max_depth=-1):
    return closed_box(rho=0.5, le=1.0, max_depth=max_depth, spp=2048)


def lambert():
    return polygon_light_plane(spp=2048)


# (integrator, parameters, closed form): one parameter at an edge of its range each
EDGES = [
    # max_depth: 0 (nothing, Mitsuba's meaning), 1 (emission seen directly), the largest value
    *[(t, {"max_depth": d}, lambda d=d: box(0 if d == 0 else d if d == 1 else -1))
      for t in ("bsdf_path", "nee_path", "mis3") for d in (0, 1, MAX_DEPTH_VALUE)],
    # rr_depth: roulette from the first vertex, and never (paths cut at max_depth 40)
    *[(t, {"rr_depth": r, **({"max_depth": 40} if r > 1 else {})},
       lambda r=r: box(40 if r > 1 else -1))
      for t in ("bsdf_path", "nee_path", "mis3") for r in (1, MAX_DEPTH_VALUE)],
    # rr_prob: never terminate (q = 1); terminate 99 % (survivors x 100: one roulette vertex,
    # at depth 3 of 4, keeps the variance affordable)
    *[(t, {"rr": "fixed", "rr_prob": 0.0, "rr_depth": 1, "max_depth": 40}, lambda: box(40))
      for t in ("nee_path", "mis3")],
    *[(t, {"rr": "fixed", "rr_prob": 0.99, "rr_depth": 3, "max_depth": 4}, lambda: box(4))
      for t in ("nee_path", "mis3")],
    # the power heuristic's exponent: near 0 (weights near 1/n) and large (near maximum)
    *[(t, {"heuristic": "power", "beta": b}, box) for t in ("nee_path", "mis3")
      for b in (0.05, 50.0)],
    *[("direct_mis", {"heuristic": "power", "beta": b}, lambert) for b in (0.05, 50.0)],
    # the cutoff heuristic's alpha: 0 (balance) and 1 (only the densest technique)
    *[(t, {"heuristic": "cutoff", "alpha": a}, box) for t in ("nee_path", "mis3")
      for a in (0.0, 1.0)],
    *[("direct_mis", {"heuristic": "cutoff", "alpha": a}, lambert) for a in (0.0, 1.0)],
    # sample counts: none and many
    ("nee_path", {"light_samples": 0}, box),
    ("nee_path", {"light_samples": BIG}, box),
    ("nee_path", {"split": BIG}, box),
    ("direct_mis", {"light_samples": 0, "bsdf_samples": 1}, lambert),
    ("direct_mis", {"light_samples": 1, "bsdf_samples": 0}, lambert),
    ("direct_mis", {"light_samples": BIG, "bsdf_samples": 1}, lambert),
    ("direct_mis", {"light_samples": 1, "bsdf_samples": BIG}, lambert),
    # mis3's technique probabilities at 0 and 1
    ("mis3", {"p_cosine": 1.0, "p_glossy": 0.0, "p_light": 0.0}, box),
    ("mis3", {"p_cosine": 0.0, "p_glossy": 0.0, "p_light": 1.0}, box),
    ("mis3", {"p_cosine": 0.0, "p_glossy": 1.0, "p_light": 0.0}, box),
    ("mis3", {"p_cosine": 0.0, "p_glossy": 0.5, "p_light": 0.5}, box),
    ("mis3", {"p_cosine": 0.0, "p_glossy": 0.0, "p_light": 1.0, "max_depth": 2}, lambert),
    ("mis3", {"p_cosine": 0.0, "p_glossy": 1.0, "p_light": 0.0}, mirror_furnace),
]


def _id(e):
    t, p, case = e
    where = {lambert: "@lambert", mirror_furnace: "@mirror"}.get(case, "")
    return t + "-" + "-".join(f"{k}={v}" for k, v in p.items()) + where


# the fast set (the rest is marked slow): every integrator's max_depth 0, the extreme roulette,
# heuristic and count settings of nee_path, the cutoff at alpha 1 everywhere, the sample counts
# of direct_mis at 0, and mis3's technique probabilities at their corners
FAST = {"bsdf_path-max_depth=0", "nee_path-max_depth=0", "mis3-max_depth=0",
        f"nee_path-max_depth={MAX_DEPTH_VALUE}",
        f"bsdf_path-rr_depth={MAX_DEPTH_VALUE}-max_depth=40",
        "nee_path-rr=fixed-rr_prob=0.0-rr_depth=1-max_depth=40",
        "nee_path-rr=fixed-rr_prob=0.99-rr_depth=3-max_depth=4",
        "nee_path-heuristic=power-beta=0.05", "nee_path-heuristic=power-beta=50.0",
        "direct_mis-heuristic=power-beta=50.0@lambert",
        "nee_path-heuristic=cutoff-alpha=1.0", "mis3-heuristic=cutoff-alpha=1.0",
        "direct_mis-heuristic=cutoff-alpha=1.0@lambert",
        "nee_path-light_samples=0", "nee_path-light_samples=16", "nee_path-split=16",
        "direct_mis-light_samples=0-bsdf_samples=1@lambert",
        "direct_mis-light_samples=1-bsdf_samples=0@lambert",
        "mis3-p_cosine=1.0-p_glossy=0.0-p_light=0.0",
        "mis3-p_cosine=0.0-p_glossy=0.0-p_light=1.0",
        "mis3-p_cosine=0.0-p_glossy=1.0-p_light=0.0",
        "mis3-p_cosine=0.0-p_glossy=1.0-p_light=0.0@mirror"}
PARAMS = [pytest.param(*e, id=_id(e), marks=() if _id(e) in FAST else (pytest.mark.slow,))
          for e in EDGES]
assert FAST <= {_id(e) for e in EDGES}


@pytest.mark.parametrize("integrator,params,case", PARAMS)
def test_parameter_edge_unbiased(integrator, params, case):
    scene, expected = case()
    integ = {"type": integrator, **params}
    if isinstance(expected, list):      # the Lambert plane: one sensor
        expected = expected[0]
    assert_unbiased(scene, expected, integ, **CLOSED)


# ---- property test: whole parameter vectors drawn from the ranges ----------------------------
HEURISTICS = ("balance", "power", "cutoff", "maximum", "average", "partition")
edge_float = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0))
common = dict(
    heuristic=st.sampled_from(HEURISTICS),
    beta=st.one_of(st.sampled_from([0.05, 1.0, 50.0]), st.floats(0.05, 50.0)),
    alpha=edge_float,
    light_selection=st.sampled_from(["uniform", "power", "adaptive"]),
    rr=st.sampled_from(["none", "fixed", "throughput"]),
    rr_prob=st.one_of(st.sampled_from([0.0, 0.9]), st.floats(0.0, 0.9)),
    rr_depth=st.sampled_from([1, 2, 5]),
)


EXAMPLES = 3


def _rr_safe(p):
    """Without roulette a path in the closed box never ends: cut it (closed form truncated)."""
    return 30 if p["rr"] == "none" else -1


@settings(derandomize=True, max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(p=st.fixed_dictionaries({**common, "light_samples": st.sampled_from([0, 1, 2, 4]),
                                "split": st.sampled_from([1, 2])}))
def test_nee_path_parameter_space(p):
    d = _rr_safe(p)
    scene, expected = box(d)
    assert_unbiased(scene, expected, {"type": "nee_path", "max_depth": d, **p}, **CLOSED)


@settings(derandomize=True, max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(p=st.fixed_dictionaries({**common, "p_cosine": edge_float, "p_glossy": edge_float,
                                "p_light": edge_float,
                                "selection": st.sampled_from(["fixed", "adaptive"])}))
def test_mis3_parameter_space(p):
    if p["p_cosine"] + p["p_glossy"] + p["p_light"] == 0:
        p["p_cosine"] = 1.0            # refused: at least one technique
    d = _rr_safe(p)
    scene, expected = box(d)
    assert_unbiased(scene, expected, {"type": "mis3", "max_depth": d, **p}, **CLOSED)
