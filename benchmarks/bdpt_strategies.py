"""Veach's strategy figure for ``bdpt``: each (s, t) strategy's weighted contribution.

    python -m benchmarks.bdpt_strategies [--scene caustic] [--spp 256] [--res 96]
                                         [--out benchmarks/results/bdpt]

Renders the scene with ``strategy_images=true`` and writes a grid of the layers ``s<s>_t<t>``
(rows: path length s + t - 1 in segments, columns: s), each tone-mapped like the full image,
as ``<scene>_strategies.png``: the picture that shows which strategy carries which light.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from .config import REPO, scene_file


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="caustic")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--max-depth", type=int, default=4)
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "bdpt")
    a = ap.parse_args(argv)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mitsuba as mi
    import numpy as np
    import integrators  # noqa: F401

    scene = mi.load_file(str(scene_file(a.scene)), res=str(a.res))
    integ = mi.load_dict({"type": "bdpt", "max_depth": a.max_depth, "strategy_images": True})
    img = mi.render(scene, integrator=integ, spp=a.spp, seed=1)
    bmp = mi.Bitmap(img, channel_names=["R", "G", "B"] + integ.aov_names())
    layers = dict(bmp.split())
    full = np.array(layers["<root>"], dtype=np.float64)[..., :3]
    scale = 1.0 / max(np.quantile(full, 0.99), 1e-8)
    names = sorted(k for k in layers if re.fullmatch(r"s\d+_t\d+", k))
    st = [tuple(int(x) for x in re.findall(r"\d+", k)) for k in names]
    lengths = sorted({s + t - 1 for s, t in st})
    cols = max(s for s, _ in st) + 1
    fig, axes = plt.subplots(len(lengths) + 1, cols, figsize=(2.2 * cols, 2.2 * (len(lengths) + 1)))
    for ax in np.ravel(axes):
        ax.axis("off")

    def show(ax, x, title):
        ax.imshow(np.clip((x * scale) ** (1 / 2.2), 0, 1))
        ax.set_title(title, fontsize=8)

    show(axes[0, 0], full, f"{a.scene}: all strategies")
    for (s, t), k in zip(st, names):
        show(axes[lengths.index(s + t - 1) + 1, s], np.array(layers[k])[..., :3],
             f"s={s}, t={t}")
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / f"{a.scene}_strategies.png"
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
