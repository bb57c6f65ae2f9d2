"""Benchmarks and experiments of the integrators against Mitsuba's built-ins.

Entry point ``python -m benchmarks run|speed|efficiency|memory`` (:mod:`benchmarks.__main__`).
Modules, one concern each:

* :mod:`benchmarks.config` - scenes, methods, groups, settings, paths (no Mitsuba import);
* :mod:`benchmarks.provenance` - the command that ran, git state, machine;
* :mod:`benchmarks.timing` - the one timing core (warm-up, round-robin rounds, perf_counter
  around render + ``dr.eval`` + ``dr.sync_thread``, median/min/max);
* :mod:`benchmarks.metrics` - relMSE, RMSE, FLIP, CIEDE2000 (colour-science), sRGB previews;
* :mod:`benchmarks.references` - references by Mitsuba's own ``path``, cached under the run
  record's key (:class:`integrators.app.record.RunRecord`); closed-form checks;
* :mod:`benchmarks.experiment` - one scene of the experiments (a worker process);
* :mod:`benchmarks.plots` - charts and equal-time image grids;
* :mod:`benchmarks.report` - ``report.md`` from ``summary.json``;
* :mod:`benchmarks.run` - the experiments' command line (``python -m benchmarks run``);
* :mod:`benchmarks.speed`, :mod:`benchmarks.efficiency`, :mod:`benchmarks.memory` - the
  single-purpose benchmarks;
* :mod:`benchmarks.distributed` - ``render --workers 2`` against in-process, the per-task
  overheads of a Dask cluster and a model of 8 to 512 workers.
"""
