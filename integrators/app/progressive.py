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
budget, passes of about ``PASS_SECONDS``, sized from the first three passes.  A film of more
than 2^24 pixels (one sample per pixel would not fit a pass), of no pixels, or one whose sums
would not fit in the memory available is refused up front (:func:`check_film`, a
:class:`RenderError` giving the memory needed).  Seeds are ``seed, seed + 1, ...`` (one per
pass, 32-bit: at most ``MAX_SEED``); runs that are to be merged must use disjoint ranges.  A
render with ``spp`` whose seeds would pass ``MAX_SEED`` is refused up front; a render with a time
budget stops after the pass with seed ``MAX_SEED`` (``acc.stopped = "seeds"``).
A render stops after the pass that reaches ``spp`` or crosses ``time_budget``, or after the pass
in flight when :class:`Stop` is set (the CLI sets it on SIGINT/SIGTERM).  Kernels are compiled
once per pass size, not once per pass (the seed is not baked into the kernel).
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import mitsuba as mi
import numpy as np

from .record import RunRecord

MAX_SAMPLES_PER_PASS = 1 << 24
PASS_SECONDS = 0.25
#: seeds are 32-bit unsigned integers (Mitsuba's samplers)
MAX_SEED = (1 << 32) - 1
#: largest samples per pixel of a render (its pass count and seeds must stay 32-bit)
MAX_SPP = (1 << 32) - 1


class RenderError(ValueError):
    """A render that cannot be done as asked (film size, memory, spp, seeds); one line."""


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
    #: channel names of the image (("R", "G", "B"), ("Y",), ("X", "Y", "Z"), ...), as the film
    #: names them; empty: by count (imageio.channel_names)
    channels: tuple = ()
    #: why the render stopped early ("" if it did not): "seeds" when the seeds ran out
    stopped: str = ""

    @classmethod
    def empty(cls, shape, seed_first=0, record: RunRecord | None = None, channels=()):
        return cls(np.zeros(shape), np.zeros(shape), seed_first=seed_first,
                   seed_last=seed_first - 1, record=record or RunRecord(),
                   channels=tuple(channels))

    def add(self, image: np.ndarray, spp: int, seed: int):
        """Add a pass; SIGINT/SIGTERM are held while the sums change (interrupt.deferred), so
        a handler that writes them never sees half an update."""
        from .interrupt import deferred
        x = np.asarray(image, dtype=np.float64)
        with deferred():
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
    def from_estimate(cls, mean, variance, record: RunRecord, channels=()) -> "Accumulator":
        """Rebuild the sums from a written estimate and its record (used by merge)."""
        spp, passes = record.spp, record.passes
        mean = np.asarray(mean, np.float64)
        sigma2 = np.asarray(variance, np.float64) * spp
        s2 = sigma2 * max(passes - 1, 0) + spp * mean * mean
        return cls(mean * spp, s2, spp, passes, record.seed_first, record.seed_last,
                   record.seconds, record=record,
                   seed_ranges=[list(r) for r in record.ranges()], channels=tuple(channels))

    def merge(self, other: "Accumulator") -> "Accumulator":
        rec = self.run_record().merged(other.run_record())
        return Accumulator(self.s + other.s, self.s2 + other.s2, rec.spp, rec.passes,
                           rec.seed_first, rec.seed_last, rec.seconds, record=rec,
                           seed_ranges=[list(r) for r in rec.seed_ranges],
                           channels=self.channels)


def film_size(scene, sensor: int = 0):
    size = scene.sensors()[sensor].film().crop_size()
    return int(size[0]), int(size[1])


_FORMAT_CHANNELS = {"luminance": 1, "y": 1, "luminance_alpha": 2, "ya": 2, "rgb": 3, "xyz": 3,
                    "rgba": 4, "xyza": 4}


def film_channels(scene, sensor: int = 0) -> int:
    """Channels of the film's image (its pixel format; 4 when it cannot be told)."""
    text = str(scene.sensors()[sensor].film())
    for line in text.splitlines():
        if "pixel_format" in line:
            return _FORMAT_CHANNELS.get(line.split("=", 1)[-1].strip(" ,").lower(), 4)
    return 4


def bytes_per_pixel(channels: int) -> int:
    """Memory a render needs per film pixel: the sums S and S2 and one pass's image in float64
    (24 bytes a channel), Mitsuba's float32 result (4 a channel) and its film (channels, alpha
    and weight in float32, in its image block and developed: 8 a channel + 16).  Measured peak
    for RGB: about 126 bytes per pixel."""
    return 36 * channels + 16


def memory_available() -> int | None:
    """Bytes this process may still allocate: the least of MemAvailable, the cgroup's limit
    minus its use, and RLIMIT_AS minus what is mapped (None when none can be read)."""
    limits = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    limits.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            cap = f.read().strip()
        if cap != "max":
            with open("/sys/fs/cgroup/memory.current") as f:
                limits.append(int(cap) - int(f.read().strip()))
    except (OSError, ValueError):
        pass
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY:
            with open("/proc/self/statm") as f:
                mapped = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
            limits.append(soft - mapped)
    except (ImportError, OSError, ValueError):
        pass
    return max(min(limits), 0) if limits else None


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def check_film(scene, sensor: int = 0) -> tuple[int, int]:
    """(width, height) of the film; :class:`RenderError` (one line, with the memory needed)
    for a film with no pixels, one larger than a pass may hold (2^24 pixels: a pass holds at
    least one sample per pixel), or one whose sums do not fit in the memory available."""
    w, h = film_size(scene, sensor)
    if w <= 0 or h <= 0:
        raise RenderError(f"the film is {w}x{h} pixels: it has no pixels to render")
    need = w * h * bytes_per_pixel(film_channels(scene, sensor))
    if w * h > MAX_SAMPLES_PER_PASS:
        raise RenderError(
            f"the film is {w}x{h} = {w * h:,} pixels, more than a pass may hold "
            f"({MAX_SAMPLES_PER_PASS:,} samples, e.g. 4096x4096), and would need about "
            f"{_gib(need)} of memory; render a smaller film (or parts of it with the film's "
            "crop_offset_x/y and crop_width/height)")
    free = memory_available()
    if free is not None and need > free:
        raise RenderError(f"the film is {w}x{h} pixels and needs about {_gib(need)} of memory "
                          f"({bytes_per_pixel(film_channels(scene, sensor))} bytes per pixel); "
                          f"{_gib(free)} are available")
    return w, h


def check_spp(spp) -> int:
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or not \
            1 <= spp <= MAX_SPP:
        raise RenderError(f"spp = {spp!r} is invalid; allowed: an integer >= 1 and <= {MAX_SPP}")
    return int(spp)


def check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not \
            0 <= seed <= MAX_SEED:
        raise RenderError(f"seed = {seed!r} is invalid; allowed: an integer >= 0 and <= "
                          f"{MAX_SEED}")
    return int(seed)


def pass_size(w: int, h: int, spp: int | None) -> tuple[int, int]:
    """(samples per pixel of a pass, the most a pass may take) for a ``w`` x ``h`` film."""
    cap = max(1, MAX_SAMPLES_PER_PASS // max(w * h, 1))
    if spp is None:
        return 1, cap          # calibration pass; resized from the first passes
    return int(min(cap, max(1, math.ceil(spp / 8)))), cap


def _film_channel_names(scene, sensor: int, count: int) -> tuple:
    try:
        st = scene.sensors()[sensor].film().bitmap().struct_()
        names = tuple(st[i].name for i in range(len(st)))
    except Exception:      # no developed bitmap: names by count
        return ()
    return names if len(names) == count else ()


def render(scene, spp: int | None = None, time_budget: float | None = None, seed: int = 0,
           sensor: int = 0, stop: Stop | None = None,
           on_pass: Callable[[Accumulator], None] | None = None,
           record: RunRecord | None = None) -> Accumulator:
    """Render ``scene`` in passes until ``spp`` samples per pixel, ``time_budget`` seconds, or
    ``stop``; returns the accumulated estimate (see the module docstring), which carries
    ``record`` (the run's identity: ``RunRecord.for_scene``) for :func:`write`."""
    from .interrupt import test_pause
    if spp is None and time_budget is None:
        spp = scene.sensors()[sensor].sampler().sample_count()
    if spp is not None:
        spp = check_spp(spp)
    seed = check_seed(seed)
    w, h = check_film(scene, sensor)
    pass_spp, cap = pass_size(w, h, spp)
    if spp is not None:
        passes = math.ceil(spp / pass_spp)
        if seed + passes - 1 > MAX_SEED:
            raise RenderError(
                f"seed {seed} with spp {spp} needs the seeds {seed}-{seed + passes - 1} (one per "
                f"pass, {passes} passes), past the largest seed {MAX_SEED}; use a seed <= "
                f"{MAX_SEED - passes + 1}")
    acc = None
    t0 = time.perf_counter()
    next_seed = seed
    while True:
        n = pass_spp if spp is None else min(pass_spp, spp - (acc.spp if acc else 0))
        test_pause("compile" if acc is None else "pass")
        t_pass = time.perf_counter()
        img = mi.render(scene, spp=n, seed=next_seed, sensor=sensor)
        img = np.array(img, dtype=np.float64)
        if img.ndim == 2:
            img = img[..., None]
        dt = time.perf_counter() - t_pass
        if acc is None:
            acc = Accumulator.empty(img.shape, seed_first=next_seed, record=record,
                                    channels=_film_channel_names(scene, sensor, img.shape[2]))
        acc.add(img, n, next_seed)
        acc.seconds = time.perf_counter() - t0
        notes = getattr(scene.integrator(), "run_notes", None)
        if callable(notes):     # the integrator's own account of its state (learning, chains)
            acc.record = replace(acc.record, notes=dict(notes()))
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
        if next_seed >= MAX_SEED:
            acc.stopped = "seeds"
            break
        next_seed += 1
    return acc


# ---------------------------------------------------------------------------------------------
# files: EXR with an RGB layer, a variance layer and the run record in its header
def write(path, acc: Accumulator, meta: RunRecord | dict | None = None,
          preview: bool | str | Path = False) -> None:
    """Write ``acc`` (estimate, variance layer) with its run record in the header
    (:meth:`RunRecord.header`).  ``meta`` replaces the accumulator's record identity: a
    RunRecord, or a dict of RunRecord fields (other keys become extra header attributes).
    ``preview`` (True: ``path`` with ``.png``; or a path) also writes the sRGB PNG preview; the
    two files are replaced together or not at all (:func:`imageio.write_together`); a failure
    raises :class:`imageio.WriteError` naming the output."""
    from .imageio import encode_exr, encode_png, write_together
    extra = {}
    if isinstance(meta, dict):
        names = set(RunRecord.__dataclass_fields__)
        extra = {k: v for k, v in meta.items() if k not in names}
        meta = RunRecord.from_dict(meta)
    if meta is not None:
        acc = replace(acc, record=meta)
    header = {**extra, **acc.run_record().header()}
    mean = acc.mean()
    items = [(Path(path), encode_exr({"": mean, "variance": acc.variance()}, header,
                                     acc.channels or None))]
    if preview:
        png = Path(path).with_suffix(".png") if preview is True else Path(preview)
        items.append((png, encode_png(mean, acc.channels or None)))
    write_together(items)


def read(path) -> Accumulator:
    """The accumulator of a file written by :func:`write`; ValueError("PATH: not an EXR
    written by render ...") for anything else."""
    from .imageio import read_layers_named
    layers, meta, names = read_layers_named(path)
    try:
        record = RunRecord.from_header(meta)
    except (KeyError, ValueError, TypeError) as e:
        what = f"no {e.args[0]} attribute" if isinstance(e, KeyError) else "bad run_record"
        raise ValueError(f"{path}: not an EXR written by render ({what})") from None
    if "" not in layers or "variance" not in layers:
        raise ValueError(f"{path}: not an EXR written by render (no RGB or variance layer)")
    if layers["variance"].shape != layers[""].shape:
        raise ValueError(f"{path}: not an EXR written by render (the variance layer does not "
                         "match the image)")
    return Accumulator.from_estimate(layers[""], layers["variance"], record, names[""])


def merge(paths) -> Accumulator:
    """Sample-weighted merge of independent runs; refuses runs whose records cannot be merged
    (:meth:`RunRecord.merge_problem`: scene content, integrator and parameters, variant,
    defines, overlapping seed ranges) and different image sizes.  The result carries the
    merged record (``seed_ranges`` lists every run's range)."""
    paths = [str(p) for p in paths]
    accs = [read(p) for p in paths]
    for i in range(1, len(accs)):
        if accs[i].s.shape[:2] == accs[0].s.shape[:2] and accs[i].channels != accs[0].channels:
            raise ValueError(f"{paths[i]}: channels {''.join(accs[i].channels)} differ from "
                             f"{paths[0]} ({''.join(accs[0].channels)})")
        if accs[i].s.shape != accs[0].s.shape:
            raise ValueError(f"{paths[i]}: image size {accs[i].s.shape[1]}x{accs[i].s.shape[0]}"
                             f" differs from {paths[0]} ({accs[0].s.shape[1]}x"
                             f"{accs[0].s.shape[0]})")
    return merge_accumulators(accs, paths)


def merge_accumulators(accs, names) -> Accumulator:
    """``accs`` merged by sample count (:meth:`Accumulator.merge`), after checking every pair's
    records (:meth:`RunRecord.merge_problem`, ValueError naming the two by ``names``): the one
    merge of ``merge`` and of distributed renders."""
    for i in range(1, len(accs)):
        for j in range(i):
            problem = accs[j].record.merge_problem(accs[i].record, names[j], names[i])
            if problem:
                raise ValueError(problem)
    out = accs[0]
    for a in accs[1:]:
        out = out.merge(a)
    return out
