r"""Efficiency of ``nee_path rr=adaptive`` (EARS roulette and splitting) against the classic
roulette, fixed splitting and Mitsuba's ``path`` (issue 16).

    python -m benchmarks.ears [--scenes ears_indirect_room ...] [--res 64] [--spp 16 64 256]
                              [--repeats 3] [--ref-spp 8192] [--out benchmarks/results/ears]
                              [--single]

Every render of every method is a *fresh* integrator rendering its budget in passes of doubling
size (1/16, 1/16, 1/8, 1/4, 1/2 of the budget: the schedule of EARS's training iterations),
the passes' images averaged by their sample counts, or with ``--single`` in one
``mi.render`` call (as a user renders a scene); a learning method (``rr=adaptive``) learns
from its own earlier passes (or parts of the call) inside that budget, so its learning is in
the measured time.  The
methods of one scene render in turn (round robin, rotated every repeat), so a shared machine's
load falls on all alike.

* relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01)
  (:mod:`benchmarks.metrics`), minus the reference's own contribution (its variance estimated
  from its passes), so ratios are not pulled towards 1 by the reference's noise;
* efficiency = 1 / (relMSE x seconds), relMSE averaged over the repeats and seconds their median;
  the table gives each method's efficiency relative to ``nee_path`` with throughput roulette at
  the same budget, and what ``rr=adaptive`` traced (rays per camera sample).

The reference is Mitsuba's ``path`` at ``--ref-spp`` (cached in ``out/ears_refs``).  Results:
``--out``/results.json, a markdown table (``ears.md``) and one chart per scene (relMSE against
time), with the command that ran.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from . import provenance
from .config import PATH_DEPTH, REPO
from .config import SCENES as EXPERIMENT_SCENES
from .metrics import EPS, relmse

PROG = "python -m benchmarks.ears"
SCENES = ("ears_indirect_room", "ears_dark_bright", "ears_glossy", "ears_heavy_mesh",
          # the experiments' hard kinds (issue 16's floor: never below 0.9x on any of them):
          # light through glass, a glass sphere in a null box and a mirror, a caustic, light
          # through a gap; rendered at their own max_depth (8)
          "glass_shade", "specular_box", "caustic", "ajar_door",
          # the experiment scenes lit mostly directly (the floor there too), at the
          # experiments' max_depth (4) and defines
          "veach_mis", "cornell_box", "many_lights", "small_light", "sharp_glossy",
          # a room lit through a window by the sky and the sun (infinite emitters, most shadow
          # rays blocked by the walls): a kind none of the others is, added after the
          # thirteen's run (2026-12-06)
          "ears_window")
METHODS = {
    "path": ({"type": "path"}, "Mitsuba's built-in `path` (throughput roulette from depth 5)"),
    "nee_path": ({"type": "nee_path", "rr": "throughput"},
                 "`nee_path`, throughput roulette from depth 5 (the baseline)"),
    "nee_path_split4": ({"type": "nee_path", "rr": "throughput", "split": 4},
                        "`nee_path`, 4 continuations from the first hit, throughput roulette"),
    "ears": ({"type": "nee_path", "rr": "adaptive"},
             "`nee_path rr=adaptive` (default `split_policy=auto`): EARS's learned roulette at "
             "every vertex, learned from the render's own earlier passes, and splitting at the "
             "first hit while a split pass estimates that it pays over the roulette"),
    "ears_never": ({"type": "nee_path", "rr": "adaptive", "split_policy": "never"},
                   "`nee_path rr=adaptive split_policy=never`: the learned roulette only, "
                   "one kernel"),
    "ears_split": ({"type": "nee_path", "rr": "adaptive", "split_policy": "always"},
                   "`nee_path rr=adaptive split_policy=always`: EARS roulette and splitting, the "
                   "first hit's copies one after another in the megakernel's lane"),
}
BASELINE = "nee_path"
#: what ``rr=adaptive`` counts as rays traced (its ``stats``)
RAYS = ("camera_rays", "continuation_rays", "shadow_rays")
#: fractions of a budget per pass (doubling passes)
SCHEDULE = (1, 1, 2, 4, 8)


def pass_sizes(spp: int, single: bool = False) -> list:
    """Doubling passes summing to ``spp`` (fewer passes for small budgets); ``single``: one."""
    total = sum(SCHEDULE)
    if spp < total or single:
        return [spp]
    sizes = [spp * k // total for k in SCHEDULE]
    sizes[-1] += spp - sum(sizes)
    return [s for s in sizes if s > 0]


def scene_max_depth(name: str) -> int:
    """The ``max_depth`` a scene file declares as its default (an experiment scene that
    declares none: the experiments' path depth; else -1)."""
    import re
    text = (REPO / "scenes" / f"{name}.xml").read_text()
    m = re.search(r'<default name="max_depth" value="(-?\d+)"', text)
    if m:
        return int(m.group(1))
    return PATH_DEPTH if name in EXPERIMENT_SCENES else -1


def render_budget(scene, integrator_dict, spp: int, seed: int, single: bool = False):
    """(image, seconds, stats) of one fresh integrator rendering ``spp`` in passes (``single``:
    one render call)."""
    import drjit as dr
    import mitsuba as mi
    from .timing import clock
    t0 = clock()
    integ = mi.load_dict(integrator_dict)
    acc, stats = None, {}
    for k, m in enumerate(pass_sizes(spp, single)):
        img = mi.render(scene, integrator=integ, spp=m, seed=seed * 64 + k) * (m / spp)
        acc = img if acc is None else acc + img
        dr.eval(acc)
        for key, v in getattr(integ, "stats", {}).items():
            if isinstance(v, int) and key != "max_lanes":
                stats[key] = stats.get(key, 0) + v
    dr.sync_thread()
    return np.array(acc, np.float64), clock() - t0, stats


def reference(name: str, scene, res: int, spp: int, passes: int = 8):
    """(mean, relMSE of the reference itself) of Mitsuba's path at ``spp``, cached."""
    import drjit as dr
    import mitsuba as mi
    cache = REPO / "out" / "ears_refs" / f"{name}_{res}_{spp}.npz"
    if cache.exists():
        z = np.load(cache)
        return z["mean"], float(z["self"])
    integ = mi.load_dict({"type": "path", "max_depth": scene_max_depth(name)})
    imgs = []
    for k in range(passes):
        img = mi.render(scene, integrator=integ, spp=spp // passes, seed=10_000_000 + k)
        dr.eval(img)
        imgs.append(np.array(img, np.float64))
    imgs = np.stack(imgs)
    mean = imgs.mean(0)
    var = imgs.var(0, ddof=1) / passes
    own = float(np.mean(var / (mean ** 2 + EPS)))
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, mean=mean, self=own)
    return mean, own


def load_scene(name: str, res: int):
    import mitsuba as mi
    if name == "ears_heavy_mesh":
        sys.path.insert(0, str(REPO / "scenes" / "tools"))
        from make_ears_heavy_mesh import ensure
        ensure()
    defines = EXPERIMENT_SCENES[name].defines(res) if name in EXPERIMENT_SCENES \
        else {"res": str(res)}
    return mi.load_file(str(REPO / "scenes" / f"{name}.xml"), **defines)


def run_scene(name, res, budgets, repeats, ref_spp, methods, log=print, single=False):
    import integrators  # noqa: F401
    scene = load_scene(name, res)
    ref, ref_self = reference(name, scene, res, ref_spp)
    log(f"{name}: reference {ref_spp} spp, its own relMSE {ref_self:.3g}")
    rows = {m: {} for m in methods}
    depth = {"max_depth": scene_max_depth(name)}
    for spp in budgets:
        errs = {m: [] for m in methods}
        secs = {m: [] for m in methods}
        stats = {m: {} for m in methods}
        for rep in range(repeats + 1):                    # round 0: warm-up (compilation)
            order = methods[rep % len(methods):] + methods[:rep % len(methods)]
            for m in order:
                img, dt, st = render_budget(scene, {**METHODS[m][0], **depth}, spp,
                                            seed=1000 * rep + spp, single=single)
                if rep == 0:
                    continue
                errs[m].append(max(relmse(img, ref) - ref_self, 1e-12))
                secs[m].append(dt)
                for k, v in st.items():
                    stats[m][k] = stats[m].get(k, 0) + v / repeats
        for m in methods:
            e, t = float(np.mean(errs[m])), float(np.median(secs[m]))
            rows[m][spp] = {"relmse": e, "seconds": t, "efficiency": 1.0 / (e * t),
                            "relmse_each": errs[m], "seconds_each": secs[m], "stats": stats[m]}
        base = rows[BASELINE][spp]["efficiency"] if BASELINE in rows else None
        log(f"  {spp} spp: " + ", ".join(
            f"{m} {rows[m][spp]['seconds']:.2f}s relMSE {rows[m][spp]['relmse']:.3g}"
            + (f" x{rows[m][spp]['efficiency'] / base:.2f}" if base else "") for m in methods))
    return {"ref_spp": ref_spp, "ref_relmse_self": ref_self, "methods": rows}


def chart(path, name, res_rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from integrators.app.imageio import write_with
    fig, ax = plt.subplots(figsize=(4.8, 3.6))
    for i, (m, rows) in enumerate(res_rows["methods"].items()):
        b = sorted(rows, key=int)
        ax.loglog([rows[s]["seconds"] for s in b], [rows[s]["relmse"] for s in b], marker="o",
                  ms=3, color="black" if m == BASELINE else f"C{i}", label=m)
    from matplotlib.ticker import NullFormatter
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("time per render, learning included (s)")
    ax.set_ylabel("relMSE (reference's own removed)")
    ax.set_title(name, fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=100))
    plt.close(fig)


def table(results, budgets, command, single=False) -> str:
    how = "one render call" if single else "doubling passes"
    md = ["# EARS: efficiency-aware roulette and splitting (issue 16)", "",
          "Efficiency = 1 / (relMSE x seconds), relative to `nee_path` with throughput "
          "roulette at the same budget (higher is better); every render a fresh integrator, "
          f"its budget in {how}, learning in the time.  `rays/sample`: rays traced "
          "per camera sample by `rr=adaptive` (closest-hit + shadow) in its own kernel's "
          "passes (the plain passes or parts after a fallback run `nee_path`'s kernel and "
          "are not counted).  `ears time`, `ears relMSE`: the two factors of its efficiency, "
          "its median seconds and its mean relMSE over `nee_path`'s (a shortfall in time is "
          "cost; in relMSE, where it runs `nee_path`'s kernel, the spread of a few repeats).",
          ""]
    # (the methods that ran, in METHODS's order: the header matches the cells)
    present = [m for m in METHODS if any(m in r["methods"] for r in results.values())]
    for m in present:
        md.append(f"- `{m}`: {METHODS[m][1]}")
    md += ["", "| scene | spp | " + " | ".join(present)
           + " | ears time | ears relMSE | ears rays/sample |",
           "|---|---:|" + "---:|" * (len(present) + 3)]
    for name, res in results.items():
        for spp in budgets:
            rows = res["methods"]
            base = rows[BASELINE][spp]["efficiency"]
            cells = [f"{rows[m][spp]['efficiency'] / base:.2f}x" if m in rows else "-"
                     for m in present]
            ours = rows.get("ears", {}).get(spp, {})
            st = ours.get("stats", {})
            cam = st.get("camera_samples", 0)
            # (none counted where every pass ran nee_path's kernel: a bound part, plain)
            rays = "-"
            if cam:
                rays = f"{sum(st.get(k, 0) for k in RAYS) / cam:.2f}"
            factors = [f"{ours[k] / rows[BASELINE][spp][k]:.2f}x" if ours else "-"
                       for k in ("seconds", "relmse")]
            md.append(f"| {name} | {spp} | " + " | ".join(cells + factors) + f" | {rays} |")
    md += ["", "Seconds and relMSE of every render: `results.json`.", "", "```", command, "```"]
    return "\n".join(md)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=provenance.invoked_as(PROG),
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=8192)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "ears"))
    ap.add_argument("--single", action="store_true",
                    help="each budget in one render call instead of doubling passes")
    a = ap.parse_args(argv)
    if BASELINE not in a.methods:
        a.methods.insert(0, BASELINE)
    from integrators.app.imageio import write_text
    command = provenance.command(PROG, argv)
    out = Path(a.out)
    results = {}
    for name in a.scenes:
        results[name] = run_scene(name, a.res, a.spp, a.repeats, a.ref_spp, a.methods,
                                  single=a.single)
        chart(out / f"{name}.png", name, results[name])
        write_text(out / "results.json", json.dumps(provenance.record(
            command, res=a.res, single=a.single, results=results), indent=1))
        write_text(out / "ears.md", table(results, a.spp, command, a.single))
    print(table(results, a.spp, command, a.single))


if __name__ == "__main__":
    main()
