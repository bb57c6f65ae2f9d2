r"""Light-tree benchmark (issue 15): ``light_selection=bvh`` against Mitsuba's ``path`` and our
``power`` and ``adaptive`` selections, from a few to many lights.

    python -m benchmarks.light_tree [--lights 64 1024 4096 16384] [--res 64] [--spp 4]
        [--repeats 3] [--ref-spp 512] [--adaptive-max 4096] [--glossy N ...] [--few]
        [--few-res 128] [--out DIR]
    python -m benchmarks.light_tree --setup [--lights N ...] [--repeats 3] [--out DIR]
    python -m benchmarks.light_tree --flat [--spp 16] [--repeats 3] [--out DIR]

Scenes: ``scenes/tools/make_light_field.py`` (N sphere lights over a floor, powers over three
decades), built at run time, one fresh process per N (every emitter alive in a process is traced
into its kernels); ``--glossy N ...`` adds light fields over a rough aluminium floor
(``glossy_field``); ``--few`` adds ``veach_mis`` and ``cornell_box``.  Direct light only
(``max_depth`` 2, ``hide_emitters``) on the light fields, ``max_depth`` 4 on the few-light
scenes, rendered ``--few-res`` pixels wide (128, as in the experiments report: at 64 x 36 the
smallest light of ``veach_mis`` is a fraction of a pixel).  Methods:
Mitsuba's ``path`` and our ``nee_path`` with ``light_selection`` = ``power``, ``adaptive`` (only
up to ``--adaptive-max`` lights: its set-up is O(N) scalar work), ``bvh`` and ``ris``; the same
estimator otherwise, so the columns compare light selection.

Measured per scene, side by side in one process:

* **set-up**: wall time of the first ``mi.render`` with a fresh integrator (1 spp): light powers,
  tree build, tracing and compiling (or loading from Dr.Jit's kernel cache) included; path first;
* **selection set-up**: ``light_selection.make(scene, mode)`` alone (powers, bounds, tree);
* **one choice alone**: wall time of ``choose`` at 2^20 random points of the floor plane (the
  selection's own cost, without Mitsuba's emitter calls; tracing included, best warm run), per
  choice (for ris the choice without a BSDF: its candidates by the leaf bound);
* **per-call overhead**: wall time of a later 1-spp render (Mitsuba's per-call work over the
  emitters, which at thousands of lights dwarfs the kernel);
* **time per sample**: the marginal cost of a sample, from the execution time of the render's
  kernels in Dr.Jit's kernel history (``JitFlag.KernelHistory``): (kernel time at 8 x
  ``--spp`` - kernel time at ``--spp``) / (pixels x 7 ``--spp``), each the least of
  ``--repeats`` renders taken round-robin over the methods (the least disturbed by other work
  on a shared machine).  The difference leaves out the kernels every ``mi.render`` call runs
  once whatever its spp (Mitsuba uploads every emitter's data for its virtual calls: 15-35 ms
  per call at 16,384 lights, as much as 100 samples per pixel of a 64 x 64 image would cost);
  they are the **per-call kernels** column (kernel time at ``--spp`` minus spp x pixels x the
  time per sample);
* **relMSE at 1 spp**: sum over pixels of (I - R)^2 / sum R^2 of a ``--spp`` render times spp,
  averaged over the repeats; R: ``nee_path`` with ``ris`` at ``--ref-spp`` (its own noise, about
  spp / ref-spp of ris's relMSE, is left in);
* **per-pixel relMSE at 1 spp**: the experiments' relMSE (``benchmarks.metrics.relmse``:
  mean over pixels of (I - R)^2 / (R^2 + 0.01)) times spp.  The sum above weights a pixel by its
  brightness squared: on a scene whose emitters the camera sees (the few-light scenes) it is
  ruled by the pixels of a small bright light seen directly, whose error is the same lottery
  for every light selection (which camera samples hit the light) and varies by tens of percent
  between sets of renders; the per-pixel measure weights every pixel alike;
* **efficiency vs path** = (relMSE x time per sample) of ``path`` / that of the method, with the
  summed relMSE (the issue's measure; the light fields hide their emitters) and, in its own
  column, with the per-pixel one.

``--setup`` measures only the set-up: per N, ``--repeats`` fresh processes, each timing the
first render (1 spp) of ``path`` and then of each selection's fresh integrator, and a later
render of each (the per-call overhead); it writes ``setup.json`` and ``setup.md`` (medians of
the per-process ratios to ``path``'s first render).

``--flat`` separates the two causes of a time per sample growing with N: the light field of
64 lights, the field of 16,384 spheres of which only 64 (every 256th) emit (the others plain
diffuse spheres), and the field of 16,384 lights; time per sample as above for ``path``,
``bvh`` and ``ris``.  From the first to the second only the geometry grows (a floor 16x as
wide, 256x the spheres), from the second to the third only the number of lights.  Writes
``flat.json`` and ``flat.md``.

Writes ``light_tree.json``, ``light_tree.md`` (the table) and ``light_tree_cost.png`` (time per
sample and set-up against N) under ``--out`` (default ``benchmarks/results/light_tree``).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from .config import REPO

OUT = REPO / "benchmarks" / "results" / "light_tree"
LIGHTS = (64, 1024, 4096, 16384)
SELECTIONS = ("power", "adaptive", "bvh", "ris")
#: the floor of ``--glossy`` light fields (BSDF-aware selection matters there)
GLOSSY_FLOOR = {"type": "roughconductor", "material": "Al", "alpha": 0.1}
#: the timing renders take this many times --spp (time per sample is their slope)
TIME_FACTOR = 8


def _methods(n_lights, adaptive_max, depth):
    # the light fields hide their emitters from the camera: the tiny bright spheres seen
    # directly would dominate every method's error (pixel aliasing, not light selection)
    hide = {"hide_emitters": True} if n_lights is not None else {}
    out = {"path": {"type": "path", "max_depth": depth, **hide}}
    for s in SELECTIONS:
        if s == "adaptive" and n_lights is not None and n_lights > adaptive_max:
            continue
        out[s] = {"type": "nee_path", "max_depth": depth, "light_selection": s, **hide}
    return out


def _kernel_seconds(dr):
    hist = dr.kernel_history()
    return sum(float(k.get("execution_time", 0.0) or 0.0) for k in hist) / 1000.0


def measure(scene_name: str, n_lights, res: int, spp: int, repeats: int, ref_spp: int,
            adaptive_max: int, few_res: int = 128) -> dict:
    """All measurements of one scene (run in its own process)."""
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import numpy as np
    import integrators  # noqa: F401  (registers the plugins)
    from .metrics import relmse
    sys.path.insert(0, str(REPO / "scenes" / "tools"))
    t0 = time.perf_counter()
    if n_lights is not None:
        import make_light_field
        d = make_light_field.scene_dict(n_lights, res=res, spp=spp)
        if scene_name == "glossy_field":   # a wet street: the floor rough aluminium
            d["floor"]["bsdf"] = GLOSSY_FLOOR
        scene = mi.load_dict(d)
        depth = 2
    else:
        params = {"res": str(few_res)} if scene_name == "cornell_box" else {
            "width": str(few_res), "height": str(max(1, few_res * 9 // 16))}
        scene = mi.load_file(str(REPO / "scenes" / f"{scene_name}.xml"), **params)
        depth = 4
    load_s = time.perf_counter() - t0
    methods = _methods(n_lights, adaptive_max, depth)
    film = scene.sensors()[0].film().crop_size()
    pixels = int(film[0]) * int(film[1])

    def render(integ, s, seed):
        dr.kernel_history()      # returns and clears the history so far
        t = time.perf_counter()
        img = mi.render(scene, integrator=integ, spp=s, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        wall = time.perf_counter() - t
        return np.array(img, dtype=np.float64)[..., :3], wall, _kernel_seconds(dr)

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    integs, setup, overhead = {}, {}, {}
    for name, d in methods.items():
        integs[name] = mi.load_dict(d)
        _, setup[name], _ = render(integs[name], 1, 0)
        _, overhead[name], _ = render(integs[name], 1, 1)
    from integrators.sampling.light_selection import make
    select_s, choose_ns = {}, {}
    lanes = 1 << 20
    rng = np.random.default_rng(0)
    bb = scene.bbox()
    lo_b, hi_b = np.array(bb.min, float).ravel(), np.array(bb.max, float).ravel()
    pts = [rng.uniform(lo_b[k], hi_b[k], lanes).astype(np.float32) for k in range(2)]
    for name in methods:
        if name == "path":
            continue
        t = time.perf_counter()
        sel = make(scene, name)
        select_s[name] = time.perf_counter() - t
        # the selection alone: one choice at each of 2^20 random points of the floor plane
        wall = []
        # adaptive is O(N) per choice: fewer points, so that it takes seconds, not minutes
        m = lanes if name != "adaptive" else min(lanes, max(1 << 12, lanes * 64 // len(
            scene.emitters())))
        for r in range(repeats + 1):
            si = dr.zeros(mi.SurfaceInteraction3f, m)
            si.p = mi.Point3f(mi.Float(pts[0][:m]), mi.Float(pts[1][:m]), float(lo_b[2]))
            si.n = mi.Vector3f(0, 0, 1)
            u = [mi.Float(rng.random(m).astype(np.float32)) for _ in range(sel.SAMPLE_DIMS)]
            u = u[0] if sel.SAMPLE_DIMS == 1 else mi.Point2f(*u)
            dr.eval(si, u)
            dr.sync_thread()
            t = time.perf_counter()
            _, pmf, _ = sel.choose(si, u)
            dr.eval(pmf)
            dr.sync_thread()
            wall.append((time.perf_counter() - t) / m * 1e9)
        choose_ns[name] = min(wall[1:])       # the least disturbed of the warm runs
    ref, _, _ = render(integs["ris"], ref_spp, 12345)
    ref_sq = float((ref ** 2).sum())
    rel, means = {m: [] for m in methods}, {m: [] for m in methods}
    rel_px = {m: [] for m in methods}
    k_lo, k_hi = {m: [] for m in methods}, {m: [] for m in methods}
    for r in range(repeats):
        for name in methods:
            img, _, kern = render(integs[name], spp, 1000 + 17 * r)
            rel[name].append(float(((img - ref) ** 2).sum()) / ref_sq * spp)
            rel_px[name].append(relmse(img, ref) * spp)
            k_lo[name].append(kern)
            means[name].append(float(img.mean()))
            k_hi[name].append(render(integs[name], spp * TIME_FACTOR, 5000 + 17 * r)[2])
    out = {"scene": scene_name, "lights": n_lights if n_lights is not None else
           len(scene.emitters()), "pixels": pixels, "spp": spp, "repeats": repeats,
           "ref_spp": ref_spp, "load_s": load_s, "ref_mean": float(ref.mean()), "methods": {}}
    for name in methods:
        out["methods"][name] = {
            "setup_s": setup[name], "overhead_s": overhead[name],
            "selection_s": select_s.get(name), "choose_ns": choose_ns.get(name),
            "relmse_1spp": statistics.mean(rel[name]),
            "relmse_px_1spp": statistics.mean(rel_px[name]),
            "time_per_sample_us": (min(k_hi[name]) - min(k_lo[name]))
            / (pixels * spp * (TIME_FACTOR - 1)) * 1e6,
            "kernel_us_at_spp": min(k_lo[name]) / (pixels * spp) * 1e6,
            "mean_ratio": statistics.mean(means[name]) / max(float(ref.mean()), 1e-30)}
    for m in out["methods"].values():
        m["per_call_kernels_ms"] = (m["kernel_us_at_spp"] - m["time_per_sample_us"]) \
            * pixels * spp * 1e-3
    base = out["methods"]["path"]
    for name, m in out["methods"].items():
        for k, e in (("relmse_1spp", "efficiency_vs_path"),
                     ("relmse_px_1spp", "efficiency_px_vs_path")):
            m[e] = ((base[k] * base["time_per_sample_us"])
                    / max(m[k] * m["time_per_sample_us"], 1e-30))
    return out


def _child(args, what: str):
    """Run ``python -m benchmarks.light_tree ARGS`` in a fresh process (every emitter alive in
    a process is traced into its kernels) and return its RESULT, or None (its output's tail
    and a line naming ``what`` on stderr)."""
    cmd = [sys.executable, "-m", "benchmarks.light_tree", *map(str, args)]
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
    if p.returncode != 0 or not line:
        sys.stderr.write(p.stdout[-2000:] + p.stderr[-4000:])
        print(f"light_tree benchmark: {what} failed", file=sys.stderr)
        return None
    return json.loads(line[0][7:])


def measure_setup(n_lights: int, methods=("path", "bvh", "ris")) -> dict:
    """Set-up only (``--setup``), in this process: the first and a later 1-spp render of each
    method's fresh integrator, ``path`` first, as :func:`measure` times them."""
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import integrators  # noqa: F401  (registers the plugins)
    sys.path.insert(0, str(REPO / "scenes" / "tools"))
    import make_light_field
    scene = mi.load_dict(make_light_field.scene_dict(n_lights, res=64, spp=16))
    all_methods = _methods(n_lights, 0, 2)
    out = {"lights": n_lights, "methods": {}}
    for name in methods:
        integ = mi.load_dict(all_methods[name])
        walls = []
        for seed in range(2):
            t = time.perf_counter()
            dr.eval(mi.render(scene, integrator=integ, spp=1, seed=seed))
            dr.sync_thread()
            walls.append(time.perf_counter() - t)
        out["methods"][name] = {"setup_s": walls[0], "overhead_s": walls[1]}
    return out


def setup_report(results) -> str:
    """Markdown table of ``--setup`` runs (one list of per-process results per N)."""
    lines = ["| lights | processes | first render (s), median: path / bvh / ris | "
             "first render / path's, median (range): bvh / ris | later render (s), median: "
             "path / bvh / ris |", "|---|---|---|---|---|"]
    for runs in results:
        med = {m: statistics.median(r["methods"][m]["setup_s"] for r in runs)
               for m in ("path", "bvh", "ris")}
        later = {m: statistics.median(r["methods"][m]["overhead_s"] for r in runs)
                 for m in ("path", "bvh", "ris")}
        ratio = {m: [r["methods"][m]["setup_s"] / r["methods"]["path"]["setup_s"]
                     for r in runs] for m in ("bvh", "ris")}
        lines.append(
            f"| {runs[0]['lights']:,} | {len(runs)} | "
            + " / ".join(f"{med[m]:.1f}" for m in ("path", "bvh", "ris")) + " | "
            + " / ".join(f"{statistics.median(ratio[m]):.2f} ({min(ratio[m]):.2f}-"
                         f"{max(ratio[m]):.2f})" for m in ("bvh", "ris")) + " | "
            + " / ".join(f"{later[m]:.1f}" for m in ("path", "bvh", "ris")) + " |")
    return "\n".join(lines) + "\n"


def _run_build(a, argv) -> int:
    """The build over 100,000 synthetic lights, ``--repeats`` times (each the best of 3): the
    issue's target is at most 1 s."""
    times = []
    for _ in range(a.repeats):
        times.append(_build_time(100_000))
        print(f"tree build over 100,000 lights: {times[-1]:.3f} s", flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "build.json").write_text(json.dumps({"lights": 100_000, "seconds": times}, indent=1))
    md = ("# Light tree benchmark: build time\n\n`python -m benchmarks.light_tree " + " ".join(
        sys.argv[1:] if argv is None else argv) + "`\n\n100,000 synthetic lights (random boxes, "
        "normals, powers over three decades), each figure the best of 3 builds: "
        + ", ".join(f"{t:.3f}" for t in times) + f" s (median {statistics.median(times):.3f} s; "
        "target: at most 1 s)\n")
    (a.out / "build.md").write_text(md)
    print(md)
    return 0


def _run_setup(a, argv) -> int:
    results = []
    for n in a.lights:
        runs = []
        for _ in range(a.repeats):
            r = _child(["--one-setup", n], f"set-up at {n} lights")
            if r is None:
                return 1
            runs.append(r)
        results.append(runs)
        print(setup_report(results[-1:]).splitlines()[2], flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "setup.json").write_text(json.dumps(results, indent=1))
    md = ("# Light tree benchmark: set-up\n\n`python -m benchmarks.light_tree " + " ".join(
        sys.argv[1:] if argv is None else argv) + "`\n\n" + setup_report(results))
    (a.out / "setup.md").write_text(md)
    print(md)
    return 0


def measure_flat(n_spheres: int, n_emitting: int, spp: int, repeats: int) -> dict:
    """Time per sample (``--flat``) of path, bvh and ris on the field of ``n_spheres``
    spheres of which ``n_emitting`` (evenly spread in the generator's order) emit."""
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import integrators  # noqa: F401  (registers the plugins)
    sys.path.insert(0, str(REPO / "scenes" / "tools"))
    import make_light_field
    d = make_light_field.scene_dict(n_spheres, res=64, spp=spp)
    step = n_spheres // n_emitting
    for i in range(n_spheres):
        if i % step:
            del d[f"light{i}"]["emitter"]
    scene = mi.load_dict(d)
    pixels = 64 * 64
    methods = {k: v for k, v in _methods(n_emitting, 0, 2).items() if k in ("path", "bvh", "ris")}
    integs = {k: mi.load_dict(v) for k, v in methods.items()}
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    def kernel_s(integ, s, seed):
        dr.kernel_history()
        dr.eval(mi.render(scene, integrator=integ, spp=s, seed=seed))
        dr.sync_thread()
        return _kernel_seconds(dr)

    for integ in integs.values():          # compile
        kernel_s(integ, spp, 0)
    lo, hi = {k: [] for k in integs}, {k: [] for k in integs}
    for r in range(repeats):
        for k, integ in integs.items():
            lo[k].append(kernel_s(integ, spp, 100 + r))
            hi[k].append(kernel_s(integ, spp * TIME_FACTOR, 200 + r))
    return {"spheres": n_spheres, "lights": len(scene.emitters()), "spp": spp,
            "time_per_sample_us": {k: (min(hi[k]) - min(lo[k])) /
                                   (pixels * spp * (TIME_FACTOR - 1)) * 1e6 for k in integs}}


def _run_flat(a, argv) -> int:
    rows = []
    for n, k in ((64, 64), (16384, 64), (16384, 16384)):
        r = _child(["--one-flat", n, k, "--spp", a.spp, "--repeats", a.repeats],
                   f"--flat {n} {k}")
        if r is None:
            return 1
        rows.append(r)
        print(rows[-1], flush=True)
    cols = ("path", "bvh", "ris")
    lines = ["| spheres | lights | time per sample (us): " + " / ".join(cols) + " |",
             "|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['spheres']:,} | {r['lights']:,} | " + " / ".join(
            f"{r['time_per_sample_us'][c]:.3g}" for c in cols) + " |")
    t = [r["time_per_sample_us"] for r in rows]
    lines.append("")
    for c in cols:
        lines.append(f"- `{c}`: x{t[1][c] / t[0][c]:.2f} from the geometry (64 lights), "
                     f"x{t[2][c] / t[1][c]:.2f} from the number of lights (same geometry), "
                     f"x{t[2][c] / t[0][c]:.2f} in all")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "flat.json").write_text(json.dumps(rows, indent=1))
    md = ("# Light tree benchmark: time per sample, geometry against number of lights\n\n"
          "`python -m benchmarks.light_tree " + " ".join(
              sys.argv[1:] if argv is None else argv) + "`\n\n" + "\n".join(lines) + "\n")
    (a.out / "flat.md").write_text(md)
    print(md)
    return 0


def _build_time(n: int, repeats: int = 3) -> float:
    """Best of ``repeats`` builds of the tree over n synthetic lights (random boxes, normals,
    powers over three decades)."""
    import numpy as np
    from integrators.sampling.light_tree import build
    rng = np.random.default_rng(0)
    c = rng.uniform(-50, 50, (n, 3))
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        build(c - 0.1, c + 0.1, w, np.ones(n), np.zeros(n), np.zeros(n, bool),
              10 ** rng.uniform(0, 3, n))
        best = min(best, time.perf_counter() - t)
    return best


def _fmt(x, f="{:.3g}"):
    return "-" if x is None else f.format(x)


def table(results) -> str:
    cols = ["path", *SELECTIONS]
    head = ("| scene | lights | relMSE at 1 spp: " + " / ".join(cols) + " | time per sample (us): "
            + " / ".join(cols) + " | efficiency vs path: " + " / ".join(cols[1:])
            + " | per-pixel relMSE at 1 spp: " + " / ".join(cols)
            + " | efficiency vs path, per-pixel relMSE: " + " / ".join(cols[1:])
            + " | per-call kernels (ms): " + " / ".join(cols)
            + " | set-up, first render (s): " + " / ".join(cols) + " | per-call overhead (s): "
            + " / ".join(cols) + " | selection set-up (s): " + " / ".join(cols[1:])
            + " | one choice alone (ns): " + " / ".join(cols[1:]) + " | mean / reference: bvh / ris |")
    lines = [head, "|" + "---|" * 14]
    for r in results:
        m = r["methods"]

        def get(k, name, f="{:.3g}"):
            return _fmt(m[name].get(k) if name in m else None, f)
        lines.append(
            f"| {r['scene']} | {r['lights']:,} | "
            + " / ".join(get("relmse_1spp", c) for c in cols) + " | "
            + " / ".join(get("time_per_sample_us", c) for c in cols) + " | "
            + " / ".join(get("efficiency_vs_path", c, "{:.1f}x") for c in cols[1:]) + " | "
            + " / ".join(get("relmse_px_1spp", c) for c in cols) + " | "
            + " / ".join(get("efficiency_px_vs_path", c, "{:.1f}x") for c in cols[1:]) + " | "
            + " / ".join(get("per_call_kernels_ms", c, "{:.1f}") for c in cols) + " | "
            + " / ".join(get("setup_s", c, "{:.1f}") for c in cols) + " | "
            + " / ".join(get("overhead_s", c, "{:.1f}") for c in cols) + " | "
            + " / ".join(get("selection_s", c, "{:.2f}") for c in cols[1:]) + " | "
            + " / ".join(get("choose_ns", c, "{:.3g}") for c in cols[1:]) + " | "
            + f"{m['bvh']['mean_ratio']:.4f} / {m['ris']['mean_ratio']:.4f} |")
    fields = [r for r in results if r["scene"] == "light_field"]
    if fields:
        lo, hi = min(fields, key=lambda r: r["lights"]), max(fields, key=lambda r: r["lights"])
        b = [r["methods"]["bvh"] for r in (lo, hi)]
        path_lo, path_hi = (r["methods"]["path"]["time_per_sample_us"] for r in (lo, hi))
        ris_lo, ris_hi = (r["methods"]["ris"]["time_per_sample_us"] for r in (lo, hi))
        lines += ["", f"time per sample at {hi['lights']:,} / at {lo['lights']:,} lights: bvh "
                  f"{b[1]['time_per_sample_us'] / b[0]['time_per_sample_us']:.2f}x, ris "
                  f"{ris_hi / ris_lo:.2f}x, path {path_hi / path_lo:.2f}x; "
                  f"relative to path's own (the selection's share): bvh "
                  f"{b[1]['time_per_sample_us'] / b[0]['time_per_sample_us'] / (path_hi / path_lo):.2f}x, "
                  f"ris {ris_hi / ris_lo / (path_hi / path_lo):.2f}x; "
                  f"one bvh choice alone: {b[1]['choose_ns'] / b[0]['choose_ns']:.2f}x; "
                  f"bvh first render / path first render at {hi['lights']:,} lights: "
                  f"{b[1]['setup_s'] / hi['methods']['path']['setup_s']:.2f}x; bvh selection "
                  f"set-up (powers, bounds, build) / path first render: "
                  f"{b[1]['selection_s'] / hi['methods']['path']['setup_s']:.2f}x"]
    few = [r for r in results if r["scene"] != "light_field"]
    for r in few:
        m = r["methods"]

        def vs_power(name, k):
            return m[name].get(k, float("nan")) / m["power"].get(k, float("nan"))
        lines.append(f"{r['scene']}: efficiency / power's, per-pixel relMSE (summed relMSE): "
                     f"bvh {vs_power('bvh', 'efficiency_px_vs_path'):.2f} "
                     f"({vs_power('bvh', 'efficiency_vs_path'):.2f}), "
                     f"ris {vs_power('ris', 'efficiency_px_vs_path'):.2f} "
                     f"({vs_power('ris', 'efficiency_vs_path'):.2f})")
    return "\n".join(lines) + "\n"


def chart(path: Path, results) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fields = sorted((r for r in results if r["scene"] == "light_field"), key=lambda r: r["lights"])
    if not fields:
        return
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for name, colour in (("path", "k"), ("power", "tab:blue"), ("adaptive", "tab:orange"),
                         ("bvh", "tab:green"), ("ris", "tab:red")):
        pts = [(r["lights"], r["methods"][name]) for r in fields if name in r["methods"]]
        if not pts:
            continue
        n = [p[0] for p in pts]
        ax[0].plot(n, [p[1]["time_per_sample_us"] for p in pts], "o-", color=colour, label=name)
        ax[1].plot(n, [p[1]["setup_s"] for p in pts], "o-", color=colour, label=name)
    for a, t in zip(ax, ("kernel time per sample (us)", "set-up: first render (s)")):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("lights")
        a.set_title(t)
        a.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.light_tree",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--lights", type=int, nargs="*", default=list(LIGHTS))
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--adaptive-max", type=int, default=4096)
    ap.add_argument("--few", action="store_true", help="also veach_mis and cornell_box")
    ap.add_argument("--few-res", type=int, default=128,
                    help="image width of the few-light scenes (default 128)")
    ap.add_argument("--glossy", type=int, nargs="*", default=[], metavar="N",
                    help="also light fields of N lights over a glossy floor (rough aluminium)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--setup", action="store_true",
                    help="measure only the set-up (first render) of path, bvh and ris")
    ap.add_argument("--build", action="store_true",
                    help="measure only the tree build over 100,000 lights (--repeats times)")
    ap.add_argument("--one", nargs=2, metavar=("SCENE", "N"), help=argparse.SUPPRESS)
    ap.add_argument("--one-setup", type=int, metavar="N", help=argparse.SUPPRESS)
    ap.add_argument("--flat", action="store_true",
                    help="time per sample: geometry grown with the lights vs lights alone")
    ap.add_argument("--one-flat", type=int, nargs=2, metavar=("SPHERES", "LIGHTS"),
                    help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    for k in ("res", "few_res", "spp", "repeats", "ref_spp"):
        if getattr(a, k) < 1:
            ap.error(f"--{k.replace('_', '-')}: {getattr(a, k)} is not allowed; at least 1")
    for k in ("lights", "glossy"):
        if any(n < 1 for n in getattr(a, k)):
            ap.error(f"--{k}: {getattr(a, k)} not allowed; every count at least 1")
    if a.one_setup:
        print("RESULT " + json.dumps(measure_setup(a.one_setup)))
        return 0
    if a.build:
        return _run_build(a, argv)
    if a.setup:
        return _run_setup(a, argv)
    if a.one_flat:
        print("RESULT " + json.dumps(measure_flat(*a.one_flat, a.spp, a.repeats)))
        return 0
    if a.flat:
        return _run_flat(a, argv)
    if a.one:
        scene, n = a.one
        r = measure(scene, None if n == "-" else int(n), a.res, a.spp, a.repeats, a.ref_spp,
                    a.adaptive_max, a.few_res)
        print("RESULT " + json.dumps(r))
        return 0
    build_s = _build_time(100_000)
    print(f"tree build over 100,000 lights (synthetic): {build_s:.2f} s", flush=True)
    jobs = [("light_field", str(n)) for n in a.lights]
    jobs += [("glossy_field", str(n)) for n in a.glossy]
    if a.few:
        jobs += [("veach_mis", "-"), ("cornell_box", "-")]
    results = []
    for scene, n in jobs:
        r = _child(["--one", scene, n, "--res", a.res, "--spp", a.spp, "--repeats", a.repeats,
                    "--ref-spp", a.ref_spp, "--adaptive-max", a.adaptive_max,
                    "--few-res", a.few_res], f"{scene} {n}")
        if r is None:
            return 1
        results.append(r)
        print(table(results[-1:]).splitlines()[2], flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "light_tree.json").write_text(json.dumps(results, indent=1))
    md = ("# Light tree benchmark\n\n`python -m benchmarks.light_tree " + " ".join(
        sys.argv[1:] if argv is None else argv) + "`\n\n" + table(results)
        + f"\ntree build over 100,000 lights (synthetic, numpy): {build_s:.2f} s\n")
    (a.out / "light_tree.md").write_text(md)
    chart(a.out / "light_tree_cost.png", results)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
