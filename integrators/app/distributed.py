r"""Renders spread over a Dask cluster (``render SCENE --workers N`` or ``--scheduler ADDRESS``).

A render is split into **tasks**, each a disjoint range of seeds (one seed per pass, as in
:mod:`integrators.app.progressive`).  A task loads the scene on its worker (once per worker
process: the loaded scene is kept for the next task), renders its passes, adds them into an
:class:`~integrators.app.progressive.Accumulator` and returns the sums ``S``, ``S2`` with its
counts.  The client merges the tasks' accumulators in seed order with
:meth:`Accumulator.merge` and :meth:`RunRecord.merge_problem`, the code of ``merge``, so the run
record lists every task's seed range.

**The plan** (:func:`plan_spp`, :func:`plan_time`):

* ``--spp S``: the passes of the in-process render (``progressive.pass_size``: about 8 passes
  of ``ceil(S / 8)`` samples per pixel, at most 2^24 samples each), or, when the cluster has
  more than 4 task slots, ``2 x slots`` smaller passes; consecutive passes are grouped into
  ``min(passes, 2 x slots)`` tasks.  Up to 4 slots the seeds and pass sizes are exactly those
  of the in-process render with the same ``--seed``, so the merged sums equal its sums up to
  the order of float64 additions (tested), and tasks rendered in one process and merged give
  the same sums bit for bit.
* ``--time T``: one task per slot, each with its own block of seeds (``seed + i B`` to
  ``seed + (i + 1) B - 1``, ``B`` = 2^20 passes or what the 32-bit seeds leave), rendering
  passes sized as in-process (about 0.25 s) until a wall-clock deadline, ``T`` seconds after
  the client submitted the tasks plus the task's own scene-load time (in-process, ``--time``
  also counts from the first pass, after the scene load), or until the end of its block; it
  ends with the pass in flight.  A task retried after its worker died renders only what is
  left.  (Clocks of the client and remote workers must agree to within the accuracy wanted.)

**Workers**: ``--workers N`` starts a ``LocalCluster(n_workers=N, threads_per_worker=1,
processes=True)`` (no dashboard; Dask's profiler off and its monitors slowed down:
:data:`LOCAL_CONFIG`); ``--scheduler ADDRESS`` connects to an existing scheduler (the scene files
must be at the same absolute paths on its workers: a task checks the SHA-1 of the file it
loads against the client's and fails with one line otherwise).  Every worker runs Dr.Jit with
``cores // task slots on its host`` threads (``dr.set_thread_count``), so workers x threads =
cores, and ignores SIGINT (a Ctrl-C at the terminal reaches the whole process group: only the
client acts on it).

**Failures**: a task whose worker dies (killed, out of memory) is rescheduled by Dask with the
same arguments, hence the same seed range, so the image is identical to a run without the
failure (Dask gives up after ``distributed.scheduler.allowed-failures`` deaths, 3 by default).
An exception inside a task (a scene the worker cannot load) ends the render with that error.

**Progress and interruption**: each pass a task publishes its count as a Dask event (topic
per render); the client shows one progress bar over the cluster.  The first SIGINT/SIGTERM
(:mod:`integrators.app.interrupt`) sets a Dask ``Event``: running tasks stop after their pass
in flight and return what they rendered, tasks not yet started return nothing, and the client
writes the merge; a second signal abandons the tasks in flight (cancelled) and writes the tasks
that had finished.

Test-only hook (environment variables inherited by LocalCluster workers; nothing else reads
them): ``INTEGRATORS_TEST_KILL_TASK=i`` with ``INTEGRATORS_TEST_KILL_FILE=PATH``: after the
first pass of task ``i`` the worker process ends at once (``os._exit``) unless ``PATH`` exists,
which it creates first, so only the first attempt of that task dies.
"""
from __future__ import annotations

import contextlib
import math
import os
import signal
import threading
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np
from distributed.diagnostics.plugin import WorkerPlugin

#: seconds to wait for a scheduler given with ``--scheduler``
CONNECT_TIMEOUT = 10.0
#: passes in a time-budget task's seed block (2^20 passes of 0.25 s: 73 hours)
TIME_BLOCK = 1 << 20
MAX_SEED = (1 << 32) - 1
#: Dask configuration of a LocalCluster (its scheduler and nannies live in this process; the
#: workers inherit it through the nannies): Dask's periodic housekeeping, harmless on an idle
#: core, took about 30 % extra CPU next to a render on a busy 2-core machine (measured: each
#: worker's event loop 15 % of its render thread, the client process as much again), mostly
#: the statistical profiler (100 stack samples a second), the event-loop health tick (every
#: 20 ms) and the system and memory monitors; slowed down here, none of them is used
LOCAL_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.admin.system-monitor.disk": False,
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.deploy.cluster-repr-interval": "10s",
}


class ClusterError(ValueError):
    """The cluster cannot be started or reached (one line)."""


# =============================================================================================
# the plan
@dataclass(frozen=True)
class TaskSpec:
    """One task: what to load and which seeds to render."""
    index: int
    scene: str                   # absolute path of the scene file
    scene_sha1: str
    defines: tuple               # sorted (name, value) pairs
    variant: str
    seed_first: int
    seed_last: int               # last seed of the task (time mode: of its block)
    pass_spp: tuple = ()         # spp of each pass (spp mode); () in time mode
    time_budget: float | None = None
    deadline: float | None = None   # time.time() by which a time-mode task ends (after load)
    stop_event: str = ""         # name of the Dask Event that stops the render
    topic: str = ""              # Dask event topic of the progress messages
    sensor: int = 0

    @property
    def spp(self) -> int:
        return int(sum(self.pass_spp))


def pass_plan(w: int, h: int, spp: int, slots: int) -> list:
    """Samples per pixel of each pass of a ``spp`` render on ``slots`` task slots: those of the
    in-process render (:func:`progressive.pass_size`) when they give at least ``2 x slots``
    passes (or one per sample), else smaller passes."""
    from .progressive import pass_size
    n, cap = pass_size(w, h, spp)
    if math.ceil(spp / n) < 2 * slots:
        n = max(1, min(cap, math.ceil(spp / (2 * slots))))
    count = math.ceil(spp / n)
    return [n] * (count - 1) + [spp - n * (count - 1)]


def plan_spp(w: int, h: int, spp: int, seed: int, slots: int) -> list:
    """[(seed_first, (pass spp, ...)), ...]: consecutive passes grouped into ``min(passes,
    2 x slots)`` tasks of nearly equal pass counts, seeds consecutive from ``seed``."""
    passes = pass_plan(w, h, spp, slots)
    tasks = min(len(passes), 2 * max(1, slots))
    out, at = [], 0
    for t in range(tasks):
        k = len(passes) // tasks + (1 if t < len(passes) % tasks else 0)
        out.append((seed + at, tuple(passes[at:at + k])))
        at += k
    return out


def plan_time(seed: int, slots: int) -> list:
    """[(first, last), ...]: one block of seeds per slot (see the module docstring)."""
    block = min(TIME_BLOCK, (MAX_SEED - seed + 1) // max(1, slots))
    if block < 1:
        raise ValueError(f"seed {seed} leaves fewer seeds than the {slots} task slots need; "
                         f"use a seed <= {MAX_SEED - slots + 1}")
    return [(seed + i * block, seed + (i + 1) * block - 1) for i in range(slots)]


# =============================================================================================
# worker side
_SCENES: dict = {}
_THREADS: int | None = None       # Dr.Jit threads of this worker (set by _WorkerSetup)
_THREADS_SET: int | None = None


def _worker_setup(threads_by_host: dict, address: str) -> None:
    """Runs on every worker (also restarted ones): ignore SIGINT, choose Dr.Jit's threads."""
    global _THREADS
    if threading.current_thread() is threading.main_thread():
        with contextlib.suppress(ValueError, OSError):
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    from distributed.comm import get_address_host
    slots = threads_by_host.get(get_address_host(address)) or 1
    _THREADS = max(1, _cores() // int(slots))


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _load(spec: TaskSpec):
    """(scene, seconds spent loading: 0 when this process has it already)."""
    global _THREADS_SET
    key = (spec.scene, spec.scene_sha1, spec.defines, spec.variant)
    if key in _SCENES:
        return _SCENES[key], 0.0
    t0 = time.perf_counter()
    import mitsuba as mi

    import integrators
    from .record import file_sha1
    if _THREADS is not None and _THREADS != _THREADS_SET:
        import drjit as dr
        dr.set_thread_count(_THREADS)
        _THREADS_SET = _THREADS
    if mi.variant() != spec.variant:
        integrators.set_variant(spec.variant)
    try:
        sha1 = file_sha1(spec.scene)
    except OSError as e:
        raise RuntimeError(f"{spec.scene}: cannot read the scene file on worker {_where()}: "
                           f"{e.strerror or e}; workers need the scene at the same path") from None
    if sha1 != spec.scene_sha1:
        raise RuntimeError(f"{spec.scene}: the scene file on worker {_where()} differs from the "
                           f"client's (sha1 {sha1[:12]}, client {spec.scene_sha1[:12]})")
    scene = mi.load_file(spec.scene, **dict(spec.defines))
    _SCENES.clear()          # one scene per process: every BSDF alive is compiled into kernels
    _SCENES[key] = scene
    return scene, time.perf_counter() - t0


def _where() -> str:
    with contextlib.suppress(Exception):
        from distributed import get_worker
        return get_worker().address
    return f"pid {os.getpid()}"


def _publish(spec: TaskSpec, msg: dict) -> None:
    if not spec.topic:
        return
    with contextlib.suppress(Exception):
        from distributed import get_worker
        get_worker().log_event(spec.topic, msg)


def _stop_requested(spec: TaskSpec) -> bool:
    if not spec.stop_event:
        return False
    try:
        from distributed import Event, get_worker
        get_worker()
    except Exception:                 # called in-process (tests): no cluster, no stop
        return False
    return bool(Event(spec.stop_event).is_set())


def _kill_hook(spec: TaskSpec) -> None:
    """Test-only (module docstring): end this worker process on the first attempt of a task."""
    which = os.environ.get("INTEGRATORS_TEST_KILL_TASK")
    mark = os.environ.get("INTEGRATORS_TEST_KILL_FILE")
    if which is None or not mark or int(which) != spec.index:
        return
    try:
        fd = os.open(mark, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return
    os.write(fd, f"{os.getpid()}\n".encode())
    os.close(fd)
    os._exit(1)


def _render_passes(scene, spec: TaskSpec, pass_s: list):
    """The passes of an spp task (``spec.pass_spp``, seeds from ``spec.seed_first``) into an
    Accumulator; stops early when the render's stop event is set."""
    import mitsuba as mi

    from . import progressive
    from .interrupt import test_pause
    acc = None
    t0 = time.perf_counter()
    for k, n in enumerate(spec.pass_spp):
        if k and _stop_requested(spec):
            break
        seed = spec.seed_first + k
        test_pause("compile" if acc is None else "pass")
        tp = time.perf_counter()
        img = np.array(mi.render(scene, spp=int(n), seed=seed, sensor=spec.sensor),
                       dtype=np.float64)
        pass_s.append(time.perf_counter() - tp)
        if img.ndim == 2:
            img = img[..., None]
        if acc is None:
            acc = progressive.Accumulator.empty(
                img.shape, seed_first=seed,
                channels=progressive._film_channel_names(scene, spec.sensor, img.shape[2]))
        acc.add(img, int(n), seed)
        acc.seconds = time.perf_counter() - t0
        _publish(spec, {"task": spec.index, "spp": int(n), "passes": 1})
        _kill_hook(spec)
    return acc


def _render_until(scene, spec: TaskSpec, load_s: float, pass_s: list):
    """A time task: ``progressive.render`` with a time budget up to the deadline (module
    docstring), stopped at the end of the seed block or by the render's stop event."""
    from . import progressive
    stop = progressive.Stop()
    budget = max(spec.deadline + load_s - time.time(), 1e-9) if spec.deadline \
        else spec.time_budget
    done = {"spp": 0}

    def on_pass(a):
        _publish(spec, {"task": spec.index, "spp": int(a.spp - done["spp"]), "passes": 1})
        pass_s.append(a.seconds - sum(pass_s))
        done["spp"] = a.spp
        if a.seed_last >= spec.seed_last or _stop_requested(spec):
            stop.set("end of the task")
        _kill_hook(spec)
    return progressive.render(scene, time_budget=budget, seed=spec.seed_first,
                              sensor=spec.sensor, stop=stop, on_pass=on_pass)


def render_task(spec: TaskSpec) -> dict:
    """Render one task (see the module docstring); the result is a dict of plain values:
    ``s``, ``s2`` (None when nothing was rendered), ``spp``, ``passes``, ``seed_first``,
    ``seed_last``, ``seconds`` (rendering), ``load_s`` (scene load, 0 when cached; the first
    task of a process includes its imports), ``channels``, ``started`` and ``finished``
    (time.time()), ``pid``, ``pass_s`` (seconds of each pass; the first includes the kernel
    compilation)."""
    t_start, t0 = time.time(), time.perf_counter()
    fresh = not _SCENES
    scene, load_s = _load(spec)
    if load_s and fresh:
        load_s = time.perf_counter() - t0
    pass_s: list = []
    acc = None
    if not _stop_requested(spec):         # a task that starts after a stop renders nothing
        acc = (_render_passes(scene, spec, pass_s) if spec.pass_spp
               else _render_until(scene, spec, load_s, pass_s))
    out = {"index": spec.index, "s": None, "s2": None, "spp": 0, "passes": 0,
           "seed_first": spec.seed_first, "seed_last": spec.seed_first - 1, "seconds": 0.0,
           "load_s": load_s, "channels": (), "started": t_start, "pid": os.getpid(),
           "pass_s": pass_s}
    if acc is not None:
        out.update(s=acc.s, s2=acc.s2, spp=acc.spp, passes=acc.passes,
                   seed_first=acc.seed_first, seed_last=acc.seed_last,
                   seconds=float(acc.seconds), channels=tuple(acc.channels))
    out["finished"] = time.time()
    return out


def accumulator(result: dict, record):
    """The :class:`Accumulator` of a task's result, carrying ``record`` with its seed range
    (None for a task that rendered nothing)."""
    from .progressive import Accumulator
    if result["s"] is None or result["passes"] == 0:
        return None
    rng = [[int(result["seed_first"]), int(result["seed_last"])]]
    rec = replace(record, spp=int(result["spp"]), passes=int(result["passes"]),
                  seed_first=rng[0][0], seed_last=rng[0][1], seconds=float(result["seconds"]),
                  seed_ranges=rng)
    return Accumulator(np.asarray(result["s"], np.float64), np.asarray(result["s2"], np.float64),
                       rec.spp, rec.passes, rec.seed_first, rec.seed_last, rec.seconds,
                       record=rec, seed_ranges=[list(r) for r in rng],
                       channels=tuple(result["channels"]))


def merge_results(results, record):
    """The tasks' accumulators merged in seed order with :meth:`Accumulator.merge` (the code of
    ``merge``), refusing overlapping seed ranges (:meth:`RunRecord.merge_problem`); None when
    no task rendered anything."""
    accs = [a for a in (accumulator(r, record) for r in
                        sorted(results, key=lambda r: r["seed_first"])) if a is not None]
    if not accs:
        return None
    from .progressive import merge_accumulators
    return merge_accumulators(accs, [f"task {i}" for i in range(len(accs))])


# =============================================================================================
# client side
class _WorkerSetup(WorkerPlugin):
    """Dask worker plugin: :func:`_worker_setup` on every worker, restarted ones too."""
    name = "integrators-worker-setup"

    def __init__(self, threads_by_host: dict):
        self.threads_by_host = dict(threads_by_host)

    def setup(self, worker):
        _worker_setup(self.threads_by_host, worker.address)


def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 200 else text[:200] + "..."


def check_scheduler_address(address: str) -> None:
    """:class:`ClusterError` (one line) for an address that is not a Dask address or, for TCP,
    where nothing accepts a connection within :data:`CONNECT_TIMEOUT` (checked with a plain
    socket first: a Dask client that failed to connect leaves a thread behind)."""
    import socket

    from distributed.comm import parse_address, parse_host_port
    hint = "give the address the scheduler prints, e.g. tcp://HOST:8786"
    try:
        scheme, loc = parse_address(address)
        host, port = parse_host_port(loc) if scheme in ("tcp", "tls", "ws", "wss") else (loc, 0)
    except (ValueError, TypeError) as e:
        raise ClusterError(f"--scheduler {address!r} is not a Dask scheduler address "
                           f"({_reason(e)}); {hint}") from None
    from distributed.comm.registry import backends
    if scheme not in backends:
        raise ClusterError(f"--scheduler {address!r} is not a Dask scheduler address (unknown "
                           f"scheme {scheme!r}; known: {', '.join(sorted(backends))}); {hint}")
    if scheme not in ("tcp", "tls", "ws", "wss"):
        return
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT).close()
    except OSError as e:
        what = e.strerror or _reason(e)
        if isinstance(e, socket.timeout):
            what = f"no answer within {CONNECT_TIMEOUT:g} s"
        raise ClusterError(f"--scheduler {address!r}: cannot connect to {host}:{port} "
                           f"({what}); {hint}") from None


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored while worker processes are spawned: they inherit it (a Ctrl-C reaches the
    whole process group; only the client handles it)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class Cluster:
    """A Dask client on a LocalCluster of ``workers`` processes, or on the scheduler at
    ``scheduler``; ``slots`` is the number of tasks that run at once."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        import logging

        from distributed import Client, LocalCluster
        self.cluster = None
        self.started_s = 0.0
        t0 = time.perf_counter()
        if scheduler:
            check_scheduler_address(scheduler)
            try:
                self.client = Client(scheduler, timeout=CONNECT_TIMEOUT,
                                     set_as_default=False)
            except Exception as e:  # OSError, TimeoutError: not a scheduler there
                raise ClusterError(
                    f"--scheduler {scheduler!r}: no Dask scheduler answered there within "
                    f"{CONNECT_TIMEOUT:g} s ({_reason(e)}); give the address the scheduler "
                    "prints, e.g. tcp://HOST:8786") from None
        else:
            import dask
            # the workers' statistical profiler samples the task thread's stack 100 times a
            # second: about 10 % of a worker's CPU during a render (measured), for a profile
            # nobody reads here
            with _sigint_ignored(), dask.config.set(LOCAL_CONFIG):
                self.cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                            processes=True, dashboard_address=":0",
                                            silence_logs=logging.CRITICAL)
                self.client = Client(self.cluster, set_as_default=False)
        info = self.client.scheduler_info()["workers"]
        by_host = Counter()
        for w in info.values():
            by_host[w.get("host")] += int(w.get("nthreads", 1))
        self.slots = max(1, sum(by_host.values()))
        if not info:
            self.close()
            raise ClusterError(f"--scheduler {scheduler!r}: the scheduler has no workers")
        self.client.register_plugin(_WorkerSetup(dict(by_host)))
        self.started_s = time.perf_counter() - t0

    def close(self):
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass
class Progress:
    """What the tasks have reported so far (updated from Dask's event thread)."""
    spp: int = 0
    passes: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, event):
        msg = event[1] if isinstance(event, tuple) and len(event) == 2 else event
        with self.lock:
            self.spp += int(msg.get("spp", 0))
            self.passes += int(msg.get("passes", 0))


def render(cluster: Cluster, scene_path, record, film: tuple, spp: int | None = None,
           time_budget: float | None = None, seed: int = 0, sensor: int = 0, stop=None,
           on_progress=None, stats: dict | None = None):
    """Render on ``cluster`` (a :class:`Cluster`, or anything with its ``client`` and
    ``slots``) and return the merged :class:`Accumulator` (None when nothing was rendered).
    ``record`` is the run's identity (``RunRecord.for_scene``); ``film`` (w, h); ``spp`` or
    ``time_budget`` as in :func:`progressive.render`.  ``stop`` (progressive.Stop): once set,
    tasks stop after their pass in flight.  ``on_progress(progress, elapsed)`` (a
    :class:`Progress`) is called at least 4 times a second.  ``stats`` (a dict) receives
    ``futures``, ``results`` (the results of the tasks finished so far, kept up to date so
    that a second signal can write them), ``tasks`` (per task: load_s, seconds, spp, passes,
    pid, pass_s, bytes, start_s, transfer_s), ``merge_s``, ``wall_s`` and ``slots``."""
    from pathlib import Path

    from distributed import Event
    w, h = film
    stats = {} if stats is None else stats
    run = uuid.uuid4().hex[:12]
    base = dict(scene=str(Path(scene_path).resolve()), scene_sha1=record.scene_sha1,
                defines=tuple(sorted((record.defines or {}).items())), variant=record.variant,
                stop_event=f"integrators-stop-{run}", topic=f"integrators-progress-{run}",
                sensor=sensor)
    if spp is not None:
        specs = [TaskSpec(index=i, seed_first=f, seed_last=f + len(p) - 1, pass_spp=p, **base)
                 for i, (f, p) in enumerate(plan_spp(w, h, spp, seed, cluster.slots))]
        last = specs[-1].seed_last
        if last > MAX_SEED:
            raise ValueError(f"seed {seed} with spp {spp} needs the seeds {seed}-{last} (one per "
                             f"pass), past the largest seed {MAX_SEED}; use a seed <= "
                             f"{MAX_SEED - (last - seed)}")
    else:
        deadline = time.time() + float(time_budget)
        specs = [TaskSpec(index=i, seed_first=f, seed_last=l, time_budget=float(time_budget),
                          deadline=deadline, **base)
                 for i, (f, l) in enumerate(plan_time(seed, cluster.slots))]
    client = cluster.client
    progress = Progress()
    client.subscribe_topic(base["topic"], progress)
    event = Event(base["stop_event"], client=client)
    t0, submitted = time.perf_counter(), time.time()
    futures = [client.submit(render_task, s, key=f"render-{run}-{s.index}", pure=False)
               for s in specs]
    changed = threading.Event()
    for f in futures:
        f.add_done_callback(lambda _f: changed.set())
    stats.update(slots=cluster.slots, tasks_planned=len(specs), results=[], tasks=[],
                 futures=futures)
    pending = list(futures)
    stop_sent = False
    try:
        while pending:
            if stop is not None and stop.requested and not stop_sent:
                event.set()
                stop_sent = True
            changed.wait(0.25)
            changed.clear()
            still = []
            for f in pending:
                if f.done():
                    r = f.result()          # re-raises a task's exception
                    got = time.time()
                    stats["results"].append(r)
                    stats["tasks"].append({"index": r["index"], "load_s": r["load_s"],
                                           "seconds": r["seconds"], "spp": r["spp"],
                                           "passes": r["passes"], "pid": r["pid"],
                                           "pass_s": list(r.get("pass_s", [])),
                                           "bytes": int(r["s"].nbytes + r["s2"].nbytes)
                                           if r["s"] is not None else 0,
                                           "start_s": r["started"] - submitted,
                                           "transfer_s": max(got - r["finished"], 0.0)})
                else:
                    still.append(f)
            pending = still
            if on_progress is not None:
                on_progress(progress, time.perf_counter() - t0)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(futures)
        raise
    finally:
        with contextlib.suppress(Exception):
            client.unsubscribe_topic(base["topic"])
    tm = time.perf_counter()
    acc = merge_results(stats["results"], record)
    stats["merge_s"] = time.perf_counter() - tm
    stats["wall_s"] = time.perf_counter() - t0
    if acc is not None:
        acc.seconds = stats["wall_s"]
    with contextlib.suppress(Exception):
        event.clear()
    return acc
