r"""What a copy at the first hit holds: EARS's split unit against the reference's (issue 16).

    python -m benchmarks.ears_unit [--scenes veach_mis ...] [--res 96] [--spp 64] [--repeats 4]
                                   [--ref-spp 4096] [--out benchmarks/results/ears_unit]

Until 42bf9ef ``nee_path rr=adaptive`` split at the first hit the continuation only: the
vertex's light samples were taken once, on arrival.  The authors' implementation of EARS (Rath
et al. 2022, ``recursive_path.cpp``) and ``nee_path split=k`` put the light samples inside each
copy, and since 42bf9ef so does ``rr=adaptive`` where the first hit splits
(:mod:`integrators.sampling.splitting`).  With the copies' number fixed, the three give the
relMSE each unit leaves at the same camera samples, and the times say what the learned
kernel's copies cost against ``split=k``'s:

* ``nee_path``: one continuation (throughput roulette), the baseline;
* ``split4``: ``nee_path split=4``: four copies, each with its own light samples at the hit;
* ``ears_n4``: ``rr=adaptive`` with n forced to 4 at every vertex (``split_depth`` 1: four
  copies from the first hit, each with its own light samples there; before 42bf9ef four copies
  of the continuation, the hit's light samples once: ``benchmarks/results/ears_unit_283a320``);
* ``ears_n1``: the same kernel with n forced to 1 (no roulette, no splitting): its cost.

Each render is one ``mi.render`` call of a fresh integrator, ``--repeats`` seeds (the methods
in turn, rotated every repeat; one render each before, its kernels' compilation untimed);
relMSE as in :mod:`benchmarks.ears` (against Mitsuba's ``path`` at ``--ref-spp``, its own
noise removed), seconds the median.  Output: ``--out``/results.json and ``ears_unit.md``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from . import provenance
from .config import REPO
from .ears import SCENES, load_scene, reference, scene_max_depth
from .metrics import relmse

PROG = "python -m benchmarks.ears_unit"
METHODS = ("nee_path", "split4", "ears_n4", "ears_n1")
DEFAULT_SCENES = ("veach_mis", "cornell_box", "small_light", "sharp_glossy", "specular_box")


def integrator(method: str, max_depth: int):
    import mitsuba as mi
    from integrators.sampling import splitting
    d = {"type": "nee_path", "max_depth": max_depth}
    if method == "split4":
        d["split"] = 4
    if method.startswith("ears"):
        d.update(rr="adaptive", split_policy="always")
    integ = mi.load_dict(d)
    if method.startswith("ears"):
        integ.forced_factor = splitting.fixed_factor(4.0 if method == "ears_n4" else 1.0)
    return integ


def run_scene(name: str, res: int, spp: int, repeats: int, ref_spp: int) -> dict:
    import drjit as dr
    import mitsuba as mi
    scene = load_scene(name, res)
    depth = scene_max_depth(name)
    ref, ref_self = reference(name, scene, res, ref_spp)
    rows = {m: {"relmse_each": [], "seconds_each": []} for m in METHODS}
    for m in METHODS:       # (each kernel compiled once, outside the times)
        dr.eval(mi.render(scene, integrator=integrator(m, depth), spp=spp, seed=99))
    for r in range(repeats):
        for m in METHODS[r % len(METHODS):] + METHODS[:r % len(METHODS)]:
            integ = integrator(m, depth)
            t0 = time.perf_counter()
            img = mi.render(scene, integrator=integ, spp=spp, seed=100 + r)
            dr.eval(img)
            dr.sync_thread()
            rows[m]["seconds_each"].append(time.perf_counter() - t0)
            rows[m]["relmse_each"].append(
                max(relmse(np.array(img, np.float64), ref) - ref_self, 1e-12))
    for row in rows.values():
        row["relmse"] = float(np.mean(row["relmse_each"]))
        row["seconds"] = float(np.median(row["seconds_each"]))
    base = rows["nee_path"]
    for row in rows.values():
        row["relmse_lowered"] = base["relmse"] / row["relmse"]
        row["efficiency_vs_nee_path"] = (base["relmse"] * base["seconds"]) / (
            row["relmse"] * row["seconds"])
    print(f"{name}: " + ", ".join(
        f"{m} relMSE {rows[m]['relmse']:.4g} (x{rows[m]['relmse_lowered']:.2f} lower) "
        f"{rows[m]['seconds']:.3f}s" for m in METHODS), flush=True)
    return rows


def table(results: dict, command: str) -> str:
    lines = ["# EARS's split unit against the reference's (issue 16)", "",
             "Per scene, the same camera samples in one render call: how much each unit lowers "
             "`nee_path`'s relMSE, and its time (median). `split4`: four copies at the first "
             "hit, each with its own light samples (the reference's unit); `ears_n4`: "
             "`rr=adaptive` with n forced to four: four copies at the first hit in its learned "
             "kernel (on commits before 42bf9ef of the continuation only, the hit's light "
             "samples once); `ears_n1`: the same kernel, one copy.", "",
             "| scene | split4 relMSE lower | ears_n4 relMSE lower | split4 s | ears_n4 s "
             "| ears_n1 s | nee_path s |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['split4']['relmse_lowered']:.2f}x | "
                     f"{r['ears_n4']['relmse_lowered']:.2f}x | {r['split4']['seconds']:.3f} | "
                     f"{r['ears_n4']['seconds']:.3f} | {r['ears_n1']['seconds']:.3f} | "
                     f"{r['nee_path']['seconds']:.3f} |")
    lines += ["", *provenance.command_block(command)]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES), choices=SCENES)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "ears_unit"))
    a = ap.parse_args(argv)
    import integrators  # noqa: F401  (the plugins, and a variant as benchmarks.ears has)
    from integrators.app.imageio import write_text
    command = provenance.command(PROG, argv)
    out = Path(a.out)
    results = {}
    for name in a.scenes:
        results[name] = run_scene(name, a.res, a.spp, a.repeats, a.ref_spp)
        write_text(out / "results.json", json.dumps(provenance.record(
            command, res=a.res, spp=a.spp, results=results), indent=1))
        write_text(out / "ears_unit.md", table(results, command))
    print(table(results, command))


if __name__ == "__main__":
    main()
