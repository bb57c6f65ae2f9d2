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
from dataclasses import dataclass, field, replace
from typing import Callable

import mitsuba as mi
import numpy as np

from .record import RunRecord

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
    """Running sums of pass means (see the module docstring), the counts of the run, and its
    :class:`RunRecord` (``record``: scene, integrator, variant, defines; the counts in it are
    filled in by :meth:`run_record`)."""
    s: np.ndarray
    s2: np.ndarray
    spp: int = 0
    passes: int = 0
    seed_first: int = 0
    seed_last: int = -1
    seconds: float = 0.0
    record: RunRecord = field(default_factory=RunRecord)
    #: seed ranges [[first, last], ...]: one for a render, one per run for a merge
    seed_ranges: list = field(default_factory=list)

    @classmethod
    def empty(cls, shape, seed_first=0, record: RunRecord | None = None):
        return cls(np.zeros(shape), np.zeros(shape), seed_first=seed_first,
                   seed_last=seed_first - 1, record=record or RunRecord())

    def add(self, image: np.ndarray, spp: int, seed: int):
        x = np.asarray(image, dtype=np.float64)
        self.s += spp * x
        self.s2 += spp * x * x
        self.spp += spp
        self.passes += 1
        self.seed_last = seed
        if self.seed_ranges:
            self.seed_ranges[-1][1] = seed
        else:
            self.seed_ranges = [[self.seed_first, seed]]

    def run_record(self) -> RunRecord:
        """``record`` with this accumulator's spp, passes, seeds and seconds."""
        ranges = self.seed_ranges or [[self.seed_first, self.seed_last]]
        return replace(self.record, spp=self.spp, passes=self.passes,
                       seed_first=self.seed_first, seed_last=self.seed_last,
                       seconds=float(self.seconds), seed_ranges=[list(r) for r in ranges])

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
    def from_estimate(cls, mean, variance, record: RunRecord) -> "Accumulator":
        """Rebuild the sums from a written estimate and its record (used by merge)."""
        spp, passes = record.spp, record.passes
        mean = np.asarray(mean, np.float64)
        sigma2 = np.asarray(variance, np.float64) * spp
        s2 = sigma2 * max(passes - 1, 0) + spp * mean * mean
        return cls(mean * spp, s2, spp, passes, record.seed_first, record.seed_last,
                   record.seconds, record=record,
                   seed_ranges=[list(r) for r in record.ranges()])

    def merge(self, other: "Accumulator") -> "Accumulator":
        rec = self.run_record().merged(other.run_record())
        return Accumulator(self.s + other.s, self.s2 + other.s2, rec.spp, rec.passes,
                           rec.seed_first, rec.seed_last, rec.seconds, record=rec,
                           seed_ranges=[list(r) for r in rec.seed_ranges])


def film_size(scene, sensor: int = 0):
    size = scene.sensors()[sensor].film().crop_size()
    return int(size[0]), int(size[1])


def render(scene, spp: int | None = None, time_budget: float | None = None, seed: int = 0,
           sensor: int = 0, stop: Stop | None = None,
           on_pass: Callable[[Accumulator], None] | None = None,
           record: RunRecord | None = None) -> Accumulator:
    """Render ``scene`` in passes until ``spp`` samples per pixel, ``time_budget`` seconds, or
    ``stop``; returns the accumulated estimate (see the module docstring), which carries
    ``record`` (the run's identity: ``RunRecord.for_scene``) for :func:`write`."""
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
            acc = Accumulator.empty(img.shape, seed_first=next_seed, record=record)
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
# files: EXR with an RGB layer, a variance layer and the run record in its header
def write(path, acc: Accumulator, meta: RunRecord | dict | None = None) -> None:
    """Write ``acc`` (estimate, variance layer) with its run record in the header
    (:meth:`RunRecord.header`).  ``meta`` replaces the accumulator's record identity: a
    RunRecord, or a dict of RunRecord fields (other keys become extra header attributes)."""
    from .imageio import write_layers
    extra = {}
    if isinstance(meta, dict):
        names = set(RunRecord.__dataclass_fields__)
        extra = {k: v for k, v in meta.items() if k not in names}
        meta = RunRecord.from_dict(meta)
    if meta is not None:
        acc = replace(acc, record=meta)
    header = {**extra, **acc.run_record().header()}
    write_layers(path, {"": acc.mean(), "variance": acc.variance()}, header)


def read(path) -> Accumulator:
    """The accumulator of a file written by :func:`write`; ValueError("PATH: not an EXR
    written by render ...") for anything else."""
    from .imageio import read_layers
    layers, meta = read_layers(path)
    try:
        record = RunRecord.from_header(meta)
    except (KeyError, ValueError, TypeError) as e:
        what = f"no {e.args[0]} attribute" if isinstance(e, KeyError) else "bad run_record"
        raise ValueError(f"{path}: not an EXR written by render ({what})") from None
    if "" not in layers or "variance" not in layers:
        raise ValueError(f"{path}: not an EXR written by render (no RGB or variance layer)")
    if layers[""].shape[-1] != 3 or layers["variance"].shape != layers[""].shape:
        raise ValueError(f"{path}: not an EXR written by render (layers are not RGB)")
    return Accumulator.from_estimate(layers[""], layers["variance"], record)


def merge(paths) -> Accumulator:
    """Sample-weighted merge of independent runs; refuses runs whose records cannot be merged
    (:meth:`RunRecord.merge_problem`: scene content, integrator and parameters, variant,
    defines, overlapping seed ranges) and different image sizes.  The result carries the
    merged record (``seed_ranges`` lists every run's range)."""
    paths = [str(p) for p in paths]
    accs = [read(p) for p in paths]
    for i in range(1, len(accs)):
        if accs[i].s.shape != accs[0].s.shape:
            raise ValueError(f"{paths[i]}: image size {accs[i].s.shape[1]}x{accs[i].s.shape[0]}"
                             f" differs from {paths[0]} ({accs[0].s.shape[1]}x"
                             f"{accs[0].s.shape[0]})")
        for j in range(i):
            problem = accs[j].record.merge_problem(accs[i].record, paths[j], paths[i])
            if problem:
                raise ValueError(problem)
    out = accs[0]
    for a in accs[1:]:
        out = out.merge(a)
    return out
