r"""Speed of our integrators against Mitsuba's built-in ones, in one process.

    python -m benchmarks.speed [--scene scenes/veach_mis.xml] [--spp 64] [--repeats 7]
                               [--max-depth 8] [--variant llvm_ad_rgb]
                               [--out benchmarks/results/speed.json]

Configurations (see :data:`CONFIGS`): our ``bsdf_path`` (BSDF sampling) against the built-in
``path`` with the same ``max_depth`` (and the default ``rr_depth`` 5 in both), and our
``direct_mis`` (1 light sample, 1 BSDF sample, power heuristic, uniform light selection: the
estimator of the built-in ``direct`` with ``emitter_samples=1, bsdf_samples=1``) against
``direct``; ``direct_mis`` with light selection by power is an extra row.

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
  ``time.perf_counter`` around ``mi.render(...); dr.eval(img); dr.sync_thread()``;
* samples/s = width * height * spp / seconds; the median over rounds per configuration;
* ratios ``ours / built-in`` of samples/s (> 1: ours is faster): the headline value is the
  median of the per-round ratios (each round's pair ran seconds apart, which cancels slow drift
  of the machine's load); the ratio of the medians and of the best (fastest) renders are
  recorded too, and, as an extra, ``direct_mis_power / direct_mis``;
* a diagnostic: the image mean of each configuration's last render (same-estimator pairs should
  agree within noise).

``bsdf_path`` has no light sampling, so it is not the same estimator as ``path`` (different
noise, different number of rays per path): that ratio compares cost per sample only.

Results: a JSON file (``--out``) and a Markdown table next to it (same name, ``.md``).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

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
)
PATH_DEPTH = ("path", "bsdf_path")   # configurations that take max_depth
RATIOS = (("bsdf_path", "path"), ("direct_mis", "direct"))
EXTRA_RATIOS = (("direct_mis_power", "direct_mis"),)   # cost of light selection by power


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.speed", description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="scenes/veach_mis.xml")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel of each timed render")
    ap.add_argument("--repeats", type=int, default=7, help="timed rounds (round-robin)")
    ap.add_argument("--max-depth", type=int, default=8, help="max_depth of path and bsdf_path")
    ap.add_argument("--variant", default=None,
                    help="Mitsuba variant (default: llvm_ad_rgb, i.e. integrators.DEFAULT_VARIANT)")
    ap.add_argument("--out", default="benchmarks/results/speed.json")
    args = ap.parse_args(argv)
    if args.spp < 1 or args.repeats < 1:
        ap.error("--spp and --repeats must be >= 1")
    return args


def _git_state():
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=REPO, capture_output=True,
                               text=True, check=True).stdout.strip() != ""
        return {"commit": head, "dirty": dirty}
    except (OSError, subprocess.CalledProcessError):
        return None


def _cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


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

    scene = mi.load_file(args.scene)
    film = scene.sensors()[0].film()
    width, height = (int(v) for v in film.size())
    samples = width * height * args.spp

    integs = {}
    for name, kind, d, desc in CONFIGS:
        d = dict(d)
        if name in PATH_DEPTH:
            d["max_depth"] = args.max_depth
        integs[name] = (mi.load_dict(d), d)

    def render(integ, seed):
        t0 = time.perf_counter()
        img = mi.render(scene, integrator=integ, spp=args.spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return time.perf_counter() - t0, img

    t_start = time.perf_counter()
    warmup, diag, means = {}, {}, {}
    for name, (integ, _) in integs.items():
        warmup[name], _ = render(integ, 10_000)          # compile (or load from the kernel cache)
    history_was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for name, (integ, _) in integs.items():
            dr.kernel_history()                          # clear
            wall, _ = render(integ, 20_000)
            diag[name] = {"wall_ms": wall * 1e3, **_kernel_stats(dr, dr.kernel_history())}
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, history_was)

    times = {name: [] for name in integs}
    for k in range(args.repeats):
        for name, (integ, _) in integs.items():
            t, img = render(integ, k)
            times[name].append(t)
            if k == args.repeats - 1:
                arr = np.asarray(img, dtype=np.float64)
                means[name] = [float(v) for v in arr.reshape(-1, arr.shape[-1]).mean(0)[:3]]
            del img
    total = time.perf_counter() - t_start

    configs = {}
    for name, kind, _, desc in CONFIGS:
        sps = [samples / t for t in times[name]]
        configs[name] = {
            "kind": kind,
            "description": desc,
            "integrator": integs[name][1],
            "median_samples_per_s": statistics.median(sps),
            "best_samples_per_s": max(sps),
            "median_seconds": statistics.median(times[name]),
            "min_seconds": min(times[name]),
            "max_seconds": max(times[name]),
            "seconds": times[name],
            "samples_per_s": sps,
            "warmup_seconds": warmup[name],
            "diagnostic_render": diag[name],
            "image_mean_rgb_last_round": means[name],
        }

    ratios = {}
    for ours, base in RATIOS + EXTRA_RATIOS:
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

    command = "python -m benchmarks.speed" + (" " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "")
    return {
        "benchmark": "benchmarks.speed",
        "command": command,
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "git": _git_state(),
        "machine": {
            "platform": platform.platform(),
            "machine": platform.machine(),
            "cpu_model": _cpu_model(),
            "cpu_count": os.cpu_count(),
            "cpu_affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "drjit_threads": dr.thread_count(),
            "python": platform.python_version(),
        },
        "mitsuba_version": mi.__version__,
        "drjit_version": dr.__version__,
        "variant": mi.variant(),
        "libllvm": integrators.LLVM_PATH,
        "scene": args.scene,
        "width": width,
        "height": height,
        "spp": args.spp,
        "samples_per_render": samples,
        "repeats": args.repeats,
        "max_depth": args.max_depth,
        "rr_depth": 5,
        "order": [name for name, *_ in CONFIGS],
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
        "extra_ratios": [f"{a} / {b}" for a, b in EXTRA_RATIOS],
    }


def markdown(res) -> str:
    m = res["machine"]
    lines = [
        "# Speed: our integrators vs Mitsuba's built-ins",
        "",
        f"Scene `{res['scene']}` at {res['width']}x{res['height']}, {res['spp']} spp per render, "
        f"{res['repeats']} rounds, `max_depth` {res['max_depth']} (`path`, `bsdf_path`), "
        f"variant `{res['variant']}`, Mitsuba {res['mitsuba_version']}, Dr.Jit "
        f"{res['drjit_version']}; {m['cpu_model']}, {m['cpu_count']} CPUs, "
        f"{m['drjit_threads']} Dr.Jit threads; {res['date_utc']}.",
        "",
        "| configuration | median M samples/s | best M samples/s | median s/render (min-max) "
        "| ratio ours/built-in |",
        "|---|---:|---:|---:|---:|",
    ]
    rat = {k.split(" / ")[0]: v for k, v in res["ratios"].items()
           if k not in res["extra_ratios"]}
    for name, c in res["configs"].items():
        r = rat.get(name)
        rtxt = (f"{r['median_of_per_round_ratios']:.2f} (rounds {r['min']:.2f}-{r['max']:.2f})"
                if r else "")
        lines.append(f"| {c['description']} | {c['median_samples_per_s'] / 1e6:.2f} | "
                     f"{c['best_samples_per_s'] / 1e6:.2f} | "
                     f"{c['median_seconds']:.3f} ({c['min_seconds']:.3f}-{c['max_seconds']:.3f}) | "
                     f"{rtxt} |")
    lines += [
        "",
        "Ratio = samples/s of ours / samples/s of the built-in (> 1: ours is faster), median over "
        "rounds of the per-round ratio (each round renders every configuration once, round-robin, "
        "so the two of a pair run seconds apart). Ratios of the medians: "
        + ", ".join(f"{k} {v['ratio_of_medians']:.2f}" for k, v in res["ratios"].items()
                    if k not in res["extra_ratios"]) + "; "
        "of the best (fastest) renders: "
        + ", ".join(f"{k} {v['ratio_of_best']:.2f}" for k, v in res["ratios"].items()
                    if k not in res["extra_ratios"]) + ". "
        "Extra: " + ", ".join(f"{k} {v['median_of_per_round_ratios']:.2f}"
                              for k, v in res["ratios"].items() if k in res["extra_ratios"])
        + " (median per-round ratio: the cost of selecting lights by power instead of "
        "uniformly).",
        "",
        "`direct_mis` (uniform light selection, 1 light + 1 BSDF sample, power heuristic) is the "
        "same estimator as `direct` with `emitter_samples=1, bsdf_samples=1`: that ratio compares "
        "equal work. `bsdf_path` has **no light sampling**, so it is not the same estimator as "
        "`path` (no shadow rays, different noise, different path lengths): that ratio is the "
        "cost per sample only, not efficiency (variance x time).",
        "",
        "The scene is loaded once, at its own resolution; each integrator is built with "
        "`mi.load_dict` and passed to `mi.render(scene, integrator=...)`. "
        "Timings exclude JIT compilation (one warm-up render per configuration). Samples/s = "
        "width x height x spp / seconds of `mi.render(...); dr.eval(img); dr.sync_thread()`. "
        "Measured on a shared, noisy machine (other load can slow single renders 2-3x: see the "
        "max in the s/render column; the median and the per-round ratios absorb that): compare "
        "ratios from one run, not absolute numbers across runs. All timings and per-round "
        "ratios are in the JSON file next to this one.",
        "",
        "Command:",
        "",
        "```",
        res["command"],
        "```",
        "",
    ]
    return "\n".join(lines)


def main(argv=None):
    args = parse_args(argv)
    res = run(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2) + "\n")
    md = markdown(res)
    out.with_suffix(".md").write_text(md)
    print(md)
    print(f"wrote {out} and {out.with_suffix('.md')} ({res['total_seconds']:.1f} s of rendering)")


if __name__ == "__main__":
    main()
