r"""A split pass's time per unit of work against a roulette pass's (issue 16: ``SPLIT_COST``).

    python -m benchmarks.ears_split_cost [--scenes ears_indirect_room ajar_door ...]
                                         [--res 96] [--spp 64] [--repeats 7]
                                         [--out benchmarks/results/ears_split_cost]

Per scene a fresh ``nee_path rr=adaptive split_policy=always`` learns a table (calls of 4 to
64 spp), the table is frozen, and passes of ``--spp`` in the ``split`` and the ``roulette``
mode alternate (the order swapped every repeat, so the host's load falls on both; the first
pair, which compiles the kernels, left out).  Per mode: the relMSE against the benchmark's
reference, the median seconds and the work of the cost model (``EARS.pass_cost``: rays, a
shadow ray counting ``SHADOW_COST``, a camera sample ``CAMERA_COST``).  The time ratio over the
work ratio is the split pass's time per unit of work relative to the roulette's, which
``SPLIT_COST`` stands for; the relMSE ratio over the time ratio is splitting's measured
efficiency over the roulette.  Output: ``--out``/results.json and ``ears_split_cost.md``.
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

PROG = "python -m benchmarks.ears_split_cost"
DEFAULT_SCENES = ("ears_indirect_room", "ajar_door", "ears_glossy", "ears_heavy_mesh")
MODES = ("split", "roulette")


def run_scene(name: str, res: int, spp: int, repeats: int, ref_spp: int) -> dict:
    import drjit as dr
    import mitsuba as mi
    from .metrics import relmse
    scene = load_scene(name, res)
    ref, _ = reference(name, scene, res, ref_spp)
    integ = mi.load_dict({"type": "nee_path", "rr": "adaptive", "split_policy": "always",
                          "max_depth": scene_max_depth(name)})
    for k, n in enumerate((4, 8, 16, 32, 64)):
        dr.eval(mi.render(scene, integrator=integ, spp=n, seed=1000 + k))
    ears = integ.ears
    ears.learning = False
    rows = {m: [] for m in MODES}
    for r in range(repeats):
        for m in MODES if r % 2 else MODES[::-1]:
            ears.mode = m
            dr.sync_thread()
            t0 = time.perf_counter()
            img = mi.render(scene, integrator=integ, spp=spp, seed=5000 + r)
            dr.eval(img)
            dr.sync_thread()
            seconds = time.perf_counter() - t0
            assert integ.stats["mode"] == m, integ.stats
            rows[m].append((relmse(np.array(img, np.float64), ref), seconds,
                            float(ears.pass_cost)))
    s, q = (np.array(rows[m][1:]) for m in MODES)
    err = float(q[:, 0].mean() / s[:, 0].mean())
    t = float(np.median(s[:, 1]) / np.median(q[:, 1]))
    work = float(s[:, 2].mean() / q[:, 2].mean())
    out = {"relmse_gain": err, "time_ratio": t, "work_ratio": work,
           "time_per_work": t / work, "efficiency": err / t, "each": rows}
    print(f"{name}: split/roulette time per unit of work {t / work:.3f}, efficiency "
          f"{err / t:.3f} (relMSE gain {err:.3f}, time {t:.3f}, work {work:.3f})", flush=True)
    return out


def table(results: dict, command: str) -> str:
    lines = ["# A split pass against a roulette pass with the same frozen table (issue 16)", "",
             "Ratios split / roulette over alternating passes (the first pair left out): time "
             "per unit of the cost model's work (what `SPLIT_COST` stands for) and efficiency "
             "(relMSE gain over time ratio).", "",
             "| scene | time per unit of work | efficiency | relMSE gain | time | work |",
             "|---|---:|---:|---:|---:|---:|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['time_per_work']:.3f} | {r['efficiency']:.3f} | "
                     f"{r['relmse_gain']:.3f} | {r['time_ratio']:.3f} | {r['work_ratio']:.3f} |")
    lines += ["", *provenance.command_block(command)]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES), choices=SCENES)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "ears_split_cost"))
    a = ap.parse_args(argv)
    if a.repeats < 2:
        ap.error(f"--repeats {a.repeats}: must be at least 2 (the first pair is left out)")
    import integrators  # noqa: F401  (the plugins, and a variant as benchmarks.ears has)
    from integrators.app.imageio import write_text
    command = provenance.command(PROG, argv)
    out = Path(a.out)
    results = {}
    for name in a.scenes:
        results[name] = run_scene(name, a.res, a.spp, a.repeats, a.ref_spp)
        write_text(out / "results.json", json.dumps(provenance.record(
            command, res=a.res, spp=a.spp, results=results), indent=1))
        write_text(out / "ears_split_cost.md", table(results, command))
    print(table(results, command))


if __name__ == "__main__":
    main()
