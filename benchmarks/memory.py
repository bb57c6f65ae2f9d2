r"""Peak memory of a render as spp grows: progressive passes against one ``mi.render`` call.

    python -m benchmarks.memory [--scene scenes/veach_mis.xml] [--spp 64 256 1024 4096]
                                [--out benchmarks/results/memory.json]

Each measurement runs in a fresh process (peak RSS from ``getrusage``), on the demo scene at its
own resolution.  ``progressive`` is :func:`integrators.app.progressive.render` (passes of at
most 2^24 samples); ``single`` is one ``mi.render(scene, spp=N)``, which keeps every sample's
wavefront state in memory at once.  The claim measured: progressive peak RSS stays flat as spp
grows.  Each child also reports its render's wall time (:mod:`benchmarks.timing`: the single
render timed as every benchmark times one, the progressive one around the whole call).
Results: ``--out`` (JSON) and a Markdown table next to it (``.md``), written atomically, with
the command that ran.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

from . import provenance, timing
from .config import REPO

PROG = "python -m benchmarks.memory"
MODES = ("progressive", "single")


def child(scene_path, spp, mode):
    import integrators  # noqa: F401
    import mitsuba as mi
    from integrators.app import progressive
    scene = mi.load_file(scene_path)
    if mode == "progressive":
        _, seconds = timing.timed(progressive.render, scene, spp=spp, seed=0)
    else:
        _, seconds = timing.timed_render(scene, None, spp, 0)
    print(json.dumps({"peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,  # Linux
                      "seconds": seconds}))


def main(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/veach_mis.xml")
    ap.add_argument("--spp", type=int, nargs="+", default=[64, 256, 1024, 4096])
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "memory.json"))
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        return child(a.child[0], int(a.child[1]), a.child[2])
    from integrators.app.imageio import write_text
    command = provenance.command(PROG, argv)
    scene = str(Path(a.scene).resolve())        # the children run in the repository
    rows = []
    for spp in a.spp:
        row = {"spp": spp}
        for mode in MODES:
            r = subprocess.run([sys.executable, "-m", "benchmarks.memory", "--child", scene,
                                str(spp), mode], capture_output=True, text=True, cwd=REPO,
                               env=provenance.subprocess_env())
            res = None
            if r.returncode == 0:
                try:
                    res = json.loads(r.stdout.strip().splitlines()[-1])
                except (ValueError, IndexError):
                    res = None
            row[mode + "_peak_mib"] = round(res["peak_kib"] / 1024, 1) if res else None
            row[mode + "_seconds"] = round(res["seconds"], 3) if res else None
            if res is None:
                print(f"{mode} at {spp} spp failed: {r.stderr.strip()[-500:]}", file=sys.stderr)
        rows.append(row)
        print(row, flush=True)
    write_text(a.out, json.dumps({"command": command, "date_utc": provenance.now_utc(),
                                  "git": provenance.git_state(), "machine": provenance.machine(),
                                  "scene": a.scene, "rows": rows}, indent=2))
    md = ["# Peak memory against spp", "", f"Scene `{a.scene}`, each run in a fresh process.", "",
          "| spp | progressive peak RSS (MiB) | one mi.render call (MiB) |", "|---:|---:|---:|"]
    md += [f"| {r['spp']} | {r['progressive_peak_mib']} | {r['single_peak_mib']} |" for r in rows]
    md += ["", *provenance.command_block(command)]
    write_text(Path(a.out).with_suffix(".md"), "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
