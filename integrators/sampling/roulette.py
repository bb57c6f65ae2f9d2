"""Russian roulette (and the weight of splitting): ending or multiplying paths without bias."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import lnot
from ..params import Param

RR_DEPTH = Param("rr_depth", "int", 5, min=1,
                 doc="Path depth at which Russian roulette starts.")

RR_MODES = ("none", "fixed", "throughput")

RR_PARAMS = (
    RR_DEPTH,
    Param("rr", "choice", "throughput", choices=RR_MODES,
          doc="Russian roulette: none, fixed termination probability, or from the throughput."),
    Param("rr_prob", "float", 0.5, min=0.0, max=0.99,
          doc="Termination probability of rr=fixed."),
)


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
        q = dr.minimum(beta_max * dr.square(eta), 0.95)
    rr_active = depth >= rr_depth
    beta = dr.select(rr_active, beta * dr.rcp(dr.select(q > 0, q, 1.0)), beta)
    return beta, active & (lnot(rr_active) | (u < q))


def russian_roulette(beta, eta, depth, rr_depth, u, active):
    """Throughput-based Russian roulette (Mitsuba's ``path``, pbrt); returns (beta, active)."""
    return roulette("throughput", rr_depth, 0.0, beta, eta, depth, u, active)
