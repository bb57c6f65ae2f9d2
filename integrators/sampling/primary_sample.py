r"""Primary sample space: a path as a point u in [0, 1)^D, and the mutations of Kelemen et al.

Kelemen, Szirmay-Kalos, Antal and Csonka (2002), "A simple and robust mutation strategy for the
Metropolis light transport algorithm": every random number a path tracer draws is a coordinate
of a *primary sample* u; the path, its film position and its contribution f(u) are a
deterministic function of u.  Metropolis sampling then moves in [0, 1)^D, where the proposal
densities are trivial:

* **large step**: a fresh uniform vector (an independence proposal, T(u -> u') = 1);
* **small step**: every coordinate moved by Kelemen's perturbation,
  u'_i = u_i +- s2 exp(-log(s2/s1) xi) (mod 1), sign and xi uniform.  The offset's density is
  even, so T(u -> u') = T(u' -> u) and the acceptance probability is min(1, I(u')/I(u)).

This module holds what the chains need, vectorised over chains as Dr.Jit lanes:

* :func:`uniform`: counter-based random numbers (TEA of an index and a key), so a primary vector
  is a function of (its index, the key): bootstrap vectors are regenerated from their index
  instead of being stored (as pbrt-v4's ``MLTIntegrator`` does with its RNG streams);
* :func:`mutate`: the proposal for every chain, flat arrays of chains x D coordinates;
* :class:`PrimarySampler`: a duck-typed sampler (``next_1d``, ``next_2d``) that reads the
  coordinates of each lane's vector in order, so that an unchanged path estimator
  (:meth:`integrators.sampling.vertex.VertexEstimator.path`) is driven by it.  It is a
  Dr.Jit struct whose only field is the per-lane dimension counter, so a symbolic loop carries
  the counter as loop state.  A path that draws more than D numbers gets fresh uniform numbers
  for the rest (keyed by lane, dimension and the step's key): those coordinates are resampled
  from their prior at every proposal, which leaves the chain exact (MH on the extended space
  (u, v) with an independence proposal for v; the current state keeps its own f).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

#: coordinates before the path's own: film x, film y, wavelength, aperture x, aperture y, time
CAMERA_DIMS = 6
#: coordinates one vertex of VertexEstimator.path draws with one light sample: light selection
#: and position (3), BSDF lobe and direction (3), roulette (1)
VERTEX_DIMS = 7
#: vertices whose coordinates are stored (and mutated); deeper vertices use fresh numbers
MAX_STORED_VERTICES = 16
#: TEA rounds of the counter-based generator
TEA_ROUNDS = 8
#: ratio s2 / s1 of Kelemen's perturbation (1/64 and 1/1024 in the paper)
KELEMEN_RATIO = 16.0

# streams: distinct constants xor-ed into a step's key, one per use of random numbers
STREAM_LARGE, STREAM_COORD, STREAM_ACCEPT, STREAM_EXTRA, STREAM_SEED = \
    0x0, 0x5bd1e995, 0x68e31da4, 0x1b873593, 0x2c1b3c6d


def dims_for(max_depth: int) -> int:
    """Stored coordinates per chain for ``max_depth`` (Mitsuba's meaning, -1 unlimited):
    CAMERA_DIMS + VERTEX_DIMS per vertex that can cast a light sample, at most
    MAX_STORED_VERTICES vertices."""
    vertices = MAX_STORED_VERTICES if max_depth < 0 else max(0, min(max_depth - 1,
                                                                    MAX_STORED_VERTICES))
    return CAMERA_DIMS + VERTEX_DIMS * vertices


def uniform(index, key):
    """Uniform numbers in [0, 1): TEA of (``index``, ``key``), both UInt32 (per lane)."""
    return mi.sample_tea_float32(mi.UInt32(index), mi.UInt32(key), TEA_ROUNDS)


def stream(key, which: int):
    """The key of one stream of a step (``key`` a UInt32, ``which`` a STREAM_* constant)."""
    return mi.UInt32(key) ^ which


def kelemen_offset(r, sigma: float):
    """Kelemen's symmetric offset from one uniform ``r``: sign from r < 1/2, magnitude
    s2 exp(-log(s2/s1) xi) with xi = 2r mod 1, s2 = ``sigma``, s1 = sigma / KELEMEN_RATIO."""
    neg = r < 0.5
    xi = dr.select(neg, 2.0 * r, 2.0 * r - 1.0)
    mag = sigma * dr.exp(-math.log(KELEMEN_RATIO) * xi)
    return dr.select(neg, -mag, mag)


def wrap(x):
    """x mod 1 in [0, 1)."""
    y = x - dr.floor(x)
    return dr.select(y >= 1.0, 0.0, y)


def mutate(u, chain_ids, dims: int, key, large_step: float, sigma: float):
    """The proposal of each chain in ``chain_ids`` (UInt32, m lanes) from its current vector
    in ``u`` (flat, chains x ``dims``): (flat proposal, m x dims; large-step mask, m lanes).
    ``large_step``: probability of a large step; ``sigma``: Kelemen's s2."""
    m = dr.width(chain_ids)
    large = uniform(chain_ids, stream(key, STREAM_LARGE)) < large_step
    flat = dr.arange(mi.UInt32, m * dims)
    lane = flat // dims
    chain = dr.gather(mi.UInt32, chain_ids, lane)
    index = chain * dims + (flat - lane * dims)
    cur = dr.gather(mi.Float, u, index)
    r = uniform(index, stream(key, STREAM_COORD))
    big = dr.gather(mi.Bool, large, lane)
    prop = dr.select(big, r, wrap(cur + kelemen_offset(r, sigma)))
    return prop, large


class PrimarySampler:
    """``next_1d``/``next_2d`` reading each lane's primary vector coordinate by coordinate.

    Made by :func:`primary_sampler`, which binds the read-only data (``u``, ``dims``,
    ``lanes``, ``key``) to a class of its own: Dr.Jit's loops rebuild a struct from its type
    and its declared fields (here only the per-lane counter ``dim``), so the data must live on
    the type.  ``u``: flat Float of lanes x ``dims`` coordinates (row-major), or None to
    generate the coordinates of lane ``i`` as ``uniform(lanes[i] * dims + d, key)`` (bootstrap
    vectors, regenerated later from their index).  ``lanes``: the row of ``u`` per lane.
    Coordinates past ``dims`` are fresh numbers keyed by (lane, dimension, ``key``)."""

    DRJIT_STRUCT = {"dim": mi.UInt32}
    u = None
    dims = 0
    lanes = None
    key = None
    extra_key = None

    def __init__(self):
        self.dim = dr.zeros(mi.UInt32, dr.width(self.lanes)) if self.lanes is not None \
            else mi.UInt32(0)

    def next_1d(self, active=True):
        d = self.dim
        stored = d < self.dims
        dd = dr.minimum(d, self.dims - 1) if self.dims > 0 else mi.UInt32(0)
        if self.u is None:
            v = uniform(self.lanes * self.dims + dd, self.key)
        else:
            v = dr.gather(mi.Float, self.u, self.lanes * self.dims + dd, stored)
        extra = uniform(self.lanes, mi.sample_tea_32(self.extra_key, d, 4)[0])
        self.dim = d + 1
        return dr.select(stored, v, extra) if self.dims > 0 else extra

    def next_2d(self, active=True):
        x = self.next_1d(active)
        y = self.next_1d(active)
        return mi.Point2f(x, y)


def primary_sampler(u, dims: int, lanes, key) -> PrimarySampler:
    """A :class:`PrimarySampler` over ``u`` (or generated vectors with ``u`` None) for the
    lanes ``lanes`` (UInt32), with the step's ``key`` (UInt32)."""
    cls = type("PrimarySampler", (PrimarySampler,),
               {"u": u, "dims": int(dims), "lanes": mi.UInt32(lanes), "key": mi.UInt32(key),
                "extra_key": stream(key, STREAM_EXTRA)})
    return cls()
