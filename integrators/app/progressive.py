r"""Progressive rendering in passes: time budgets, progress, interruption, checkpoints, merging.

Mitsuba's JIT variants have no progress bar, ignore ``timeout`` and keep every sample of a render
in memory at once.  :func:`render` instead calls ``mi.render`` in passes with distinct seeds and
accumulates an unbiased running estimate:

* ``S = sum_p n_p x_p`` and ``S2 = sum_p n_p x_p^2`` per pixel and channel, x_p the mean image of
  pass p with n_p samples per pixel, ``N = sum_p n_p``;
* the estimate is ``S / N``; the per-sample variance is estimated from the pass means as
  ``sigma^2 = (S2 - N mean^2) / (P - 1)`` (each pass mean has variance sigma^2 / n_p), and the
  variance layer written to the EXR is that of the estimate, ``sigma^2 / N`` (needs two passes;
  NaN-free zeros with ``passes = 1`` in the header otherwise).

Pass size: at most ``MAX_SAMPLES_PER_PASS`` samples (2^24) in flight, so memory stays bounded at
any spp and resolution; with ``spp`` given, about 8 passes (for the variance layer); with a time
budget, passes of about ``PASS_SECONDS``, sized from the first three passes.  Seeds are
``seed, seed + 1, ...`` (one per pass); runs that are to be merged must use disjoint ranges.
A render stops after the pass that reaches ``spp`` or crosses ``time_budget``, or after the pass
in flight when :class:`Stop` is set (the CLI sets it on SIGINT/SIGTERM).  Kernels are compiled
once per pass size, not once per pass (the seed is not baked into the kernel).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import mitsuba as mi
import numpy as np

MAX_SAMPLES_PER_PASS = 1 << 24
PASS_SECONDS = 0.25


class Stop:
    """A flag a signal handler can set; the render loop checks it between passes."""

    def __init__(self):
        self.requested = False
        self.reason = ""

    def set(self, reason: str = "stop requested"):
        self.requested, self.reason = True, reason


@dataclass
class Accumulator:
    """Running sums of pass means (see the module docstring)."""
    s: np.ndarray
    s2: np.ndarray
    spp: int = 0
    passes: int = 0
    seed_first: int = 0
    seed_last: int = -1
    seconds: float = 0.0
    meta: dict = field(default_factory=dict)

    @classmethod
    def empty(cls, shape, seed_first=0):
        return cls(np.zeros(shape), np.zeros(shape), seed_first=seed_first,
                   seed_last=seed_first - 1)

    def add(self, image: np.ndarray, spp: int, seed: int):
        x = np.asarray(image, dtype=np.float64)
        self.s += spp * x
        self.s2 += spp * x * x
        self.spp += spp
        self.passes += 1
        self.seed_last = seed

    def mean(self) -> np.ndarray:
        return self.s / max(self.spp, 1)

    def variance(self) -> np.ndarray:
        """Variance of the estimate per pixel and channel (zeros with fewer than 2 passes)."""
        if self.passes < 2:
            return np.zeros_like(self.s)
        m = self.mean()
        sigma2 = np.maximum(self.s2 - self.spp * m * m, 0.0) / (self.passes - 1)
        return sigma2 / self.spp

    @classmethod
    def from_estimate(cls, mean, variance, spp, passes, seed_first, seed_last, meta=None):
        """Rebuild the sums from a written estimate (used by merge)."""
        mean = np.asarray(mean, np.float64)
        sigma2 = np.asarray(variance, np.float64) * spp
        s2 = sigma2 * max(passes - 1, 0) + spp * mean * mean
        return cls(mean * spp, s2, spp, passes, seed_first, seed_last, meta=dict(meta or {}))

    def merge(self, other: "Accumulator") -> "Accumulator":
        return Accumulator(self.s + other.s, self.s2 + other.s2, self.spp + other.spp,
                           self.passes + other.passes, min(self.seed_first, other.seed_first),
                           max(self.seed_last, other.seed_last),
                           self.seconds + other.seconds, dict(self.meta))


def film_size(scene, sensor: int = 0):
    size = scene.sensors()[sensor].film().crop_size()
    return int(size[0]), int(size[1])


def render(scene, spp: int | None = None, time_budget: float | None = None, seed: int = 0,
           sensor: int = 0, stop: Stop | None = None,
           on_pass: Callable[[Accumulator], None] | None = None) -> Accumulator:
    """Render ``scene`` in passes until ``spp`` samples per pixel, ``time_budget`` seconds, or
    ``stop``; returns the accumulated estimate (see the module docstring)."""
    if spp is None and time_budget is None:
        spp = scene.sensors()[sensor].sampler().sample_count()
    w, h = film_size(scene, sensor)
    cap = max(1, MAX_SAMPLES_PER_PASS // max(w * h, 1))
    if spp is not None:
        pass_spp = int(min(cap, max(1, math.ceil(spp / 8))))
    else:
        pass_spp = 1  # calibration pass; resized below
    acc = None
    t0 = time.perf_counter()
    next_seed = seed
    while True:
        n = pass_spp if spp is None else min(pass_spp, spp - (acc.spp if acc else 0))
        t_pass = time.perf_counter()
        img = mi.render(scene, spp=n, seed=next_seed, sensor=sensor)
        img = np.array(img, dtype=np.float64)
        dt = time.perf_counter() - t_pass
        if acc is None:
            acc = Accumulator.empty(img.shape, seed_first=next_seed)
        acc.add(img, n, next_seed)
        next_seed += 1
        acc.seconds = time.perf_counter() - t0
        if spp is None and acc.passes <= 3:
            # the first pass includes compilation: size the passes from the next ones too
            pass_spp = int(min(cap, max(1, round(PASS_SECONDS * n / max(dt, 1e-6)))))
        if on_pass is not None:
            on_pass(acc)
        if stop is not None and stop.requested:
            break
        if spp is not None and acc.spp >= spp:
            break
        if time_budget is not None and acc.seconds >= time_budget:
            break
    return acc


# ---------------------------------------------------------------------------------------------
# files: EXR with an RGB layer, a variance layer and the run's description in its header
META_KEYS = ("scene", "integrator", "variant", "defines", "spp", "passes", "seed_first",
             "seed_last", "seconds")


def write(path, acc: Accumulator, meta: dict) -> None:
    from .imageio import write_layers
    header = dict(meta)
    header.update(spp=acc.spp, passes=acc.passes, seed_first=acc.seed_first,
                  seed_last=acc.seed_last, seconds=f"{acc.seconds:.3f}")
    write_layers(path, {"": acc.mean(), "variance": acc.variance()}, header)


def read(path) -> Accumulator:
    from .imageio import read_layers
    layers, meta = read_layers(path)
    missing = [k for k in ("spp", "passes", "seed_first", "seed_last") if k not in meta]
    if missing or "variance" not in layers:
        raise ValueError(f"{path}: not a render of this tool (no {', '.join(missing) or 'variance layer'})")
    acc = Accumulator.from_estimate(layers[""], layers["variance"], int(meta["spp"]),
                                    int(meta["passes"]), int(meta["seed_first"]),
                                    int(meta["seed_last"]), meta)
    acc.seconds = float(meta.get("seconds", 0.0))
    return acc


def merge(paths) -> tuple[Accumulator, dict]:
    """Sample-weighted merge of independent runs; refuses different scenes, integrators,
    variants or overlapping seed ranges."""
    accs = [read(p) for p in paths]
    first = accs[0].meta
    for p, a in zip(paths[1:], accs[1:]):
        for key in ("scene", "integrator", "variant", "defines"):
            if a.meta.get(key) != first.get(key):
                raise ValueError(f"{p}: {key} differs from {paths[0]} "
                                 f"({a.meta.get(key)!r} vs {first.get(key)!r}); "
                                 "only runs of the same scene and integrator can be merged")
        if a.s.shape != accs[0].s.shape:
            raise ValueError(f"{p}: image size {a.s.shape[:2]} differs from {paths[0]}")
    ranges = sorted((a.seed_first, a.seed_last, p) for a, p in zip(accs, paths))
    for (f1, l1, p1), (f2, l2, p2) in zip(ranges, ranges[1:]):
        if f2 <= l1:
            raise ValueError(f"{p1} (seeds {f1}-{l1}) and {p2} (seeds {f2}-{l2}) overlap: "
                             "their samples are not independent; render with disjoint --seed ranges")
    out = accs[0]
    for a in accs[1:]:
        out = out.merge(a)
    return out, {k: first[k] for k in ("scene", "integrator", "variant", "defines") if k in first}
