"""Renders on a Dask cluster (integrators.app.distributed, ``render --workers/--scheduler``).

* The plan: disjoint, contiguous seed ranges that cover the in-process render's passes.
* H0 "the same sums": a 2-worker LocalCluster render equals, bit for bit, its tasks rendered in
  this process and merged, and the in-process ``progressive.render`` with the same ``--seed``
  up to the order of float64 additions (relative 1e-12); exact checks, no false failures.
* A worker killed after the first pass of a task (test-only hook: ``os._exit`` on the first
  attempt) changes nothing: the task is retried with the same seed range; the merged sums
  equal those of the same render without the failure, bit for bit.
* The image statistically: 16 tasks of the distributed render against 16 in-process renders
  with other seeds, H0 "same expected image", the kit's block-wise Welch test
  (:func:`integrators.testing.image_test`, alpha = the kit's 1.5e-5, Sidak over the blocks).
* The command line: ``--time`` across workers, Ctrl-C (SIGINT to the whole process group, as
  a terminal sends it) stops the tasks and writes what they rendered, exit 130; a bad
  ``--scheduler`` address is one line and exit 2.

Renders are tiny (the machine has 2 cores); a LocalCluster takes a few seconds to start.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

import mitsuba as mi  # noqa: E402

import integrators  # noqa: E402,F401
from integrators.app import distributed as D  # noqa: E402
from integrators.app import progressive as P  # noqa: E402
from integrators.app.record import RunRecord  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "veach_mis.xml"
DEFINES = {"width": "32", "height": "18"}


def _scene_and_record():
    scene = mi.load_file(str(SCENE), **DEFINES)
    return scene, RunRecord.for_scene(SCENE, scene.integrator(), mi.variant(), DEFINES)


def _specs(cluster_slots, spp, seed, record):
    base = dict(scene=str(SCENE), scene_sha1=record.scene_sha1,
                defines=tuple(sorted(DEFINES.items())), variant=record.variant)
    return [D.TaskSpec(index=i, seed_first=f, seed_last=f + len(p) - 1, pass_spp=p, **base)
            for i, (f, p) in enumerate(D.plan_spp(32, 18, spp, seed, cluster_slots))]


def _in_process(specs, record):
    """The tasks rendered one after another in this process, merged as the client merges."""
    try:
        return D.merge_results([D.render_task(s) for s in specs], record)
    finally:
        D._SCENES.clear()          # keep no scene alive in the test process


@pytest.fixture(scope="module")
def cluster():
    c = D.Cluster(workers=2)
    yield c
    c.close()


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("w,h,spp,slots", [(32, 18, 64, 2), (32, 18, 100, 2), (32, 18, 5, 2),
                                           (32, 18, 1, 2),
                                           (4096, 4096, 100, 2), (64, 64, 1000, 64),
                                           (64, 64, 7, 1)])
def test_plan_covers_the_render_with_disjoint_seeds(w, h, spp, slots):
    plan = D.plan_spp(w, h, spp, 17, slots)
    passes = [n for _, p in plan for n in p]
    assert sum(passes) == spp and all(n >= 1 for n in passes)
    assert len(plan) == min(len(passes), 2 * slots)
    seeds = [f + k for f, p in plan for k in range(len(p))]
    assert seeds == list(range(17, 17 + len(passes)))          # contiguous, disjoint
    n, cap = P.pass_size(w, h, spp)
    assert max(passes) <= cap
    if slots <= 4 and spp >= 8:              # the in-process render's passes, exactly
        assert passes[:-1] == [n] * (len(passes) - 1)


def test_time_plan_blocks_are_disjoint():
    blocks = D.plan_time(5, 3)
    assert blocks[0][0] == 5 and all(a[1] + 1 == b[0] for a, b in zip(blocks, blocks[1:]))
    top = D.plan_time(D.MAX_SEED - 5, 3)
    assert top[-1][1] <= D.MAX_SEED and len(top) == 3
    with pytest.raises(ValueError, match="seed"):
        D.plan_time(D.MAX_SEED, 3)


# ---------------------------------------------------------------------------------------------
def test_two_workers_give_the_sums_of_one_process(cluster):
    scene, record = _scene_and_record()
    stats = {}
    acc = D.render(cluster, SCENE, record, (32, 18), spp=64, seed=3, stats=stats)
    assert cluster.slots == 2 and len(stats["tasks"]) == 4
    assert len({t["pid"] for t in stats["tasks"]}) >= 1
    rec = acc.run_record()
    assert rec.spp == 64 and rec.passes == 8 and rec.ranges() == [(3, 4), (5, 6), (7, 8), (9, 10)]
    # bit for bit: the same tasks rendered here and merged by the same code
    same = _in_process(_specs(2, 64, 3, record), record)
    assert np.array_equal(acc.s, same.s) and np.array_equal(acc.s2, same.s2)
    # the in-process render with the same seed: the same passes, float64 sums in another order
    one = P.render(scene, spp=64, seed=3)
    assert (one.seed_first, one.seed_last, one.passes) == (3, 10, 8)
    np.testing.assert_allclose(acc.s, one.s, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(acc.s2, one.s2, rtol=1e-12, atol=1e-300)
    assert record.merge_problem(rec) is None      # mergeable with other runs of the scene


def test_workers_times_threads_is_cores(cluster):
    """Each worker's Dr.Jit runs cores // workers threads (at least 1) once it has rendered."""
    scene, record = _scene_and_record()
    D.render(cluster, SCENE, record, (32, 18), spp=4, seed=900)
    want = max(1, D._cores() // 2)
    planned = cluster.client.run(lambda: D._THREADS)
    assert sorted(planned.values()) == [want, want]
    used = cluster.client.run(lambda: (D._THREADS_SET, __import__("drjit").thread_count()))
    assert all(u == (want, want) for u in used.values() if u[0] is not None)
    assert any(u[0] is not None for u in used.values())


def test_killed_worker_changes_nothing(tmp_path, cluster):
    """Task 1 of a fresh cluster's render dies (os._exit) after its first pass, on its first
    attempt only; Dask retries it with the same seed range on a live or restarted worker."""
    scene, record = _scene_and_record()
    mark = tmp_path / "killed"
    env = {"INTEGRATORS_TEST_KILL_TASK": "1", "INTEGRATORS_TEST_KILL_FILE": str(mark)}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        killer = D.Cluster(workers=2)       # its workers inherit the hook's variables
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    try:
        stats = {}
        acc = D.render(killer, SCENE, record, (32, 18), spp=64, seed=40, stats=stats)
    finally:
        killer.close()
    assert mark.exists(), "the hook did not kill a worker"
    dead = int(mark.read_text())
    task1 = [t for t in stats["tasks"] if t["index"] == 1]
    assert len(task1) == 1 and task1[0]["pid"] != dead     # retried in another process
    # the same render without a failure (the module's cluster has no hook)
    clean = D.render(cluster, SCENE, record, (32, 18), spp=64, seed=40)
    assert acc.run_record().ranges() == clean.run_record().ranges()
    assert np.array_equal(acc.s, clean.s) and np.array_equal(acc.s2, clean.s2)
    assert (acc.spp, acc.passes) == (clean.spp, clean.passes) == (64, 8)


def test_distributed_image_statistically_equals_in_process(cluster):
    """H0: the distributed render and in-process renders with other seeds have the same
    expected image (16 task images against 16 in-process batches, block-wise Welch)."""
    from integrators.testing import batch_images, image_test
    scene, record = _scene_and_record()

    class Wide:           # plan for 8 slots on the 2 workers: 16 tasks of one pass each
        client, slots = cluster.client, 8
    stats = {}
    acc = D.render(Wide, SCENE, record, (32, 18), spp=256, seed=0, stats=stats)
    assert len(stats["results"]) == 16 and acc.spp == 256
    a = np.array([r["s"] / r["spp"] for r in sorted(stats["results"],
                                                    key=lambda r: r["seed_first"])])
    b = batch_images(scene, scene.integrator(), batches=16, spp=16, seed0=500_000)
    r = image_test(a, b, block=4)
    assert r.passed, r


def test_time_budget_across_workers(cluster):
    scene, record = _scene_and_record()
    stats = {}
    t0 = time.perf_counter()
    acc = D.render(cluster, SCENE, record, (32, 18), time_budget=1.5, seed=7, stats=stats)
    wall = time.perf_counter() - t0
    assert len(stats["tasks"]) == 2 and all(t["spp"] > 0 for t in stats["tasks"])
    # the deadline is 1.5 s after submission plus each task's own scene load: a task renders
    # until then (so from its start, delayed by the scheduling, at least 1.5 s minus that
    # delay) and ends with the pass in flight
    for t in stats["tasks"]:
        assert t["seconds"] + t["start_s"] >= 1.5 - 0.05 and t["seconds"] < 1.5 + 10, t
    assert wall < 1.5 + 20
    blocks = D.plan_time(7, 2)
    for (f, l), (bf, bl) in zip(acc.run_record().ranges(), blocks):
        assert f == bf and l <= bl


# ---------------------------------------------------------------------------------------------
def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "integrators", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=300, **kw)


@pytest.mark.parametrize("args,says", [
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler 'tcp://127.0.0.1:1': cannot connect"),
    (["--scheduler", "nonsense"], "--scheduler 'nonsense' is not a Dask scheduler address"),
    (["--scheduler", "http://example:80"], "is not a Dask scheduler address (unknown scheme"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "give one of them"),
    (["--workers", "0"], "--workers = 0 must be a positive integer"),
    (["--workers", "2", "--checkpoint", "5"], "--checkpoint cannot be combined"),
])
def test_bad_cluster_options_are_one_line(tmp_path, args, says):
    r = _cli("render", str(SCENE), "-o", str(tmp_path / "x.exr"), *args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], r.stderr
    assert not (tmp_path / "x.exr").exists()


def test_cli_on_an_existing_scheduler(tmp_path, cluster):
    """``--scheduler ADDRESS``: the command uses the running cluster (the module's LocalCluster
    here) and leaves it running; the output equals the same render in this process (sums to
    float64 order; the file holds float32)."""
    out = tmp_path / "s.exr"
    address = cluster.cluster.scheduler_address
    r = _cli("render", str(SCENE), "-D", "width=32", "-D", "height=18", "--spp", "32",
             "--seed", "77", "--scheduler", address, "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert f"Dask cluster {address}" in r.stdout and r.stderr.strip() == ""
    got = P.read(out)
    assert got.run_record().ranges() == [(77, 78), (79, 80), (81, 82), (83, 84)]
    scene, _ = _scene_and_record()
    want = P.render(scene, spp=32, seed=77)
    np.testing.assert_allclose(got.mean(), want.mean().astype(np.float32), rtol=1e-6, atol=1e-7)
    assert cluster.client.status == "running"          # the cluster is still there


def test_cli_time_budget_on_two_workers(tmp_path):
    out = tmp_path / "t.exr"
    r = _cli("render", str(SCENE), "-D", "width=32", "-D", "height=18", "--time", "2",
             "--workers", "2", "--seed", "100", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "2 Dask workers" in r.stdout and out.exists() and out.with_suffix(".png").exists()
    rec = P.read(out).run_record()
    assert len(rec.ranges()) == 2 and rec.ranges()[0][0] == 100
    assert rec.spp > 0 and 2 <= rec.seconds < 30


def test_cli_ctrl_c_stops_the_tasks_and_writes_what_they_rendered(tmp_path):
    """SIGINT to the process group (workers included, as a terminal's Ctrl-C) once a task has
    finished a pass: the tasks stop after their pass in flight, the merge is written, 130."""
    out, mark = tmp_path / "c.exr", tmp_path / "marks"
    env = {**os.environ, "INTEGRATORS_TEST_PAUSE_AT": "pass",
           "INTEGRATORS_TEST_PAUSE_FILE": str(mark)}
    p = subprocess.Popen([sys.executable, "-m", "integrators", "render", str(SCENE), "-D",
                          "width=32", "-D", "height=18", "--spp", "100000", "--workers", "2",
                          "-o", str(out)], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        t0 = time.monotonic()
        while not (mark.exists() and mark.read_text().count("pass") >= 2):
            assert p.poll() is None, p.communicate()
            assert time.monotonic() - t0 < 120, "no pass finished"
            time.sleep(0.1)
        time.sleep(0.5)                       # let the client hear of the pass
        os.killpg(p.pid, signal.SIGINT)
        stdout, stderr = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130, stderr
    assert "SIGINT: stopping the tasks after their pass in flight" in stderr
    assert "Traceback" not in stderr and "stopped by SIGINT" in stdout
    rec = P.read(out).run_record()
    assert 0 < rec.spp < 100000 and rec.passes >= 1
    plan = D.plan_spp(32, 18, 100000, 0, 2)
    for f, l in rec.ranges():             # each range a prefix of a planned task's seeds
        assert any(f == pf and l <= pf + len(pp) - 1 for pf, pp in plan), (f, l)


# ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_experiments_on_two_workers_match_a_sequential_run(tmp_path):
    """``python -m benchmarks run --workers 2``: references, then scenes, as Dask tasks; every
    error of every point equals the sequential run's, with the same reference keys.  Equal to
    float32 rounding, not bit for bit: Mitsuba's film adds the splats of a Gaussian filter with
    parallel atomic adds, so two sequential runs with 2 Dr.Jit threads already differ in the
    last bits (bit-identical with 1 thread, as each Dask worker has here)."""
    import json

    def bench(out, *extra):
        r = subprocess.run([sys.executable, "-m", "benchmarks", "run", "--quick", "--scenes",
                            "furnace", "cornell_box", "--methods", "bsdf_path", "--out",
                            str(out), "--cache", str(out / "cache"), *extra], cwd=ROOT,
                           capture_output=True, text=True, timeout=1200)
        assert r.returncode == 0, r.stderr[-3000:]
        return json.loads((out / "summary.json").read_text())
    seq = bench(tmp_path / "seq")
    dist = bench(tmp_path / "dist", "--workers", "2")
    assert dist["meta"]["cluster"]["slots"] == 2 and seq["meta"]["cluster"] is None
    assert set(seq["scenes"]) == set(dist["scenes"]) == {"furnace", "cornell_box"}
    for sc, a in seq["scenes"].items():
        b = dist["scenes"][sc]
        assert {g: r["key"] for g, r in a["reference"].items()} == \
            {g: r["key"] for g, r in b["reference"].items()}
        for label, m in a["methods"].items():
            for p, q in zip(m["points"], b["methods"][label]["points"]):
                assert p["spp"] == q["spp"]
                for k in ("rmse", "relmse", "flip", "de2000"):
                    assert q[k] == pytest.approx(p[k], rel=1e-4), (sc, label, p["spp"], k)
