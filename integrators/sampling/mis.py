r"""Multiple importance sampling weights.

The lecture's multi-sample estimator (N techniques, N_i samples from p_i)

    F = \sum_i 1/N_i \sum_j w_i(X_ij) f(X_ij) / p_i(X_ij)

is unbiased whenever (a) the weights sum to one wherever f != 0 and (b) a technique whose pdf is
zero gets weight zero.  Every heuristic here is a function of the *effective densities*
q_k = N_k p_k(x) (multi-sample) or q_k = p(k) p_k(x) (one-sample), evaluated for the same point
x.  All of them satisfy (a) and (b) by construction: a technique with q_k = 0 has weight 0, and the
weights are normalised over the techniques with q_k > 0.  (When every q_k is zero no technique can
produce x and all weights are 0.)

Heuristics (``HEURISTICS``):

``balance``   w_i = q_i / sum_k q_k                      (Veach; the lecture's balance heuristic)
``power``     w_i = q_i^beta / sum_k q_k^beta             (Veach; beta = 2 is the usual choice)
``cutoff``    techniques with q_k < alpha max_k q_k are dropped, the rest balanced (Veach)
``maximum``   w_i = 1 for the technique with the largest q (ties share equally), else 0
``average``   w_i = 1 / (number of techniques with q_k > 0).  The lecture's plain 1/N, restricted
              to the techniques that can produce x, since 1/N itself would violate (b) and bias
              the estimate wherever a pdf is zero (e.g. a BSDF direction that misses every light).
``partition`` the lecture's stratification, w in {0, 1}: the first technique *in the order the
              caller lists them* whose q is non-zero takes the whole weight.  Integrators list
              light sampling first, so a direction that hits a light counts only from light
              sampling and every other direction only from BSDF sampling.

Densities are normalised by their maximum before powers are taken, so steep pdfs (Phong exponent
10,000, tiny lights) cannot overflow single precision.  ``q`` may hold +inf for a technique that
must win outright.  Negative or NaN densities (some Mitsuba BSDFs return them below the horizon)
count as zero.
"""
from __future__ import annotations

from typing import Sequence

import drjit as dr
import mitsuba as mi

from ..common import safe_div
from ..params import Param

HEURISTICS = ("balance", "power", "cutoff", "maximum", "average", "partition")

PARAMS = (
    Param("heuristic", "choice", "balance", choices=HEURISTICS,
          doc="MIS weighting of the sampling techniques."),
    Param("beta", "float", 2.0, min=0.0, min_exclusive=True,
          doc="Exponent of the power heuristic."),
    Param("alpha", "float", 0.1, min=0.0, max=1.0,
          doc="Cutoff heuristic: techniques below alpha * max density are dropped."),
)


class Heuristic:
    """A MIS weighting function over effective densities ``q``."""

    def __init__(self, name: str = "balance", beta: float = 2.0, alpha: float = 0.1):
        if name not in HEURISTICS:
            raise ValueError(f"unknown MIS heuristic {name!r}; allowed: {', '.join(HEURISTICS)}")
        self.name, self.beta, self.alpha = name, float(beta), float(alpha)

    @classmethod
    def from_params(cls, p: dict) -> "Heuristic":
        return cls(p["heuristic"], p.get("beta", 2.0), p.get("alpha", 0.1))

    def __repr__(self):
        extra = {"power": f", beta={self.beta}", "cutoff": f", alpha={self.alpha}"}.get(self.name, "")
        return f"Heuristic({self.name!r}{extra})"

    def weights(self, q: Sequence) -> list:
        """Weights of every technique for densities ``q`` (one entry per technique)."""
        q = [mi.Float(x) for x in q]
        q = [dr.select(x > 0, x, 0.0) for x in q]          # NaN / negative -> 0
        qmax = q[0]
        for x in q[1:]:
            qmax = dr.maximum(qmax, x)
        has = qmax > 0
        inv = safe_div(1.0, qmax)
        # ratio to the largest density, in [0, 1]; exactly 1 for the maximum (also for +inf)
        r = [dr.select(x == qmax, dr.select(has, 1.0, 0.0), x * inv) for x in q]
        zero = mi.Float(0.0)

        if self.name == "balance":
            s = r
        elif self.name == "power":
            s = [dr.select(x > 0, dr.power(x, self.beta), 0.0) for x in r]
        elif self.name == "cutoff":
            s = [dr.select((x > 0) & (x >= self.alpha), x, 0.0) for x in r]
        elif self.name == "maximum":
            s = [dr.select(has & (x == 1.0), 1.0, 0.0) for x in r]
        elif self.name == "average":
            s = [dr.select(x > 0, 1.0, 0.0) for x in r]
        else:  # partition: the first technique (in the caller's order) that can produce x
            s, taken = [], mi.Bool(False)
            for x in r:
                s.append(dr.select(taken, 0.0, dr.select(x > 0, 1.0, 0.0)))
                taken = taken | (x > 0)
        total = zero
        for x in s:
            total = total + x
        inv_total = safe_div(1.0, total)
        return [x * inv_total for x in s]

    def weight(self, i: int, q: Sequence):
        """Weight of technique ``i`` for densities ``q``."""
        return self.weights(q)[i]
