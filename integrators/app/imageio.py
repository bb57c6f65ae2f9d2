"""Image output: EXR (linear radiance) and an sRGB PNG preview, both written atomically.

A file is first written to a temporary name in the target directory and then renamed over the
target (``os.replace``), so a reader never sees a half-written image and an interrupted write
leaves the previous file intact.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import mitsuba as mi
import numpy as np


def _atomic(path: Path, write) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> Path:
    """A text file (JSON, Markdown), written atomically."""
    _atomic(Path(path), lambda tmp: Path(tmp).write_text(text))
    return Path(path)


def write_with(path, writer) -> Path:
    """Atomic write by any ``writer(tmp_path)`` that writes a whole file (a matplotlib figure,
    a PIL image); the temporary name keeps the suffix, so writers that infer the format work."""
    _atomic(Path(path), writer)
    return Path(path)


def to_bitmap(image, metadata: dict | None = None) -> "mi.Bitmap":
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    bmp = mi.Bitmap(arr, mi.Bitmap.PixelFormat.RGB if arr.shape[2] == 3 else
                    mi.Bitmap.PixelFormat.RGBA if arr.shape[2] == 4 else mi.Bitmap.PixelFormat.Y)
    if metadata:
        meta = bmp.metadata()
        for k, v in metadata.items():
            meta[str(k)] = str(v)
    return bmp


def write_exr(path, image, metadata: dict | None = None) -> Path:
    bmp = to_bitmap(image, metadata)
    _atomic(Path(path), lambda tmp: bmp.write(tmp, mi.Bitmap.FileFormat.OpenEXR))
    return Path(path)


def write_png(path, image) -> Path:
    """sRGB preview: values clipped to [0, 1] and encoded with Mitsuba's sRGB transfer curve."""
    bmp = to_bitmap(np.asarray(image, dtype=np.float32)[..., :3])
    png = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    _atomic(Path(path), lambda tmp: png.write(tmp, mi.Bitmap.FileFormat.PNG))
    return Path(path)


def write_layers(path, layers: dict, metadata: dict | None = None) -> Path:
    """EXR with named RGB layers ({"": rgb, "variance": rgb}) and string metadata."""
    names, arrays = [], []
    for layer, img in layers.items():
        prefix = f"{layer}." if layer else ""
        names += [prefix + c for c in "RGB"]
        arrays.append(np.asarray(img, dtype=np.float32)[..., :3])
    bmp = mi.Bitmap(np.concatenate(arrays, axis=2), mi.Bitmap.PixelFormat.MultiChannel,
                    channel_names=names)
    meta = bmp.metadata()
    for k, v in (metadata or {}).items():
        meta[str(k)] = str(v)
    _atomic(Path(path), lambda tmp: bmp.write(tmp, mi.Bitmap.FileFormat.OpenEXR))
    return Path(path)


def read_layers(path) -> tuple[dict, dict]:
    """({layer: HxWx3 array} with "" for the RGB layer, {metadata key: string})."""
    bmp = mi.Bitmap(str(path))
    layers = {("" if name == "<root>" else name): np.array(b, dtype=np.float32)
              for name, b in bmp.split()}
    meta = bmp.metadata()
    return layers, {k: meta[k] for k in meta.keys()}


def read_exr(path) -> np.ndarray:
    """The RGB layer of an EXR."""
    return read_layers(path)[0][""]
