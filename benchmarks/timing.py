"""The one timing core of the benchmarks (speed, efficiency, memory, the experiments).

* :func:`timed_render`: ``time.perf_counter`` around ``mi.render(...)``, ``dr.eval(img)`` and
  ``dr.sync_thread()`` (Dr.Jit evaluates lazily: without the last two the clock would stop
  before the kernel ran);
* :func:`round_robin`: ``warmup`` untimed rounds (JIT compilation, or a kernel-cache load, is
  paid there), then ``rounds`` timed rounds, each rendering every configuration once, in the
  given order or rotated by one every round (``rotate``), so slow drift of a shared machine's
  load falls on all configurations alike;
* :func:`stats`: median, min and max of a configuration's timed renders.

Whatever a caller does with an image (errors, means) happens in ``on_render``, outside the
clock.  Mitsuba and Dr.Jit are imported on first use, so importing this module is cheap.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence


def clock() -> float:
    return time.perf_counter()


def timed_render(scene, integrator, spp: int, seed: int, sensor: int = 0):
    """(image, seconds) of one ``mi.render`` (``integrator`` None: the scene's own)."""
    import drjit as dr
    import mitsuba as mi
    kw = {} if integrator is None else {"integrator": integrator}
    t0 = time.perf_counter()
    img = mi.render(scene, spp=int(spp), seed=int(seed), sensor=sensor, **kw)
    dr.eval(img)
    dr.sync_thread()
    return img, time.perf_counter() - t0


def timed(fn: Callable, *args, **kw):
    """(result, seconds) of ``fn(*args, **kw)`` (for work that is not one ``mi.render``, e.g. a
    progressive render, which synchronises itself)."""
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0


def learned_render(scene, integrator, spp: int, seed: int, passes: int = 4, sensor: int = 0):
    """A render of ``spp`` samples per pixel in ``passes`` passes (fewer when spp is smaller),
    for an integrator that learns between passes: the sample-weighted mean image."""
    import drjit as dr
    import mitsuba as mi
    n = max(1, min(int(passes), int(spp)))
    sizes = [spp // n + (1 if k < spp % n else 0) for k in range(n)]
    acc = None
    for k, m in enumerate(sizes):
        img = mi.render(scene, integrator=integrator, spp=m, seed=int(seed) * 64 + k,
                        sensor=sensor) * (m / spp)
        acc = img if acc is None else acc + img
    dr.eval(acc)
    dr.sync_thread()
    return acc


@dataclass
class Timings:
    """Seconds per configuration: ``timed`` (the timed rounds, in round order) and ``warmup``."""
    timed: dict = field(default_factory=dict)
    warmup: dict = field(default_factory=dict)

    def stats(self, name: str) -> dict:
        return stats(self.timed[name])


def stats(seconds: Sequence[float]) -> dict:
    s = list(seconds)
    return {"median": statistics.median(s), "min": min(s), "max": max(s)}


def round_robin(render: Callable[[str, int], tuple], names: Sequence[str], rounds: int,
                warmup: int = 1, rotate: bool = False,
                seed: Callable[[int, str], int] | None = None,
                on_render: Callable[..., None] | None = None) -> Timings:
    """Render every configuration in ``names`` once per round: ``warmup`` untimed rounds, then
    ``rounds`` timed ones.

    ``render(name, seed) -> (image, seconds)`` (usually :func:`timed_render` bound to a scene
    and an integrator); ``seed(round, name)`` with ``round`` counting from 0 over warm-up and
    timed rounds (default: the round index); ``on_render(name, round, warm, image, seconds)``
    after each render.  With ``rotate`` round ``r`` starts at ``names[r % len(names)]``."""
    names = list(names)
    out = Timings({n: [] for n in names}, {n: [] for n in names})
    for rnd in range(warmup + rounds):
        k = rnd % len(names) if rotate and names else 0
        warm = rnd < warmup
        for name in names[k:] + names[:k]:
            s = rnd if seed is None else seed(rnd, name)
            img, dt = render(name, s)
            (out.warmup if warm else out.timed)[name].append(dt)
            if on_render is not None:
                on_render(name, rnd, warm, img, dt)
            del img
    return out
