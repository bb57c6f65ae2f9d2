r"""Peak memory of a render as spp grows: progressive passes against one ``mi.render`` call.

    python -m benchmarks.memory [--scene scenes/veach_mis.xml] [--spp 64 256 1024 4096]

Each measurement runs in a fresh process (peak RSS from ``getrusage``), on the demo scene at its
own resolution.  ``progressive`` is :func:`integrators.progressive.render` (passes of at most
2^24 samples); ``single`` is one ``mi.render(scene, spp=N)``, which keeps every sample's
wavefront state in memory at once.  The claim measured: progressive peak RSS stays flat as spp
grows.  Results: benchmarks/results/memory.json and memory.md.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(scene_path, spp, mode):
    import drjit as dr
    import integrators  # noqa: F401
    import mitsuba as mi
    from integrators.app import progressive
    scene = mi.load_file(scene_path)
    if mode == "progressive":
        progressive.render(scene, spp=spp, seed=0)
    else:
        img = mi.render(scene, spp=spp, seed=0)
        dr.eval(img)
        dr.sync_thread()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # KiB on Linux


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/veach_mis.xml")
    ap.add_argument("--spp", type=int, nargs="+", default=[64, 256, 1024, 4096])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "memory.json"))
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        return child(a.child[0], int(a.child[1]), a.child[2])
    rows = []
    for spp in a.spp:
        row = {"spp": spp}
        for mode in ("progressive", "single"):
            r = subprocess.run([sys.executable, "-m", "benchmarks.memory", "--child", a.scene,
                                str(spp), mode], capture_output=True, text=True, cwd=ROOT)
            row[mode + "_peak_mib"] = (round(int(r.stdout.split()[-1]) / 1024, 1)
                                       if r.returncode == 0 else None)
        rows.append(row)
        print(row, flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps({"scene": a.scene, "rows": rows}, indent=2))
    md = ["# Peak memory against spp", "", f"Scene `{a.scene}`, each run in a fresh process.", "",
          "| spp | progressive peak RSS (MiB) | one mi.render call (MiB) |", "|---:|---:|---:|"]
    md += [f"| {r['spp']} | {r['progressive_peak_mib']} | {r['single_peak_mib']} |" for r in rows]
    md += ["", "Command:", "", "```", "python -m benchmarks.memory", "```", ""]
    Path(a.out).with_suffix(".md").write_text("\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
