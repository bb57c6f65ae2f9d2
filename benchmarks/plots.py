"""Figures of the experiments, written atomically (:func:`integrators.app.imageio.write_with`).

* :func:`chart`: log-log relMSE against time per render, one panel per group, the baseline in
  black, the reference's own relMSE dashed;
* :func:`grid`: equal-time images, one column per method (the reference first), rows: sRGB
  image, a zoomed crop, the per-pixel relative squared error (log colour scale).
"""
from __future__ import annotations

import numpy as np

from integrators.app.imageio import write_with

from .config import GROUPS
from .metrics import EPS, srgb

BUILTINS = ("path", "direct")     # Mitsuba's integrators among the methods


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def chart(path, scene: str, groups: dict, points: dict, ref_info: dict) -> None:
    """``groups``: {group: [Method, ...]}; ``points``: {label: [{time_s, relmse}, ...]};
    ``ref_info``: {group: {"relmse_self": ...}}."""
    plt = _pyplot()
    from matplotlib.ticker import NullFormatter
    gs = list(groups)
    fig, axes = plt.subplots(1, len(gs), figsize=(4.6 * len(gs), 3.6), squeeze=False)
    for ax, g in zip(axes[0], gs):
        for i, m in enumerate(groups[g]):
            pts = [p for p in points[m.label] if p["relmse"]]
            base = m.label == GROUPS[g]["baseline"]
            ax.loglog([p["time_s"] for p in pts], [p["relmse"] for p in pts],
                      marker="o", ms=3, lw=2.2 if base else 1.3,
                      color="black" if base else f"C{i}",
                      label=m.label + (" (Mitsuba)" if m.integrator["type"] in BUILTINS else ""))
        r = ref_info[g]["relmse_self"]
        if r > 0:
            ax.axhline(r, color="gray", ls="--", lw=1, label="reference's own relMSE")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("time per render (s)")
        ax.set_ylabel("relMSE")
        ax.set_title(f"{scene}: {GROUPS[g]['title']}", fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=100))
    plt.close(fig)


def crop_box(w: int, h: int, centre) -> tuple:
    """(x0, y0, side) of a square crop a quarter of the width wide around ``centre``."""
    side = max(8, w // 4)
    cx, cy = centre
    x0 = int(min(max(round(cx * w - side / 2), 0), w - side))
    y0 = int(min(max(round(cy * h - side / 2), 0), h - side))
    return x0, y0, side


def grid(path, scene: str, group: str, ref, var, ref_spp: int, renders: dict, target: float,
         crop_centre) -> None:
    """``renders``: {label: {"image", "spp", "time_s", "relmse"}} at about ``target`` s each."""
    plt = _pyplot()
    from matplotlib.colors import LogNorm
    from matplotlib.patches import Rectangle
    h, w = ref.shape[:2]
    cols = [("reference", ref, var / (ref ** 2 + EPS), None)]
    for label, r in renders.items():
        img = np.nan_to_num(r["image"])
        cols.append((label, img, (img - ref) ** 2 / (ref ** 2 + EPS), r))
    n = len(cols)
    aspect = h / w
    pw = 1.35
    fig = plt.figure(figsize=(pw * n + 0.6, pw * (2 * aspect + 1) + 0.75))
    gsp = fig.add_gridspec(3, n + 1, height_ratios=[aspect, 1, aspect],
                           width_ratios=[1] * n + [0.08], wspace=0.04, hspace=0.06,
                           left=0.01, right=0.95, top=0.86, bottom=0.01)
    x0, y0, side = crop_box(w, h, crop_centre)
    norm = LogNorm(vmin=1e-4, vmax=10)
    im = None
    for j, (label, img, err, r) in enumerate(cols):
        pre = srgb(img)
        ax = fig.add_subplot(gsp[0, j])
        ax.imshow(pre, interpolation="nearest")
        ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), side, side, fill=False, ec="cyan", lw=0.7))
        if r is None:
            title = f"reference\n{ref_spp} spp"
        else:
            title = (f"{label}\n{r['spp']} spp, {r['time_s']:.2f} s\n"
                     f"relMSE {r['relmse']:.3g}" if r["relmse"] is not None else label)
        ax.set_title(title, fontsize=6)
        ax2 = fig.add_subplot(gsp[1, j])
        ax2.imshow(pre[y0:y0 + side, x0:x0 + side], interpolation="nearest")
        ax3 = fig.add_subplot(gsp[2, j])
        im = ax3.imshow(np.clip(err.mean(axis=2), 1e-4, 10), norm=norm, cmap="magma",
                        interpolation="nearest")
        for a in (ax, ax2, ax3):
            a.set_xticks([])
            a.set_yticks([])
    cax = fig.add_subplot(gsp[2, n])
    cb = fig.colorbar(im, cax=cax)
    cb.ax.tick_params(labelsize=5)
    fig.suptitle(f"{scene}, {GROUPS[group]['title']}: equal time ~{target:.2f} s "
                 "(rows: sRGB, crop x4, relative squared error; reference column: its own "
                 "expected error)", fontsize=7)
    write_with(path, lambda tmp: (fig.savefig(tmp, dpi=100), shrink_png(tmp)))
    plt.close(fig)


def shrink_png(path) -> None:
    """Palette PNG (256 colours): a third of the size of an RGB one for these noisy images."""
    try:
        from PIL import Image
        img = Image.open(path).convert("RGB")
        img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
                     ).save(path, optimize=True)
    except Exception:
        pass
