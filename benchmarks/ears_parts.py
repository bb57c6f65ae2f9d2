r"""One render call of ``nee_path rr=adaptive`` with and without the part rule (issue 16).

    python -m benchmarks.ears_parts [--scenes many_lights veach_mis ...] [--res 96]
                                    [--spp 16 32] [--repeats 8]
                                    [--out benchmarks/results/ears_parts]

While a part decides the mode, a call is rendered in parts (:meth:`EARS.part
<integrators.sampling.splitting.EARS.part>`); a part after the first is split off only where
the samples left are worth its measured fixed cost (``WEIGH_PART_COST``).  Per scene and
budget, a fresh integrator renders one call with the rule on and one with it off, in turn
(rotated every repeat, so the host's load falls on both), and ``nee_path`` with throughput
roulette for scale; seconds are medians, with each integrator's kernels compiled once before
the timed calls.  The images of the two differ only in which kernel renders which samples, so
their time ratio is the efficiency ratio.  Output: ``--out``/results.json and
``ears_parts.md``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from . import provenance
from .config import REPO
from .ears import SCENES, load_scene, scene_max_depth

PROG = "python -m benchmarks.ears_parts"
DEFAULT_SCENES = ("many_lights", "veach_mis", "cornell_box", "small_light")
METHODS = ("rule", "no_rule", "nee_path")


def one_call(scene, method: str, depth: int, spp: int, seed: int):
    """(seconds, parts) of one fresh integrator's render call."""
    import drjit as dr
    import mitsuba as mi
    from integrators.sampling import splitting
    adaptive = method != "nee_path"
    splitting.WEIGH_PART_COST = method == "rule"
    try:
        integ = mi.load_dict({"type": "nee_path", "max_depth": depth,
                              "rr": "adaptive" if adaptive else "throughput"})
        t0 = time.perf_counter()
        dr.eval(mi.render(scene, integrator=integ, spp=spp, seed=seed))
        dr.sync_thread()
        seconds = time.perf_counter() - t0
    finally:
        splitting.WEIGH_PART_COST = True
    return seconds, (integ.stats.get("parts") if adaptive else None)


def run_scene(name: str, res: int, budgets, repeats: int) -> dict:
    scene = load_scene(name, res)
    depth = scene_max_depth(name)
    rows = {}
    for spp in budgets:
        for m in METHODS:       # (kernels compiled once, outside the times)
            one_call(scene, m, depth, spp, 99)
        times = {m: [] for m in METHODS}
        parts = {}
        for r in range(repeats):
            for m in METHODS[r % len(METHODS):] + METHODS[:r % len(METHODS)]:
                t, p = one_call(scene, m, depth, spp, r)
                times[m].append(t)
                parts[m] = p
        med = {m: float(np.median(times[m])) for m in METHODS}
        rows[spp] = {"seconds": med, "seconds_each": times,
                     "parts": {m: [list(x) for x in parts[m]] for m in ("rule", "no_rule")},
                     "no_rule_over_rule": med["no_rule"] / med["rule"]}
        print(f"{name} {spp} spp: rule {med['rule'] * 1e3:.1f} ms {parts['rule']}, no rule "
              f"{med['no_rule'] * 1e3:.1f} ms {parts['no_rule']}, nee_path "
              f"{med['nee_path'] * 1e3:.1f} ms", flush=True)
    return rows


def table(results: dict, command: str) -> str:
    lines = ["# One render call with and without the part rule (issue 16)", "",
             "Median seconds of one `mi.render` call of a fresh integrator. `no rule / rule` is "
             "the time ratio, which is the efficiency ratio (same samples, same estimators).", "",
             "| scene | spp | parts with the rule | parts without | rule ms | no rule ms "
             "| nee_path ms | no rule / rule |", "|---|---:|---|---|---:|---:|---:|---:|"]
    for name, rows in results.items():
        for spp, r in rows.items():
            s = r["seconds"]
            fmt = lambda p: " ".join(f"{m} {n}" for m, n in p)  # noqa: E731
            lines.append(f"| {name} | {spp} | {fmt(r['parts']['rule'])} | "
                         f"{fmt(r['parts']['no_rule'])} | {s['rule'] * 1e3:.1f} | "
                         f"{s['no_rule'] * 1e3:.1f} | {s['nee_path'] * 1e3:.1f} | "
                         f"{r['no_rule_over_rule']:.2f}x |")
    lines += ["", *provenance.command_block(command)]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES), choices=SCENES)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "ears_parts"))
    a = ap.parse_args(argv)
    import integrators  # noqa: F401  (the plugins, and a variant as benchmarks.ears has)
    from integrators.app.imageio import write_text
    command = provenance.command(PROG, argv)
    out = Path(a.out)
    results = {}
    for name in a.scenes:
        results[name] = run_scene(name, a.res, a.spp, a.repeats)
        write_text(out / "results.json", json.dumps(provenance.record(
            command, res=a.res, results=results), indent=1))
        write_text(out / "ears_parts.md", table(results, command))
    print(table(results, command))


if __name__ == "__main__":
    main()
