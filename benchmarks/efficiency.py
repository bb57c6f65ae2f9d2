r"""Efficiency of light selection (uniform, power, adaptive) on scenes/many_lights.xml.

    python -m benchmarks.efficiency [--spp 16] [--repeats 5] [--ref-spp 8192] [--res 128]
                                    [--out benchmarks/results/efficiency.json]
                                    [--cache DIR] [--no-cache]

Efficiency = 1 / (relMSE x time), relMSE = mean over pixels and channels of
(x - ref)^2 / (ref^2 + 0.01) (:mod:`benchmarks.metrics`), for ``nee_path`` (max_depth 4) with
each ``light_selection``.  The reference is Mitsuba's own ``path`` (max_depth 4) at ``ref-spp``
in 16 passes, from the experiments' reference cache (:mod:`benchmarks.references`: same key,
same files); its own relMSE, from its variance layer, is reported and must be far below the
measured errors (``path`` selects among the 64 lights uniformly: it needs more samples than
the estimators it judges).  Timing (:mod:`benchmarks.timing`): one warm-up render each
(compilation excluded), then each round renders every method once, round-robin, with a fresh
seed; relMSE is averaged and time is the median over rounds.  Ratios are relative to
``uniform``.  Results: JSON plus a Markdown table next to it, written atomically, with the
command that ran.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import provenance, references, timing
from .config import REFERENCE_SEED, REPO, cache_default, scene_file
from .metrics import relmse

PROG = "python -m benchmarks.efficiency"
SCENE = scene_file("many_lights")
METHODS = ("uniform", "power", "adaptive")
MAX_DEPTH = 4
REF_PASSES = 16


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=8192,
                    help=f"samples per pixel of the reference (a multiple of {REF_PASSES})")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "efficiency.json"))
    ap.add_argument("--cache", default=str(cache_default()),
                    help="reference cache folder (default %(default)s)")
    ap.add_argument("--no-cache", action="store_true", help="render the reference afresh, keep none")
    a = ap.parse_args(argv)
    if a.spp < 1 or a.repeats < 1 or a.res < 1:
        ap.error("--spp, --repeats and --res must be >= 1")
    if a.ref_spp < REF_PASSES or a.ref_spp % REF_PASSES:
        ap.error(f"--ref-spp must be a positive multiple of {REF_PASSES}")
    return a


def main(argv=None):
    a = parse_args(argv)
    command = provenance.command(PROG, argv)
    import integrators  # noqa: F401  (variant + plugin registration)
    import mitsuba as mi
    import numpy as np

    from integrators.app.imageio import write_text
    defines = {"res": str(a.res)}
    scene = mi.load_file(str(SCENE), **defines)
    w, h = (int(v) for v in scene.sensors()[0].film().crop_size())
    spec = references.ReferenceSpec(
        name="many_lights", scene_path=SCENE, defines=defines, width=w, height=h,
        max_depth=MAX_DEPTH, spp=a.ref_spp, passes=REF_PASSES,
        seed_first=REFERENCE_SEED["path"])
    ref, _, ref_info = references.get(spec, scene, None if a.no_cache else Path(a.cache))
    ref_relmse = ref_info["relmse_self"]

    integ = {m: mi.load_dict({"type": "nee_path", "max_depth": MAX_DEPTH, "light_selection": m})
             for m in METHODS}
    rows = {m: {"relmse": [], "time_s": []} for m in METHODS}

    def error(name, rnd, warm, img, dt):
        if not warm:
            rows[name]["relmse"].append(relmse(np.array(img, dtype=np.float64)[..., :3], ref))

    # warm-up round (seed 0) compiles; timed rounds r = 1..repeats use seed r
    t = timing.round_robin(lambda m, seed: timing.timed_render(scene, integ[m], a.spp, seed),
                           METHODS, rounds=a.repeats, warmup=1, on_render=error)
    for m in METHODS:
        rows[m]["time_s"] = t.timed[m]
    result = {"benchmark": "benchmarks.efficiency", "command": command,
              "date_utc": provenance.now_utc(), "git": provenance.git_state(),
              "scene": str(SCENE.relative_to(REPO)), "resolution": a.res, "spp": a.spp,
              "repeats": a.repeats,
              "reference": {"integrator": ref_info["integrator"], "spp": a.ref_spp,
                            "passes": REF_PASSES, "relmse": ref_relmse,
                            "key": ref_info.get("key"), "cached": ref_info["cached"],
                            "file": ref_info["file"]},
              "integrator": {"type": "nee_path", "max_depth": MAX_DEPTH},
              "variant": mi.variant(), "mitsuba": mi.__version__,
              "machine": provenance.machine(), "methods": {}}
    base = None
    for m in METHODS:
        e = float(np.mean(rows[m]["relmse"]))
        tm = float(timing.stats(rows[m]["time_s"])["median"])
        eff = 1.0 / (e * tm)
        base = base or eff
        result["methods"][m] = {"relmse": e, "time_s": tm, "efficiency": eff,
                                "efficiency_vs_uniform": eff / base,
                                "relmse_rounds": rows[m]["relmse"],
                                "time_s_rounds": rows[m]["time_s"]}
    out = Path(a.out)
    write_text(out, json.dumps(result, indent=2) + "\n")
    lines = ["# Light selection efficiency on `many_lights`", "",
             f"`nee_path` (max_depth {MAX_DEPTH}) at {w}x{h}, {a.spp} spp, {a.repeats} rounds "
             f"round-robin, `{mi.variant()}`; reference: Mitsuba `path` (max_depth {MAX_DEPTH}) "
             f"at {a.ref_spp} spp (its own relMSE {ref_relmse:.2e}).", "",
             "| light_selection | relMSE | time (s) | efficiency 1/(relMSE x time) | vs uniform |",
             "|---|---:|---:|---:|---:|"]
    for m in METHODS:
        r = result["methods"][m]
        lines.append(f"| {m} | {r['relmse']:.4g} | {r['time_s']:.3f} | {r['efficiency']:.4g} "
                     f"| {r['efficiency_vs_uniform']:.2f} |")
    lines += ["", *provenance.command_block(command)]
    write_text(out.with_suffix(".md"), "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
