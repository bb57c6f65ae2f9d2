r"""Efficiency of light selection (uniform, power, adaptive) on scenes/many_lights.xml.

    python -m benchmarks.efficiency [--spp 16] [--repeats 5] [--ref-spp 2048] [--res 128]
                                    [--out benchmarks/results/efficiency.json]

Efficiency = 1 / (relMSE x time), relMSE = mean over pixels and channels of
(x - ref)^2 / (ref^2 + 0.01), for ``nee_path`` (max_depth 4) with each ``light_selection``.
The reference is a render with ``light_selection=adaptive`` at ``ref-spp`` (its own relMSE,
estimated from two halves, is reported and must be far below the measured errors).  Each round
renders every method once, round-robin, with a fresh seed; relMSE and time are averaged over
rounds; timings exclude compilation (one warm-up render each).  Ratios are relative to
``uniform``.  Results: JSON plus a Markdown table next to it.
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import integrators
import drjit as dr
import mitsuba as mi
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "many_lights.xml"
METHODS = ("uniform", "power", "adaptive")


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def render(scene, integ, spp, seed):
    t0 = time.perf_counter()
    img = mi.render(scene, integrator=integ, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return np.array(img, dtype=np.float64), time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "efficiency.json"))
    a = ap.parse_args(argv)
    scene = mi.load_file(str(SCENE), res=str(a.res))
    integ = {m: mi.load_dict({"type": "nee_path", "max_depth": 4, "light_selection": m})
             for m in METHODS}
    # reference: two independent halves give its own error estimate
    h1, _ = render(scene, integ["adaptive"], a.ref_spp // 2, 10_000)
    h2, _ = render(scene, integ["adaptive"], a.ref_spp // 2, 20_000)
    ref = 0.5 * (h1 + h2)
    ref_relmse = relmse(h1, h2) / 4.0   # var(mean of halves) = var(half difference) / 4
    for m in METHODS:
        render(scene, integ[m], a.spp, 0)  # compile
    rows = {m: {"relmse": [], "time_s": []} for m in METHODS}
    for r in range(a.repeats):
        for m in METHODS:
            img, t = render(scene, integ[m], a.spp, 1 + r)
            rows[m]["relmse"].append(relmse(img, ref))
            rows[m]["time_s"].append(t)
    result = {"scene": str(SCENE.relative_to(ROOT)), "resolution": a.res, "spp": a.spp,
              "repeats": a.repeats, "reference": {"spp": a.ref_spp, "relmse": ref_relmse},
              "integrator": {"type": "nee_path", "max_depth": 4},
              "variant": mi.variant(), "mitsuba": mi.__version__,
              "machine": {"platform": platform.platform(), "cpus": __import__("os").cpu_count()},
              "methods": {}}
    base = None
    for m in METHODS:
        e = float(np.mean(rows[m]["relmse"]))
        t = float(np.median(rows[m]["time_s"]))
        eff = 1.0 / (e * t)
        base = base or eff
        result["methods"][m] = {"relmse": e, "time_s": t, "efficiency": eff,
                                "efficiency_vs_uniform": eff / base,
                                "relmse_rounds": rows[m]["relmse"],
                                "time_s_rounds": rows[m]["time_s"]}
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    lines = ["# Light selection efficiency on `many_lights`", "",
             f"`nee_path` (max_depth 4) at {a.res}x{a.res}, {a.spp} spp, {a.repeats} rounds "
             f"round-robin, `{mi.variant()}`; reference: adaptive at {a.ref_spp} spp "
             f"(its own relMSE {ref_relmse:.2e}).", "",
             "| light_selection | relMSE | time (s) | efficiency 1/(relMSE x time) | vs uniform |",
             "|---|---:|---:|---:|---:|"]
    for m in METHODS:
        r = result["methods"][m]
        lines.append(f"| {m} | {r['relmse']:.4g} | {r['time_s']:.3f} | {r['efficiency']:.4g} "
                     f"| {r['efficiency_vs_uniform']:.2f} |")
    lines += ["", "Command:", "", "```", "python -m benchmarks.efficiency", "```", ""]
    out.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
