r"""Speed of our integrators against Mitsuba's built-in ones, one scene per process.

    python -m benchmarks.speed [--scene SCENE ...] [--configs NAME,...] [--spp 64]
                               [--repeats 7] [--max-depth 8] [--variant llvm_ad_rgb]
                               [--out benchmarks/results/speed.json]

Without ``--scene`` every scene of :data:`DEFAULT_SCENES` (``scenes/veach_mis.xml`` with every
configuration, ``scenes/cornell_box.xml`` with ``path`` and the two ``nee_path`` rows) is
benchmarked in its own subprocess (``--scene S --out <tmp>``) and the results are merged into
one JSON file and one Markdown file (a table per scene).  With one ``--scene`` the benchmark
runs in this process and writes that scene's result alone (the single-scene format); with
several, each runs in a subprocess as above.

Configurations (see :data:`CONFIGS`; ``--configs`` picks a subset, ``path`` always included):
our ``bsdf_path`` (BSDF sampling) against the built-in ``path`` with the same ``max_depth`` (and
the default ``rr_depth`` 5 in both); our ``direct_mis`` (1 light sample, 1 BSDF sample, power
heuristic, uniform light selection: the estimator of the built-in ``direct`` with
``emitter_samples=1, bsdf_samples=1``) against ``direct``; our ``nee_path`` with
``heuristic=power, light_selection=uniform, rr=throughput, light_samples=1, split=1`` (the
estimator of the built-in ``path``) against ``path``.  Extra rows: ``direct_mis`` with light
selection by power (ratio to ``direct_mis``) and ``nee_path`` with its defaults (light
selection by power; ratio to ``path``).

Method:

* the scene is loaded once, at its own sensor resolution, and every integrator is built with
  ``mi.load_dict`` and passed to ``mi.render(scene, integrator=...)``.  One scene only: every
  BSDF alive in the process is compiled into each kernel, so extra copies of the scene would
  change every kernel (see /work/shared/mitsuba-notes.md);
* one warm-up render per configuration (JIT compilation excluded from the timings), then one
  diagnostic render with Dr.Jit's kernel history switched on (kernel execution time, operation
  count, cache hits; not used for the timings);
* ``repeats`` rounds, each rendering every configuration once in a fixed round-robin order
  (A B C D E A B C D E ...), ``seed`` = round index, each render timed with
  ``time.perf_counter`` around ``mi.render(...); dr.eval(img); dr.sync_thread()`` (the timing
  core of every benchmark, :mod:`benchmarks.timing`);
* samples/s = width * height * spp / seconds; the median over rounds per configuration;
* ratios ``ours / built-in`` of samples/s (> 1: ours is faster): the headline value is the
  median of the per-round ratios (each round's pair ran seconds apart, which cancels slow drift
  of the machine's load); the ratio of the medians and of the best (fastest) renders are
  recorded too, and, as extras, ``direct_mis_power / direct_mis`` and ``nee_path / path``;
* a diagnostic: the image mean of each configuration's last render (same-estimator pairs should
  agree within noise).

``bsdf_path`` has no light sampling, so it is not the same estimator as ``path`` (different
noise, different number of rays per path): that ratio compares cost per sample only.

Results: a JSON file (``--out``) and a Markdown file next to it (same name, ``.md``), both
written atomically; both record the command that ran (``"command"``, the "Command:" line).
A merged (multi-scene) JSON file holds ``"scenes"``: one single-scene result per scene, each in
the single-scene format.
"""
from __future__ import annotations

import argparse
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from . import provenance, timing

PROG = "python -m benchmarks.speed"
CHILD = "python -m benchmarks.speed"      # how a scene's subprocess is started

# name, kind ('ours' | 'builtin'), integrator dict (max_depth filled in later), description
CONFIGS = (
    ("path", "builtin", {"type": "path"},
     "Mitsuba `path` (NEE + BSDF sampling, power-heuristic MIS)"),
    ("bsdf_path", "ours", {"type": "bsdf_path", "hemisphere": "bsdf"},
     "our `bsdf_path`, hemisphere=bsdf (no light sampling)"),
    ("direct", "builtin", {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
     "Mitsuba `direct`, emitter_samples=1, bsdf_samples=1"),
    ("direct_mis", "ours", {"type": "direct_mis", "light_samples": 1, "bsdf_samples": 1,
                            "heuristic": "power", "light_selection": "uniform"},
     "our `direct_mis`, 1+1 samples, power heuristic, uniform light selection"),
    ("direct_mis_power", "ours", {"type": "direct_mis", "light_samples": 1, "bsdf_samples": 1,
                                  "heuristic": "power", "light_selection": "power"},
     "our `direct_mis`, as above but light selection by power (extra)"),
    ("nee_path_mitsuba", "ours", {"type": "nee_path", "heuristic": "power",
                                  "light_selection": "uniform", "rr": "throughput",
                                  "light_samples": 1, "split": 1},
     "our `nee_path`, power heuristic, uniform light selection, rr=throughput, 1 light sample, "
     "split 1 (the estimator of `path`)"),
    ("nee_path", "ours", {"type": "nee_path"},
     "our `nee_path`, defaults (light selection by power; otherwise as above) (extra)"),
)
PATH_DEPTH = ("path", "bsdf_path", "nee_path_mitsuba", "nee_path")   # take max_depth
RATIOS = (("bsdf_path", "path"), ("direct_mis", "direct"), ("nee_path_mitsuba", "path"))
EXTRA_RATIOS = (("direct_mis_power", "direct_mis"),   # cost of light selection by power
                ("nee_path", "path"))                 # nee_path with its defaults
CONFIG_NAMES = tuple(name for name, *_ in CONFIGS)

# scenes of the default (multi-scene) run and the configurations benchmarked on each
DEFAULT_SCENES = (
    ("scenes/veach_mis.xml", CONFIG_NAMES),
    ("scenes/cornell_box.xml", ("path", "nee_path_mitsuba", "nee_path")),
)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG), description=__doc__.split("\n")[0])
    ap.add_argument("--scene", action="append", default=None,
                    help="scene file (repeatable); default: every scene of DEFAULT_SCENES, one "
                         "subprocess each, results merged")
    ap.add_argument("--configs", default=None,
                    help="comma-separated configurations (default: per scene, see "
                         f"DEFAULT_SCENES; all otherwise): {','.join(CONFIG_NAMES)}")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel of each timed render")
    ap.add_argument("--repeats", type=int, default=7, help="timed rounds (round-robin)")
    ap.add_argument("--max-depth", type=int, default=8, help="max_depth of path, bsdf_path and nee_path")
    ap.add_argument("--variant", default=None,
                    help="Mitsuba variant (default: llvm_ad_rgb, i.e. integrators.DEFAULT_VARIANT)")
    ap.add_argument("--out", default="benchmarks/results/speed.json")
    args = ap.parse_args(argv)
    if args.spp < 1 or args.repeats < 1:
        ap.error("--spp and --repeats must be >= 1")
    if args.configs is not None:
        names = [c.strip() for c in args.configs.split(",") if c.strip()]
        bad = [c for c in names if c not in CONFIG_NAMES]
        if bad:
            ap.error(f"--configs: unknown {', '.join(bad)}; allowed: {', '.join(CONFIG_NAMES)}")
        args.configs = names
    return args


def _configs_for(scene: str, requested) -> tuple:
    """Configurations to benchmark on ``scene``, in :data:`CONFIGS` order (``path`` always)."""
    if requested is None:
        default = {str(Path(s)): c for s, c in DEFAULT_SCENES}
        requested = default.get(str(Path(scene)), CONFIG_NAMES)
    want = set(requested) | {"path"}
    # a ratio needs its base configuration
    for ours, base in RATIOS + EXTRA_RATIOS:
        if ours in want:
            want.add(base)
    return tuple(name for name in CONFIG_NAMES if name in want)


def _kernel_stats(dr, history):
    """Summary of the JIT kernels of one render (from ``dr.kernel_history()``)."""
    ks = [h for h in history if h.get("type") == dr.KernelType.JIT]
    main = max(ks, key=lambda h: h.get("operation_count", 0), default={})
    return {
        "kernels": len(ks),
        "cache_hits": sum(int(h.get("cache_hit", 0)) for h in ks),
        "execution_ms": sum(float(h.get("execution_time", 0.0)) for h in ks),
        "codegen_ms": sum(float(h.get("codegen_time", 0.0)) for h in ks),
        "backend_ms": sum(float(h.get("backend_time", 0.0)) for h in ks),
        "main_kernel_ops": int(main.get("operation_count", 0)),
        "main_kernel_size": int(main.get("size", 0)),
    }


def run(args):
    import integrators
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    variant = args.variant or integrators.DEFAULT_VARIANT
    try:
        integrators.set_variant(variant)
    except (ValueError, RuntimeError) as e:
        raise SystemExit(f"benchmarks.speed: {e}") from None

    scene_file = args.scene[0]
    names = _configs_for(scene_file, args.configs)
    CONF = tuple(c for c in CONFIGS if c[0] in names)
    scene = mi.load_file(scene_file)
    film = scene.sensors()[0].film()
    width, height = (int(v) for v in film.size())
    samples = width * height * args.spp

    integs = {}
    for name, kind, d, desc in CONF:
        d = dict(d)
        if name in PATH_DEPTH:
            d["max_depth"] = args.max_depth
        integs[name] = (mi.load_dict(d), d)

    def render(name, seed):
        return timing.timed_render(scene, integs[name][0], args.spp, seed)

    order = list(integs)
    t_start = timing.clock()
    # warm-up: compile (or load from the kernel cache), one render per configuration
    warm = timing.round_robin(render, order, rounds=0, warmup=1, seed=lambda rnd, name: 10_000)
    diag, means = {}, {}
    history_was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for name in order:
            dr.kernel_history()                          # clear
            _, wall = render(name, 20_000)
            diag[name] = {"wall_ms": wall * 1e3, **_kernel_stats(dr, dr.kernel_history())}
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, history_was)

    def image_mean(name, rnd, warmup, img, dt):
        if rnd == args.repeats - 1:
            arr = np.asarray(img, dtype=np.float64)
            means[name] = [float(v) for v in arr.reshape(-1, arr.shape[-1]).mean(0)[:3]]

    # timed rounds, fixed round-robin order, seed = round
    times = timing.round_robin(render, order, rounds=args.repeats, warmup=0,
                               on_render=image_mean).timed
    warmup = {name: warm.warmup[name][0] for name in order}
    total = timing.clock() - t_start

    configs = {}
    for name, kind, _, desc in CONF:
        sps = [samples / t for t in times[name]]
        st = timing.stats(times[name])
        configs[name] = {
            "kind": kind,
            "description": desc,
            "integrator": integs[name][1],
            "median_samples_per_s": statistics.median(sps),
            "best_samples_per_s": max(sps),
            "median_seconds": st["median"],
            "min_seconds": st["min"],
            "max_seconds": st["max"],
            "seconds": times[name],
            "samples_per_s": sps,
            "warmup_seconds": warmup[name],
            "diagnostic_render": diag[name],
            "image_mean_rgb_last_round": means[name],
        }

    ratios = {}
    for ours, base in RATIOS + EXTRA_RATIOS:
        if ours not in times or base not in times:
            continue
        per_round = [tb / to for to, tb in zip(times[ours], times[base])]
        ratios[f"{ours} / {base}"] = {
            "median_of_per_round_ratios": statistics.median(per_round),
            "ratio_of_medians": (configs[ours]["median_samples_per_s"]
                                 / configs[base]["median_samples_per_s"]),
            "ratio_of_best": (configs[ours]["best_samples_per_s"]
                              / configs[base]["best_samples_per_s"]),
            "per_round": per_round,
            "min": min(per_round),
            "max": max(per_round),
        }

    return {
        "benchmark": "benchmarks.speed",
        "command": args.command,
        "date_utc": provenance.now_utc(),
        "git": provenance.git_state(),
        "machine": {**provenance.machine(), "drjit_threads": dr.thread_count()},
        "mitsuba_version": mi.__version__,
        "drjit_version": dr.__version__,
        "variant": mi.variant(),
        "libllvm": integrators.LLVM_PATH,
        "scene": scene_file,
        "width": width,
        "height": height,
        "spp": args.spp,
        "samples_per_render": samples,
        "repeats": args.repeats,
        "max_depth": args.max_depth,
        "rr_depth": 5,
        "order": [name for name, *_ in CONF],
        "method": ("one process, one scene; one warm-up render per config (excluded), one "
                   "diagnostic render with kernel history (excluded); then `repeats` rounds, each "
                   "rendering every config once in the order given (round-robin), seed = round; "
                   "time = perf_counter around mi.render + dr.eval + dr.sync_thread; "
                   "samples/s = width*height*spp/time; median over rounds"),
        "ratio_definition": ("samples/s of ours divided by samples/s of the built-in (> 1: ours "
                             "faster). Headline: median over rounds of the per-round ratio "
                             "(t_builtin / t_ours in the same round); ratio of the medians also "
                             "given."),
        "total_seconds": total,
        "configs": configs,
        "ratios": ratios,
        "extra_ratios": [f"{a} / {b}" for a, b in EXTRA_RATIOS if a in times and b in times],
    }


def _ratio_text(r, base=None) -> str:
    vs = f" vs `{base}`" if base else ""
    return (f"{r['median_of_per_round_ratios']:.2f}{vs} "
            f"(rounds {r['min']:.2f}-{r['max']:.2f})")


def _scene_body(res) -> list:
    """Table and notes of one scene's result."""
    lines = [
        "| configuration | median M samples/s | best M samples/s | median s/render (min-max) "
        "| ratio ours/built-in (extra rows: vs the named one) |",
        "|---|---:|---:|---:|---:|",
    ]
    extra = set(res["extra_ratios"])
    rat, ext = {}, {}
    for k, v in res["ratios"].items():
        ours, base = k.split(" / ")
        (ext if k in extra else rat)[ours] = (v, base)
    for name, c in res["configs"].items():
        if name in rat:
            rtxt = _ratio_text(rat[name][0])
        elif name in ext:
            rtxt = _ratio_text(*ext[name])
        else:
            rtxt = ""
        lines.append(f"| {c['description']} | {c['median_samples_per_s'] / 1e6:.2f} | "
                     f"{c['best_samples_per_s'] / 1e6:.2f} | "
                     f"{c['median_seconds']:.3f} ({c['min_seconds']:.3f}-{c['max_seconds']:.3f}) | "
                     f"{rtxt} |")
    main = [(k, v) for k, v in res["ratios"].items() if k not in extra]
    extras = [(k, v) for k, v in res["ratios"].items() if k in extra]
    lines += [
        "",
        ((("Ratios of the medians: "
          + ", ".join(f"{k} {v['ratio_of_medians']:.2f}" for k, v in main) + "; "
          "of the best (fastest) renders: "
          + ", ".join(f"{k} {v['ratio_of_best']:.2f}" for k, v in main) + ".") if main else "")
        + (" Extra (median per-round ratio): "
           + ", ".join(f"{k} {v['median_of_per_round_ratios']:.2f}" for k, v in extras) + "."
           if extras else "")).strip(),
        "",
        "Image mean (RGB average) of each configuration's last render, a diagnostic "
        "(same-estimator pairs should agree within noise): "
        + ", ".join(f"{n} {sum(c['image_mean_rgb_last_round']) / 3:.4f}"
                    for n, c in res["configs"].items()) + ".",
        "",
    ]
    return lines


_NOTES = [
    "Ratio = samples/s of ours / samples/s of the built-in (> 1: ours is faster), median over "
    "rounds of the per-round ratio (each round renders every configuration once, round-robin, "
    "so the two of a pair run seconds apart); the range over rounds in brackets. Extra rows: "
    "`direct_mis_power` vs `direct_mis` (the cost of selecting lights by power instead of "
    "uniformly), `nee_path` with its defaults vs `path`.",
    "",
    "`direct_mis` (uniform light selection, 1 light + 1 BSDF sample, power heuristic) is the "
    "same estimator as `direct` with `emitter_samples=1, bsdf_samples=1`, and `nee_path` with "
    "`heuristic=power, light_selection=uniform, rr=throughput, light_samples=1, split=1` the same "
    "estimator as `path` (same `max_depth`, `rr_depth` 5): those ratios compare equal work. "
    "`bsdf_path` has **no light sampling**, so it is not the same estimator as "
    "`path` (no shadow rays, different noise, different path lengths): that ratio is the "
    "cost per sample only, not efficiency (variance x time).",
    "",
    "Each scene is loaded once, at its own resolution; each integrator is built with "
    "`mi.load_dict` and passed to `mi.render(scene, integrator=...)`. "
    "Timings exclude JIT compilation (one warm-up render per configuration). Samples/s = "
    "width x height x spp / seconds of `mi.render(...); dr.eval(img); dr.sync_thread()`. "
    "Measured on a shared, noisy machine (other load can slow single renders 2-3x: see the "
    "max in the s/render column; the median and the per-round ratios absorb that): compare "
    "ratios from one run, not absolute numbers across runs. All timings and per-round "
    "ratios are in the JSON file next to this one.",
    "",
]


def _scene_header(res) -> str:
    return (f"Scene `{res['scene']}` at {res['width']}x{res['height']}, {res['spp']} spp per "
            f"render, {res['repeats']} rounds, `max_depth` {res['max_depth']} (`path`, "
            f"`bsdf_path`, `nee_path`).")


def _machine_line(res) -> str:
    m = res["machine"]
    return (f"Variant `{res['variant']}`, Mitsuba {res['mitsuba_version']}, Dr.Jit "
            f"{res['drjit_version']}; {m['cpu_model']}, {m['cpu_count']} CPUs, "
            f"{m['drjit_threads']} Dr.Jit threads; {res['date_utc']}.")


def markdown(res) -> str:
    """Markdown of a single-scene result or of a merged (multi-scene) one."""
    lines = ["# Speed: our integrators vs Mitsuba's built-ins", ""]
    if "scenes" in res:
        lines += [
            f"{len(res['scenes'])} scenes, one process each (every BSDF alive in a process is "
            "compiled into its kernels). " + _machine_line(res["scenes"][0]) +
            f" Total wall time {res['total_seconds']:.0f} s.",
            "",
            "Headline (median of per-round ratios, range over rounds):",
            "",
        ]
        for r in res["scenes"]:
            lines.append(f"- `{r['scene']}`: " + "; ".join(
                f"{k} {_ratio_text(v)}" for k, v in r["ratios"].items()))
        lines.append("")
        for r in res["scenes"]:
            lines += [f"## `{r['scene']}`", "", _scene_header(r), "", *_scene_body(r)]
        lines += ["## Notes", ""]
    else:
        lines += [_scene_header(res) + " " + _machine_line(res), "", *_scene_body(res)]
    lines += [*_NOTES, *provenance.command_block(res["command"])]
    if "scenes" in res:
        lines += ["which ran, one process per scene (each also with `--out` a temporary file):",
                  "", "```",
                  *(r["subprocess_command"] for r in res["scenes"]), "```", ""]
    return "\n".join(lines)


def run_scenes(args, scenes) -> dict:
    """Each scene in its own subprocess; the single-scene results merged."""
    t0 = timing.clock()
    results = []
    with tempfile.TemporaryDirectory(prefix="speed-") as tmp:
        for i, scene in enumerate(scenes):
            out = Path(tmp) / f"scene{i}.json"
            cmd = ["--scene", scene, "--configs", ",".join(_configs_for(scene, args.configs)),
                   "--spp", str(args.spp), "--repeats", str(args.repeats),
                   "--max-depth", str(args.max_depth)]
            if args.variant:
                cmd += ["--variant", args.variant]
            child = f"{CHILD} {shlex.join(cmd)}"
            print(f"[{scene}] {child}", flush=True)
            subprocess.run([sys.executable, "-m", "benchmarks.speed", *cmd, "--out", str(out)],
                           env=provenance.subprocess_env(), check=True,
                           stdout=subprocess.DEVNULL)
            r = json.loads(out.read_text())
            # the subprocess's own command without its temporary --out
            r["command"] = r["subprocess_command"] = child
            results.append(r)
    return {
        "benchmark": "benchmarks.speed",
        "command": args.command,
        "date_utc": provenance.now_utc(),
        "git": provenance.git_state(),
        "mode": "one subprocess per scene, results merged; each entry of `scenes` is that "
                "scene's single-scene result",
        "total_seconds": timing.clock() - t0,
        "summary": {r["scene"]: {k: {"median_of_per_round_ratios": v["median_of_per_round_ratios"],
                                     "min": v["min"], "max": v["max"]}
                                 for k, v in r["ratios"].items()} for r in results},
        "scenes": results,
    }


def main(argv=None):
    from integrators.app.imageio import write_text
    args = parse_args(argv)
    args.command = provenance.command(PROG, argv)
    scenes = args.scene or [s for s, _ in DEFAULT_SCENES]
    res = run(args) if len(scenes) == 1 and args.scene else run_scenes(args, scenes)
    out = Path(args.out)
    write_text(out, json.dumps(res, indent=2) + "\n")
    md = markdown(res)
    write_text(out.with_suffix(".md"), md)
    print(md)
    print(f"wrote {out} and {out.with_suffix('.md')} ({res['total_seconds']:.1f} s)")


if __name__ == "__main__":
    main()
