r"""Renders on a Dask cluster against in-process: samples per second, per-task overheads, a model.

    python -m benchmarks.distributed [--scene veach_mis] [--seconds 35] [--repeats 3]
                                     [--workers 2] [--out benchmarks/results/distributed]

**What is compared** (side by side, in one process, order alternated every repeat): the same
render, ``spp`` samples per pixel with the same seeds, (a) in-process (``progressive.render``,
Dr.Jit with every core) and (b) on a fresh ``LocalCluster`` of ``--workers`` processes
(``integrators.app.distributed.render``: 2 x workers tasks, Dr.Jit threads = cores / workers),
exactly what ``render --workers N`` does.  ``spp`` is calibrated so that the in-process render
takes about ``--seconds`` (at least 30 s).  Samples per second:

* ``render``: samples / seconds from the call to the merged result; in-process this includes
  the kernel compilation of the first pass, distributed also the scene load on each worker,
  the compilation there, scheduling, the transfer of the sums and the merge;
* ``command``: distributed also counts starting the LocalCluster and closing it (what a
  ``render --workers N`` command pays; an existing cluster given by ``--scheduler`` does not).

**Overheads measured**: cluster start and close; per worker the scene load (file read,
``mi.load_file``) and the kernel compilation (first pass minus the median later pass);
per task the scheduling delay (submit to start, for tasks that did not wait for a free
worker), the transfer of its sums to the client (a separate micro-benchmark: tasks returning
arrays of the same size, minus an empty task) and the merge on the client.  From these the
report models how a render's time splits at 8, 64 and 512 workers.

Outputs: ``distributed.json`` and ``distributed.md`` in ``--out``, written atomically.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import statistics
import sys
import time
from pathlib import Path

from . import provenance
from .config import REPO, scene_file

PROG = "python -m benchmarks.distributed"
DEFAULT_OUT = REPO / "benchmarks" / "results" / "distributed"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="veach_mis", help="scene name in scenes/ (default "
                    "%(default)s, its own resolution)")
    ap.add_argument("--seconds", type=float, default=35.0,
                    help="length of the in-process render (default %(default)s; the target "
                         "is stated for >= 30)")
    ap.add_argument("--repeats", type=int, default=3, help="pairs of renders (default 3)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output folder")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite distributed.md from OUT/distributed.json, render nothing")
    a = ap.parse_args(argv)
    if a.repeats < 1 or a.workers < 1 or a.seconds <= 0:
        ap.error("--repeats, --workers and --seconds must be positive")
    return a


def _cpu(pids) -> float:
    """User + system CPU seconds of the processes ``pids`` (threads included)."""
    import psutil
    total = 0.0
    for pid in pids:
        try:
            t = psutil.Process(pid).cpu_times()
            total += t.user + t.system
        except psutil.Error:
            pass
    return total


def _median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def transfer_costs(cluster, shape, repeats=7) -> dict:
    """Seconds per task to bring a task's sums (two float64 arrays of ``shape``) to the client:
    round trips of tasks returning arrays of that size minus those returning nothing."""
    import numpy as np

    def arrays(n, shape=shape):
        return {"s": np.full(shape, float(n)), "s2": np.full(shape, float(n))} if n else {}

    client = cluster.client
    times = {"empty": [], "sums": []}
    for i in range(repeats):
        for kind in ("empty", "sums"):
            t0 = time.perf_counter()
            f = client.submit(arrays, (i + 1) if kind == "sums" else 0, pure=False)
            r = f.result()
            times[kind].append(time.perf_counter() - t0)
            del r, f
    nbytes = 2 * int(np.prod(shape)) * 8
    e, s = _median(times["empty"]), _median(times["sums"])
    return {"bytes": nbytes, "empty_task_s": e, "sums_task_s": s,
            "transfer_s": max(s - e, 0.0), "mb_per_s": nbytes / 1e6 / max(s - e, 1e-9)}


def merge_cost(shape, tasks=8) -> float:
    """Seconds per task of :func:`distributed.merge_results` for sums of ``shape``."""
    import numpy as np

    from integrators.app import distributed
    from integrators.app.record import RunRecord
    results = [{"s": np.random.rand(*shape), "s2": np.random.rand(*shape), "spp": 4,
                "passes": 2, "seed_first": 2 * i, "seed_last": 2 * i + 1, "seconds": 1.0,
                "channels": ("R", "G", "B")} for i in range(tasks)]
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        distributed.merge_results(results, RunRecord(scene_sha1="x"))
        best = min(best, time.perf_counter() - t0)
    return best / tasks


_WROTE = re.compile(r"wrote .*\((\d+)x(\d+), (\d+) spp in (\d+) passes, ([0-9.]+) s, "
                    r"([0-9.]+) M samples/s")


def command(scene_path, spp, seed, out, workers=None) -> dict:
    """One ``python -m integrators render`` in a fresh process: its own report of the render
    (seconds and samples/s from the first pass to the written sums), the wall time of the
    whole command and the CPU seconds of it and its children (the LocalCluster's workers)."""
    cmd = [sys.executable, "-m", "integrators", "render", str(scene_path), "--spp", str(spp),
           "--seed", str(seed), "--quiet", "-o", str(out)]
    if workers:
        cmd += ["--workers", str(workers)]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True,
                       env=provenance.subprocess_env())
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    m = _WROTE.search(r.stdout)
    if not m:
        raise SystemExit(f"no 'wrote' line from {' '.join(cmd)}: {r.stdout[-300:]}")
    w, h, n, passes, secs, rate = m.groups()
    samples = int(w) * int(h) * int(n)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"render_s": float(secs), "samples_per_s": samples / float(secs),
            "command_s": wall, "command_samples_per_s": samples / wall, "cpu_s": cpu,
            "samples_per_cpu_s": samples / cpu, "passes": int(passes), "spp": int(n),
            "load_average_after": os.getloadavg()[0]}


def overheads(path, record, film, spp, workers) -> dict:
    """One render through the API on a fresh LocalCluster: the per-task overheads."""
    from integrators.app import distributed
    t0 = time.perf_counter()
    cluster = distributed.Cluster(workers=workers)
    stats = {}
    try:
        acc = distributed.render(cluster, path, record, film, spp=spp, seed=7, stats=stats)
        transfer = transfer_costs(cluster, acc.s.shape)
    finally:
        t_close = time.perf_counter()
        cluster.close()
    close_s = time.perf_counter() - t_close
    tasks = stats["tasks"]
    first = {}
    for t in sorted(tasks, key=lambda t: t["start_s"]):
        first.setdefault(t["pid"], t)
    return {"cluster_start_s": cluster.started_s, "cluster_close_s": close_s,
            "wall_s": stats["wall_s"], "tasks": len(tasks), "slots": stats["slots"],
            "load_s": [t["load_s"] for t in first.values()],
            "compile_s": [t["pass_s"][0] - _median(t["pass_s"][1:])
                          for t in first.values() if len(t["pass_s"]) > 1],
            "start_delay_s": [t["start_s"] for t in first.values()],
            "transfer_s_in_run": [t["transfer_s"] for t in tasks],
            "task_bytes": tasks[0]["bytes"], "merge_s": stats["merge_s"],
            "task_seconds": [t["seconds"] for t in tasks], "spp": spp,
            "transfer": transfer, "total_s": time.perf_counter() - t0}


def run(args) -> dict:
    import tempfile

    import mitsuba as mi

    import integrators  # noqa: F401
    from integrators.app import progressive
    from integrators.app.record import RunRecord
    path = scene_file(args.scene)
    scene = mi.load_file(str(path))
    record = RunRecord.for_scene(path, scene.integrator(), mi.variant(), {})
    w, h = progressive.film_size(scene)
    print(f"calibrating {args.scene} ({w}x{h}) ...", flush=True)
    progressive.render(scene, spp=8, seed=0)                      # compile
    t0 = time.perf_counter()
    probe = progressive.render(scene, spp=64, seed=100)
    rate = probe.spp * w * h / (time.perf_counter() - t0)
    del scene, probe
    seconds = args.seconds
    if seconds < 30:
        print(f"warning: --seconds {seconds:g}: the target is stated for renders of 30 s or "
              "more", file=sys.stderr)
    spp = max(16, int(round(rate * seconds / (w * h) / 16)) * 16)
    print(f"{rate / 1e6:.2f} M samples/s in-process: {spp} spp for about {seconds:.0f} s",
          flush=True)
    rounds = []
    with tempfile.TemporaryDirectory(prefix="bench-dist-") as tmp:
        for r in range(args.repeats):
            row = {}
            order = ("in_process", "distributed") if r % 2 == 0 else ("distributed",
                                                                       "in_process")
            for kind in order:
                seed = 1000 + r * 100_000
                row[kind] = command(path, spp, seed, Path(tmp) / f"{kind}.exr",
                                    args.workers if kind == "distributed" else None)
                x = row[kind]
                print(f"round {r + 1} {kind}: {x['samples_per_s'] / 1e6:.2f} M samples/s "
                      f"({x['render_s']:.1f} s render, {x['command_s']:.1f} s command, "
                      f"{x['cpu_s']:.1f} CPU s, load {x['load_average_after']:.1f})",
                      flush=True)
            a, b = row["in_process"], row["distributed"]
            row["ratio_render"] = b["samples_per_s"] / a["samples_per_s"]
            row["ratio_command"] = b["command_samples_per_s"] / a["command_samples_per_s"]
            row["ratio_cpu"] = b["samples_per_cpu_s"] / a["samples_per_cpu_s"]
            print(f"round {r + 1}: distributed / in-process = {row['ratio_render']:.3f} "
                  f"(render), {row['ratio_command']:.3f} (command), {row['ratio_cpu']:.3f} "
                  "(per CPU second)", flush=True)
            rounds.append(row)
    print("per-task overheads (one render through the API) ...", flush=True)
    over = overheads(path, record, (w, h), max(16, spp // 4 // 16 * 16), args.workers)
    return {"scene": args.scene, "film": [w, h], "spp": spp, "workers": args.workers,
            "seconds": seconds, "in_process_rate_probe": rate, "rounds": rounds,
            "overheads": over, "merge_s_per_task": merge_cost((h, w, 3)),
            "transfer": over["transfer"]}


def model(res) -> dict:
    """Time split of a render at 8, 64 and 512 workers from the measured overheads (see the
    written model in :func:`markdown`)."""
    o = res["overheads"]
    # samples/s of one worker on one core
    per_core = o["spp"] * res["film"][0] * res["film"][1] / sum(o["task_seconds"])
    load = _median(o["load_s"])
    comp = max(_median(o["compile_s"]) or 0.0, 0.0)
    sched = _median(o["start_delay_s"])
    tr = res["transfer"]["transfer_s"]
    merge = res["merge_s_per_task"]
    samples = res["spp"] * res["film"][0] * res["film"][1]
    out = {"per_core_samples_per_s": per_core, "load_s": load, "compile_s": comp,
           "schedule_s": sched, "transfer_s_per_task": tr, "merge_s_per_task": merge,
           "rows": []}
    for W in (8, 64, 512):
        tasks = 2 * W
        for label, work in (("this render", samples), ("30 s per worker", per_core * 30 * W)):
            compute = work / (W * per_core)
            client = tasks * (tr + merge)          # serial at the client
            total = sched + load + comp + compute + client
            out["rows"].append({"workers": W, "case": label, "compute_s": compute,
                                "fixed_s": sched + load + comp, "client_s": client,
                                "total_s": total, "efficiency": compute / total})
    return out


def markdown(res, command, machine, date) -> str:
    rounds = res["rounds"]
    rr = [r["ratio_render"] for r in rounds]
    rc = [r["ratio_command"] for r in rounds]
    o = res["overheads"]
    m = res["model"]
    tr = res["transfer"]
    L = ["# Distributed renders: `--workers 2` against in-process", "",
         f"Generated by `{command}` on {date} ({machine['cpu_model']}, "
         f"{machine['cpu_count']} CPUs; the machine was shared with other work: ratios are "
         "taken side by side, order alternated every round).", "",
         f"Scene `{res['scene']}` ({res['film'][0]}x{res['film'][1]}), {res['spp']} spp "
         f"(calibrated to about {res['seconds']:.0f} s in-process), {res['workers']} workers, "
         f"{2 * res['workers']} tasks.  Each round runs both commands in fresh processes, "
         "`python -m integrators render SCENE --spp N` and the same with "
         f"`--workers {res['workers']}`: the render columns are each command's own report "
         "(samples over the seconds from the first pass, compilation included, to the "
         "merged sums; distributed: from submitting the tasks, so each worker's scene load "
         "and compilation, the transfers and the merge are in it), the command ratio is over "
         "the wall time of the whole commands (imports, scene load, LocalCluster start and "
         "close), the CPU ratio over the CPU seconds of each command and its children.", "",
         "| round | in-process M samples/s (render s, command s) | distributed M samples/s "
         "(render s, command s) | **render ratio** | command ratio | "
         "samples per CPU second ratio | load average after (in-process, distributed) |",
         "|---|---:|---:|---:|---:|---:|---|"]
    for i, r in enumerate(rounds):
        a, b = r["in_process"], r["distributed"]
        L.append(f"| {i + 1} | {a['samples_per_s'] / 1e6:.2f} ({a['render_s']:.1f}, "
                 f"{a['command_s']:.1f}) | "
                 f"{b['samples_per_s'] / 1e6:.2f} ({b['render_s']:.1f}, {b['command_s']:.1f}) | "
                 f"**{r['ratio_render']:.3f}** | {r['ratio_command']:.3f} | "
                 f"{r['ratio_cpu']:.3f} | {a['load_average_after']:.1f}, "
                 f"{b['load_average_after']:.1f} |")
    rcpu = [r["ratio_cpu"] for r in rounds]
    L += ["", f"Median ratio: **{statistics.median(rr):.3f}** for the render "
          f"(range {min(rr):.3f}-{max(rr):.3f}), {statistics.median(rc):.3f} for the whole "
          f"command (target: at least 0.9 for renders of 30 s or more); samples per CPU "
          f"second (client and worker processes, all threads) {statistics.median(rcpu):.3f} "
          f"(range {min(rcpu):.3f}-{max(rcpu):.3f}): the overhead in work, which the other "
          "load on a shared machine does not change.", "",
          "## Overheads measured", "",
          f"From one more render through the API ({o['spp']} spp, {o['tasks']} tasks of "
          f"{statistics.mean(o['task_seconds']):.1f} s on average):", "",
          "| what | seconds |", "|---|---:|",
          f"| LocalCluster start ({res['workers']} processes, imports in the workers) | "
          f"{o['cluster_start_s']:.2f} |",
          f"| LocalCluster close | {o['cluster_close_s']:.2f} |",
          f"| scene load per worker (file, `mi.load_file`) | {m['load_s']:.3f} |",
          f"| kernel compilation per worker (first pass minus median later pass) | "
          f"{m['compile_s']:.3f} |",
          f"| scheduling: submit to task start (free worker) | {m['schedule_s']:.3f} |",
          f"| transfer of one task's sums ({tr['bytes'] / 1e6:.1f} MB; round trip minus an "
          f"empty task's {tr['empty_task_s'] * 1e3:.1f} ms) | {tr['transfer_s']:.3f} "
          f"({tr['mb_per_s']:.0f} MB/s) |",
          f"| merge of one task's sums on the client | {m['merge_s_per_task']:.4f} |",
          "", "## Model: how the time splits at 8, 64 and 512 workers", "",
          "Each worker renders its tasks at the measured single-core rate "
          f"({m['per_core_samples_per_s'] / 1e6:.2f} M samples/s); per render every worker pays "
          "the scene load and the kernel compilation once, in parallel, after the scheduling "
          "delay; the client then receives and merges 2 x workers task sums one after another "
          "(the serial part).  Cluster start is left out (an existing cluster, "
          "`--scheduler`); on a real cluster the scene file must also reach every worker "
          "(a shared file system) and the transfer runs over the network, not loopback, so "
          "the client column grows with the network's bandwidth.", "",
          "| workers | work | compute (s) | fixed: schedule + load + compile (s) | "
          "client: receive + merge (s) | total (s) | compute share |",
          "|---:|---|---:|---:|---:|---:|---:|"]
    for row in m["rows"]:
        L.append(f"| {row['workers']} | {row['case']} | {row['compute_s']:.2f} | "
                 f"{row['fixed_s']:.2f} | {row['client_s']:.2f} | {row['total_s']:.2f} | "
                 f"{100 * row['efficiency']:.0f} % |")
    rows = {(r["workers"], r["case"]): r for r in m["rows"]}
    core_s = res["spp"] * res["film"][0] * res["film"][1] / m["per_core_samples_per_s"]
    per_task = m["transfer_s_per_task"] + m["merge_s_per_task"]
    L += ["", f"Reading the model: this render ({core_s:.0f} core-seconds) stops scaling "
          f"between 8 and 64 workers: at 64 its compute is {rows[(64, 'this render')]['compute_s']:.1f} s "
          f"against {rows[(64, 'this render')]['client_s']:.1f} s for the client to receive and "
          f"merge 128 task sums ({1e3 * per_task:.0f} ms each, serial).  A render that gives "
          f"every worker 30 s of work keeps "
          f"{100 * rows[(64, '30 s per worker')]['efficiency']:.0f} % of its time in compute at "
          f"64 workers and {100 * rows[(512, '30 s per worker')]['efficiency']:.0f} % at 512, "
          "where the client's serial receive-and-merge of 1024 sums is the largest part; the "
          "per-worker fixed costs (scheduling, scene load, compilation: "
          f"{rows[(8, 'this render')]['fixed_s']:.2f} s) are paid in parallel and do not grow.  "
          "Remedies, not implemented: merge on the workers in a tree (log2 depth; the client "
          "receives one sum), one task per worker for large films, float32 sums on the wire.",
          ""]
    return "\n".join(L)


def main(argv=None):
    args = parse_args(argv)
    from integrators.app.imageio import write_text
    out = Path(args.out)
    if args.report_only:
        res = json.loads((out / "distributed.json").read_text())
        res["model"] = model(res)
        write_text(out / "distributed.md", markdown(res, res["meta"]["command"],
                                                    res["meta"]["machine"],
                                                    res["meta"]["date_utc"]) + "\n")
        print(f"wrote {out / 'distributed.md'}")
        return 0
    command = provenance.command(PROG, argv)
    machine = provenance.machine()
    res = run(args)
    res["model"] = model(res)
    res["meta"] = {"command": command, "date_utc": provenance.now_utc(), "machine": machine,
                   "git": provenance.git_state()}
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "distributed.json", json.dumps(res, indent=2, default=str) + "\n")
    write_text(out / "distributed.md", markdown(res, command, machine,
                                                res["meta"]["date_utc"]) + "\n")
    print(f"wrote {out / 'distributed.json'} and {out / 'distributed.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
