r"""Learned per-region statistics: what an estimator learns from earlier passes of the same render.

:class:`RegionGrid` hashes a shading point (its position on a regular grid over the scene's
bounding box, and the octant of its shading normal) into one of ``size`` cells.  An estimator
accumulates per-cell statistics inside its kernel (:meth:`RegionGrid.add`, an atomic
scatter-add, so the statistics of a pass cost no extra rays), and between passes turns them into
per-cell decisions on the host (:meth:`RegionGrid.table` / :meth:`RegionGrid.set_table`),
which the next pass reads with one gather (:meth:`RegionGrid.lookup`).  Hash collisions merge two
regions' statistics: a decision may then be worse, never biased, as long as every estimator
built on it is unbiased for any value of the decision (the rule for using this module).

Tables are Dr.Jit arrays passed to the kernel, not constants in it, so a pass with new decisions
reuses the compiled kernel.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import host, host_view, is_jit


class RegionGrid:
    """A hash grid over (position, normal octant) with per-cell statistics and decisions."""

    def __init__(self, scene, stats: int, resolution: int = 32, size: int = 1 << 16,
                 default: float = -1.0):
        bbox = scene.bbox()
        lo = np.array(bbox.min, dtype=np.float64)
        hi = np.array(bbox.max, dtype=np.float64)
        extent = np.maximum(hi - lo, 1e-6)
        self.cell = float(extent.max() / resolution)
        self.lo = [float(x) for x in lo - 1e-3 * extent]
        self.size, self.stats_per_cell, self.default = int(size), int(stats), float(default)
        self.reset()

    def reset(self):
        """Forget everything learned (new scene, or a user's request)."""
        n = self.size * self.stats_per_cell
        self.stats = dr.zeros(mi.Float, n) if is_jit() else np.zeros(n)
        self._table = np.full(self.size, self.default, dtype=np.float32)
        self.decisions = mi.Float(self._table) if is_jit() else self._table.copy()

    # ---- in the kernel -------------------------------------------------------------------
    def cell_of(self, si):
        """Cell index of a surface interaction (UInt32)."""
        q = [mi.Int32(dr.floor((si.p[k] - self.lo[k]) / self.cell)) for k in range(3)]
        octant = (mi.UInt32(si.sh_frame.n.x > 0) | (mi.UInt32(si.sh_frame.n.y > 0) << 1) |
                  (mi.UInt32(si.sh_frame.n.z > 0) << 2))
        h = (mi.UInt32(q[0]) * 73856093) ^ (mi.UInt32(q[1]) * 19349663) ^ \
            (mi.UInt32(q[2]) * 83492791) ^ (octant * 2654435761)
        return h % self.size

    def lookup(self, cell, active=True):
        """The current decision of ``cell`` (``default`` where nothing was learned yet)."""
        if is_jit():
            return dr.gather(mi.Float, self.decisions, cell, active)
        return float(self.decisions[int(cell)]) if active else self.default

    def add(self, cell, values, active, mode=None):
        """Add ``values`` (one Float per statistic, or a dict {statistic index: Float} for a
        few of them) to the cell's statistics.  ``mode``: the scatter's ``dr.ReduceMode``
        (default ``Local``; ``Direct`` is much faster on the LLVM backend when the lanes'
        cells are mostly distinct, e.g. a batch of records)."""
        items = values.items() if isinstance(values, dict) else enumerate(values)
        for k, v in items:
            if is_jit():   # Local: reduce within a SIMD packet first (many lanes, few cells)
                dr.scatter_add(self.stats, v, cell * self.stats_per_cell + k, active,
                               mode=dr.ReduceMode.Local if mode is None else mode)
            elif active:
                self.stats[int(cell) * self.stats_per_cell + k] += float(v)

    # ---- between passes ------------------------------------------------------------------
    def statistics(self) -> np.ndarray:
        """(size, stats) array of what the passes so far accumulated."""
        return host(self.stats).reshape(self.size, self.stats_per_cell)

    def visited(self, column: int):
        """(the cells whose statistic ``column`` is positive, their rows of statistics as
        float64): what a learner reads back between passes, without copying the cells no pass
        reached (most of them)."""
        st = host_view(self.stats).reshape(self.size, self.stats_per_cell)
        vis = np.flatnonzero(st[:, column] > 0)
        return vis, st[vis].astype(np.float64)

    def set_table(self, table: np.ndarray):
        """Decisions for the next pass (one value per cell)."""
        self._table = np.asarray(table, dtype=np.float32)
        self.decisions = mi.Float(self._table) if is_jit() else self._table.copy()

    def table(self) -> np.ndarray:
        return self._table.copy()


#: relative errors are (x - I_p)^2 / (I_p^2 + PIXEL_EPS), the relMSE of the benchmarks
#: (benchmarks.metrics.EPS): without it the darkest pixels' relative variance decides everything
PIXEL_EPS = 0.01


def film_shape(film):
    """(height, width) of the pixels Mitsuba's render lays a pass out over: the film's crop,
    with the reconstruction filter's border where the film samples it."""
    h, w = int(film.crop_size()[1]), int(film.crop_size()[0])
    if film.sample_border():
        b = 2 * int(film.rfilter().border_size())
        h, w = h + b, w + b
    return h, w


def sensor_view(sensor) -> tuple:
    """What a film's pixels see: the film's layout (:func:`film_shape`), its crop offset and
    the sensor's pose (its to_world matrix).  Per-pixel statistics learned for one view are
    not another's: a sensor moved, or another sensor with a film of the same size, starts
    them again.  (Not the sensor's intrinsics: a zoom keeps them.)"""
    film = sensor.film()
    m = np.array(sensor.world_transform().matrix, np.float64).ravel()
    return (film_shape(film), tuple(int(x) for x in film.crop_offset()),
            tuple(float(x) for x in m))


def relmse_denominator(mean):
    """I_p^2 + PIXEL_EPS for pixel means ``mean`` (numpy): what a pixel's squared error is
    divided by in the relMSE, so 1 / it is the pixel's weight there (EARS's and mis3's
    learners both weigh by it)."""
    return np.maximum(mean, 0.0) ** 2 + PIXEL_EPS


class PixelStats:
    """Per-pixel statistics of a render so far, for estimators that learn what a decision is
    worth to the *image*: the mean and second moment of each pixel's camera-sample estimates
    (luminance) and the cost of a camera sample.  From them :meth:`weights` gives each pixel's
    weight in the relMSE, 1 / (I_p^2 + PIXEL_EPS) (I_p the pixel's mean so far), and
    :meth:`image` the image's relative variance and cost per camera sample, whose ratio V / C
    is the exchange rate: where a decision
    changes a pixel sample's variance by dV and its cost by dC, the efficiency of the whole
    image (1 / (V C)) improves iff w_p dV + (V / C) dC < 0, so that is the exchange rate of
    variance against cost that every region's decision should use (the EARS argument, Rath et
    al. 2022).

    Mitsuba's render hands ``sample`` every camera sample of a pass in one wavefront, pixel by
    pixel with ``spp`` consecutive lanes each (lane // spp is the pixel, row by row over the
    film's crop, plus the filter's border where the film samples it): :meth:`pixel` returns
    that index, or None where the wavefront is not laid out so (then nothing is collected)."""

    def __init__(self, n_pixels: int, view=None):
        self.n = int(n_pixels)
        #: the view the pixels are of (:func:`sensor_view`): another view starts them again
        self.view = view
        self.s1 = dr.zeros(mi.Float, self.n)
        self.s2 = dr.zeros(mi.Float, self.n)
        self.count = 0                 # camera samples per pixel so far
        self.cost = dr.zeros(mi.Float, self.n)    # (per pixel: no float32 sum of millions)
        self.cost_samples = 0          # camera samples whose cost was added to ``cost``
        self.w = dr.full(mi.Float, 1.0, self.n)
        dr.eval(self.s1, self.s2, self.cost, self.w)

    @staticmethod
    def layout(sensor) -> int:
        """The number of pixels Mitsuba's render lays a pass out over for ``sensor``."""
        h, w = film_shape(sensor.film())
        return h * w

    @classmethod
    def of(cls, stats, sensor):
        """``stats`` where they are of ``sensor``'s view (:func:`sensor_view`), else new ones
        for it: the pixels' means a moved sensor, or another of the same film size, would
        weigh its visits by are another image's."""
        view = sensor_view(sensor)
        if stats is not None and stats.view == view:
            return stats
        return cls(cls.layout(sensor), view)

    def pixel(self, width: int, spp: int):
        """The pixel of each lane of a wavefront of ``width`` lanes at ``spp`` (or None); the
        width is the sampler's (``wavefront_size``): a sensor's rays may be narrower (a
        radiance meter's ray is one literal)."""
        if width != self.n * spp or spp < 1:
            return None
        return dr.arange(mi.UInt32, width) // dr.opaque(mi.UInt32, spp)

    def add(self, pixel, value):
        """A camera sample's estimate (luminance) for its ``pixel`` (in the kernel)."""
        dr.scatter_add(self.s1, value, pixel)
        dr.scatter_add(self.s2, value * value, pixel)

    def add_cost(self, pixel, cost):
        """Camera samples' costs for their ``pixel`` (in the kernel; counted by
        :meth:`passed`)."""
        dr.scatter_add(self.cost, cost, pixel)

    def passed(self, spp: int, costed: bool):
        """After a pass of ``spp`` that added to the statistics (and its costs, ``costed``)."""
        self.count += int(spp)
        if costed:
            self.cost_samples += int(spp) * self.n
        mean = host(self.s1) / max(self.count, 1)
        self.w = mi.Float((1.0 / relmse_denominator(mean)).astype(np.float32))

    def weights(self):
        return self.w

    def image(self):
        """(V, C): the image's mean relative variance per camera sample and the mean cost of a
        camera sample (None until both are measured)."""
        if self.count < 2 or self.cost_samples == 0:
            return None
        n = self.count
        s1 = host(self.s1)
        s2 = host(self.s2)
        mean = s1 / n
        var = np.maximum(s2 / n - mean * mean, 0.0) * n / (n - 1)
        rel = var / relmse_denominator(mean)
        ok = np.isfinite(rel)       # (a pixel that saw a NaN or an infinity says nothing)
        cost = host(self.cost)
        if not ok.any() or not np.isfinite(cost).all():
            return None
        v = float(np.mean(rel[ok]))
        c = float(cost.sum()) / self.cost_samples
        return (v, c) if v > 0 and c > 0 else None
