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

from ..common import is_jit


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
        return np.array(self.stats, dtype=np.float64).reshape(self.size, self.stats_per_cell)

    def set_table(self, table: np.ndarray):
        """Decisions for the next pass (one value per cell)."""
        self._table = np.asarray(table, dtype=np.float32)
        self.decisions = mi.Float(self._table) if is_jit() else self._table.copy()

    def table(self) -> np.ndarray:
        return self._table.copy()
