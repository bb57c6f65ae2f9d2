"""Writes the heavy mesh of scenes/ears_heavy_mesh.xml: a bumpy sphere of about a million
triangles (binary PLY, about 18 MB) in out/meshes/ (untracked: generated, not stored).

    python scenes/tools/make_ears_heavy_mesh.py [--n 720]

The mesh is an n x 2n latitude-longitude grid (4 n^2 triangles) displaced radially by
0.04 sin(9 theta) sin(11 phi) + 0.02 sin(23 theta + 17 phi): fine relief, so camera rays and
every later ray traverse a deep BVH (the "expensive first hit" of the EARS experiments)."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "out" / "meshes" / "ears_heavy.ply"


def make(n: int = 720, path: Path = OUT) -> Path:
    theta = np.linspace(0.0, np.pi, n + 1)
    phi = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    r = 1.0 + 0.04 * np.sin(9 * t) * np.sin(11 * p) + 0.02 * np.sin(23 * t + 17 * p)
    v = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], -1)
    v = v.reshape(-1, 3).astype("<f4")
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a = i * 2 * n + j
    b = i * 2 * n + (j + 1) % (2 * n)
    c = a + 2 * n
    d = b + 2 * n
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                        np.stack([b, d, c], -1).reshape(-1, 3)]).astype("<i4")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        fh.write((f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  f"element face {len(f)}\nproperty list uchar int vertex_indices\n"
                  "end_header\n").encode())
        rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", 3)])
        rec["n"], rec["i"] = 3, f
        fh.write(v.tobytes())
        fh.write(rec.tobytes())
    tmp.replace(path)
    return path


def ensure(path: Path = OUT) -> Path:
    """The mesh, written first if it is missing."""
    return path if path.exists() else make(path=path)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=720)
    print(make(ap.parse_args().n))
