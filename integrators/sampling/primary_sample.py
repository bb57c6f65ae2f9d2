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

* :func:`uniform`: counter-based random numbers (a hash of an index and a key), so a primary vector
  is a function of (its index, the key): bootstrap vectors are regenerated from their index
  instead of being stored (as pbrt-v4's ``MLTIntegrator`` does with its RNG streams);
* :func:`propose`, :func:`large_steps`: the proposal of every coordinate of every chain, a
  function of the current value, the coordinate's index and the step's key;
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
#: ratio s2 / s1 of Kelemen's perturbation (1/64 and 1/1024 in the paper)
KELEMEN_RATIO = 16.0

# streams: distinct constants xor-ed into a step's key, one per use of random numbers
STREAM_LARGE, STREAM_COORD, STREAM_ACCEPT, STREAM_EXTRA, STREAM_SEED = \
    0x0, 0x5bd1e995, 0x68e31da4, 0x1b873593, 0x2c1b3c6d


def dims_for(max_depth: int, choice_dims: int = 1) -> int:
    """Stored coordinates per chain for ``max_depth`` (Mitsuba's meaning, -1 unlimited):
    CAMERA_DIMS + VERTEX_DIMS per vertex that can cast a light sample, at most
    MAX_STORED_VERTICES vertices; ``choice_dims``: the numbers a light choice draws (1, or 2
    for ris), VERTEX_DIMS counting one."""
    vertices = MAX_STORED_VERTICES if max_depth < 0 else max(0, min(max_depth - 1,
                                                                    MAX_STORED_VERTICES))
    return CAMERA_DIMS + (VERTEX_DIMS + choice_dims - 1) * vertices


def hash32(x):
    """The PCG hash of a UInt32 (Jarzynski and Olano 2020, "Hash functions for GPU rendering":
    one step of a PCG generator and its output permutation)."""
    state = mi.UInt32(x) * 747796405 + 2891336453
    word = ((state >> ((state >> 28) + 4)) ^ state) * 277803737
    return (word >> 22) ^ word


def uniform(index, key):
    """Uniform numbers in [0, 1) (multiples of 2^-24): the hash of ``index`` (UInt32, per
    lane) mixed with the hash of ``key`` (UInt32), hashed again."""
    h = hash32(hash32(index) + hash32(key))
    return mi.Float(h >> 8) * (1.0 / (1 << 24))


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


def propose(cur, index, key, large, sigma: float):
    """The proposed value of coordinate ``index`` (UInt32, chain x dims + d) whose current
    value is ``cur``: uniform with ``large`` (a large step), else ``cur`` moved by Kelemen's
    offset of size ``sigma``, mod 1.  A function of (cur, index, key), so the path kernel draws
    the coordinates it needs lazily and the accept step recomputes the same values."""
    r = uniform(index, stream(key, STREAM_COORD))
    return dr.select(large, r, wrap(cur + kelemen_offset(r, sigma)))


def large_steps(chain_ids, key, large_step: float):
    """Which chains take a large step (probability ``large_step``) in the step of ``key``."""
    return uniform(chain_ids, stream(key, STREAM_LARGE)) < large_step


class PrimarySampler:
    """``next_1d``/``next_2d`` reading each lane's primary vector coordinate by coordinate.

    Made by :func:`primary_sampler`, which binds the read-only data to a class of its own:
    Dr.Jit's loops rebuild a struct from its type and its declared fields (here only the
    per-lane counter ``dim``), so the data must live on the type.  Lane i reads row
    ``rows[i]`` of ``u`` (flat Float, chains x ``dims``, row-major; or a ``dr.Local`` of
    ``dims`` Floats per lane holding the lane's own row, inside a loop over steps that
    rewrites it): with ``large`` (Bool per
    lane) given, the *proposal* of that row (:func:`propose`, drawn lazily), else the row
    itself (the current state); with ``u`` None,
    the generated vector ``uniform(rows[i] * dims + d, key)`` (bootstrap vectors, regenerated
    later from their index).  Coordinates past ``dims`` (only with ``extra``) are fresh
    numbers keyed by (row, dimension, ``key``)."""

    DRJIT_STRUCT = {"dim": mi.UInt32}
    u = None
    dims = 0
    rows = None
    key = None
    large = None
    sigma = 0.0
    extra = True
    #: this stream's coordinates within a row: ``count`` of them from ``offset`` (count 0: the
    #: whole row); past them, fresh numbers
    offset = 0
    count = 0

    def __init__(self):
        self.dim = dr.zeros(mi.UInt32, dr.width(self.rows)) if self.rows is not None \
            else mi.UInt32(0)

    def next_1d(self, active=True):
        d = self.dim
        self.dim = d + 1
        n = self.count or self.dims - self.offset
        if n <= 0:
            return self._extra(d)
        stored = d < n
        col = self.offset + dr.minimum(d, n - 1)
        index = self.rows * self.dims + col
        if self.u is None:
            v = uniform(index, self.key)
        else:
            v = self.u[col] if isinstance(self.u, dr.Local) \
                else dr.gather(mi.Float, self.u, index)
            if self.large is not None:
                v = propose(v, index, self.key, self.large, self.sigma)
        return dr.select(stored, v, self._extra(d)) if self.extra else v

    def _extra(self, d):
        k = hash32(stream(self.key, STREAM_EXTRA))
        if self.offset:                  # each stream its own fresh numbers
            k = hash32(k + self.offset)
        return uniform(self.rows, k + d)

    def substream(self, offset: int, count: int) -> "PrimarySampler":
        """A sampler over the same rows that reads coordinates ``offset`` ..
        ``offset + count - 1`` of each row (fresh numbers past them), from its first: a path
        estimator with two subpaths gives each its own coordinates, so that a longer light
        subpath does not shift the camera subpath's numbers."""
        cls = type("PrimarySampler", (type(self),), {"offset": int(offset), "count": int(count)})
        return cls()

    def next_2d(self, active=True):
        x = self.next_1d(active)
        y = self.next_1d(active)
        return mi.Point2f(x, y)


def primary_sampler(u, dims: int, rows, key, large=None, sigma: float = 0.0,
                    extra: bool = True) -> PrimarySampler:
    """A :class:`PrimarySampler`: lane i reads row ``rows[i]`` of ``u`` (its proposal when
    ``large`` is given; generated vectors with ``u`` None), with the step's ``key`` (UInt32).
    ``extra`` False: the path never draws more than ``dims`` numbers (finite max_depth)."""
    cls = type("PrimarySampler", (PrimarySampler,),
               {"u": u, "dims": int(dims), "rows": mi.UInt32(rows), "key": mi.UInt32(key),
                "large": large, "sigma": float(sigma), "extra": bool(extra)})
    return cls()
