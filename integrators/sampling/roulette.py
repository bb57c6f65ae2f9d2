r"""Russian roulette and splitting: ending or multiplying paths without bias.

* **Russian roulette** after a vertex: the path survives with probability q and its throughput is
  divided by q, so E[beta'] = beta.  ``rr`` = ``none`` | ``fixed`` (q = 1 - ``rr_prob``) |
  ``throughput`` (q = min(max(beta) eta^2, 0.95), Mitsuba's ``path`` and pbrt), from path depth
  ``rr_depth`` on.
* **Splitting** into k continuations, each weighted :func:`split_weight` = 1/k: their average is
  an unbiased estimate of one continuation.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import lnot
from ..params import MAX_DEPTH_VALUE, Param

RR_DEPTH = Param("rr_depth", "int", 5, min=1, max=MAX_DEPTH_VALUE,
                 doc="Path depth at which Russian roulette starts.")

RR_MODES = ("none", "fixed", "throughput")

RR_PARAMS = (
    RR_DEPTH,
    Param("rr", "choice", "throughput", choices=RR_MODES,
          doc="Russian roulette: none, fixed termination probability, or from the throughput."),
    Param("rr_prob", "float", 0.5, min=0.0, max=0.99,
          doc="Termination probability of rr=fixed."),
)


def throughput_survival(beta, eta):
    """The throughput rule's survival probability, min(max(beta) eta^2, 0.95)."""
    beta_max = dr.max(mi.unpolarized_spectrum(beta), axis=0)
    q = dr.minimum(beta_max * dr.square(eta), 0.95)
    return q


def roulette(mode: str, rr_depth: int, rr_prob: float, beta, eta, depth, u, active):
    """Russian roulette of the given mode; returns (beta, active).  Unbiased: survivors are
    divided by their survival probability."""
    beta_max = dr.max(mi.unpolarized_spectrum(beta), axis=0)
    active = active & (beta_max != 0)
    if mode == "none":
        return beta, active
    if mode == "fixed":
        q = mi.Float(1.0 - rr_prob)
    else:
        q = throughput_survival(beta, eta)
    rr_active = depth >= rr_depth
    beta = dr.select(rr_active, beta * dr.rcp(dr.select(q > 0, q, 1.0)), beta)
    return beta, active & (lnot(rr_active) | (u < q))


class Roulette:
    """A path's Russian roulette: ``Roulette(mode, rr_depth, rr_prob)(beta, eta, depth, u,
    active)`` -> (beta, active)."""

    def __init__(self, mode: str = "throughput", rr_depth: int = 5, rr_prob: float = 0.5):
        if mode not in RR_MODES:
            raise ValueError(f"rr = {mode!r}; allowed: one of {', '.join(RR_MODES)}")
        self.mode, self.rr_depth, self.rr_prob = mode, int(rr_depth), float(rr_prob)

    @classmethod
    def from_params(cls, p: dict) -> "Roulette":
        return cls(p.get("rr", "throughput"), p.get("rr_depth", 5), p.get("rr_prob", 0.5))

    def __call__(self, beta, eta, depth, u, active):
        return roulette(self.mode, self.rr_depth, self.rr_prob, beta, eta, depth, u, active)


def split_weight(k: int) -> float:
    """Weight of each of the k continuations of a split: their average is unbiased."""
    return 1.0 / k
