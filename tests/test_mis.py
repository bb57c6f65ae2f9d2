"""MIS heuristics: the two unbiasedness conditions of the lecture, checked exhaustively on
random densities (deterministic property tests, no significance level):
  (a) f(x) != 0  =>  sum_i w_i(x) = 1     (every x that some technique can produce)
  (b) p_j(x) = 0 =>  w_j(x) = 0
plus the defining formulas of each heuristic."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.sampling.mis import HEURISTICS, Heuristic


def random_q(rng, n_tech, n=20000):
    """Random densities over several decades, with exact zeros and ties sprinkled in."""
    q = 10.0 ** rng.uniform(-6, 6, size=(n_tech, n))
    q[rng.random((n_tech, n)) < 0.25] = 0.0
    tie = rng.random(n) < 0.05
    q[1, tie] = q[0, tie]
    return q.astype(np.float32)


@pytest.mark.parametrize("name", HEURISTICS)
@pytest.mark.parametrize("n_tech", [2, 3])
def test_weights_sum_to_one_and_vanish_with_pdf(name, n_tech):
    rng = np.random.default_rng(1234 + n_tech)
    q = random_q(rng, n_tech)
    w = np.array([np.array(x) for x in Heuristic(name).weights([mi.Float(r) for r in q])])
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    some = q.max(0) > 0
    assert np.allclose(w[:, some].sum(0), 1.0, atol=1e-5)           # (a)
    assert np.all(w[q == 0] == 0)                                     # (b)
    assert np.all(w[:, ~some] == 0)                                   # nothing can produce x


def test_formulas():
    q = [mi.Float([1.0, 3.0, 0.0, 5.0]), mi.Float([3.0, 1.0, 2.0, 5.0])]
    bal = np.array(Heuristic("balance").weight(0, q))
    assert np.allclose(bal, [0.25, 0.75, 0.0, 0.5])
    pw = np.array(Heuristic("power", beta=2).weight(0, q))
    assert np.allclose(pw, [0.1, 0.9, 0.0, 0.5])
    pw3 = np.array(Heuristic("power", beta=3).weight(0, q))
    assert np.allclose(pw3, [1 / 28, 27 / 28, 0.0, 0.5])
    cut = np.array(Heuristic("cutoff", alpha=0.5).weight(0, q))
    assert np.allclose(cut, [0.0, 1.0, 0.0, 0.5])
    mx = np.array(Heuristic("maximum").weight(0, q))
    assert np.allclose(mx, [0.0, 1.0, 0.0, 0.5])                     # ties share
    avg = np.array(Heuristic("average").weight(0, q))
    assert np.allclose(avg, [0.5, 0.5, 0.0, 0.5])
    part = np.array(Heuristic("partition").weight(0, q))             # first non-zero wins
    assert np.allclose(part, [1.0, 1.0, 0.0, 1.0])


def test_no_overflow_for_steep_pdfs():
    q = [mi.Float([1e30, 3e-30]), mi.Float([3e30, 1e-30])]
    for name in HEURISTICS:
        w = np.array([np.array(x) for x in Heuristic(name).weights(q)])
        assert np.all(np.isfinite(w)) and np.allclose(w.sum(0), 1.0, atol=1e-6), name


def test_infinite_density_wins():
    q = [mi.Float([np.inf]), mi.Float([5.0])]
    for name in HEURISTICS:
        w = [float(np.array(x)[0]) for x in Heuristic(name).weights(q)]
        assert w == [1.0, 0.0], name


def test_scalar_variant_same_weights():
    q = [[1.0, 3.0, 0.0], [3.0, 1.0, 2.0], [0.5, 0.0, 0.0]]
    ref = {n: [np.array(x) for x in Heuristic(n).weights([mi.Float(r) for r in q])]
           for n in HEURISTICS}
    integrators.set_variant("scalar_rgb")
    try:
        for n in HEURISTICS:
            for lane in range(3):
                w = Heuristic(n).weights([r[lane] for r in q])
                assert np.allclose([float(x) for x in w], [r[lane] for r in ref[n]]), n
    finally:
        integrators.set_variant("llvm_ad_rgb")


# ---- property test over the parameter space (hypothesis: fixed seed, bounded examples) ----
from hypothesis import given, settings, strategies as st  # noqa: E402

_density = st.one_of(st.just(0.0), st.floats(1e-30, 1e30, allow_nan=False))


@settings(max_examples=150, deadline=None, derandomize=True)
@given(name=st.sampled_from(HEURISTICS), beta=st.floats(0.05, 10.0), alpha=st.floats(0.0, 1.0),
       q=st.lists(st.lists(_density, min_size=2, max_size=4), min_size=1, max_size=8))
def test_weights_sum_to_one_for_any_parameters(name, beta, alpha, q):
    """(a) and (b) for every heuristic at any beta > 0 and alpha in [0, 1], edges included."""
    n_tech = len(q[0])
    q = np.array([row[:n_tech] + [0.0] * (n_tech - len(row)) for row in q], dtype=np.float32).T
    w = np.array([np.array(x) for x in
                  Heuristic(name, beta=beta, alpha=alpha).weights([mi.Float(r) for r in q])])
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    some = q.max(0) > 0
    assert np.allclose(w[:, some].sum(0), 1.0, atol=1e-5)
    assert np.all(w[q == 0] == 0)
