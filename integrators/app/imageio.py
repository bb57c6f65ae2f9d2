"""Image files: EXR (linear radiance, through the ``OpenEXR`` module) and an sRGB PNG preview
(Mitsuba's Bitmap), both written atomically.

A file is first written to a temporary name in the target directory and then renamed over the
target (``os.replace``), so a reader never sees a half-written image and an interrupted or failed
write leaves the previous file intact.

EXR layout: named layers, the RGB layer as channels ``R, G, B`` and a layer ``name`` as
``name.R, name.G, name.B`` (1 channel: ``Y``, 4: ``RGBA``), 32-bit float, ZIP compression.
Header attributes are typed: Python ints as EXR ``int`` (32-bit; an int outside that range is
written as a string, never wrapped), floats as ``float`` (32-bit), strings as ``string``,
dicts and lists as JSON strings.  Any EXR reader (``mi.Bitmap``, OpenImageIO, Blender) loads
the RGB layer.
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from pathlib import Path

import mitsuba as mi
import numpy as np

#: header attributes every EXR has; ``read_layers`` leaves them out of the metadata it returns
STANDARD_ATTRIBUTES = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
    "screenWindowCenter", "screenWindowWidth", "type"})


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


def write_png(path, image) -> Path:
    """sRGB preview: values clipped to [0, 1] and encoded with Mitsuba's sRGB transfer curve."""
    bmp = to_bitmap(np.asarray(image, dtype=np.float32)[..., :3])
    png = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    _atomic(Path(path), lambda tmp: png.write(tmp, mi.Bitmap.FileFormat.PNG))
    return Path(path)


# ---------------------------------------------------------------------------------------------
# EXR through OpenEXR
def header_value(v):
    """A metadata value as a typed EXR attribute value (see the module docstring)."""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        v = int(v)
        return v if -2**31 <= v < 2**31 else str(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    if isinstance(v, str):
        return v
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v, sort_keys=True, default=str)
    return str(v)


_CHANNELS = {1: "Y", 3: "RGB", 4: "RGBA"}


def _channels(layers: dict) -> dict:
    out, shape = {}, None
    for layer, img in layers.items():
        arr = np.asarray(img, dtype=np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3 or arr.shape[2] not in _CHANNELS:
            raise ValueError(f"layer {layer!r}: shape {arr.shape}; expected HxW with 1, 3 or 4 "
                             "channels")
        if shape is not None and arr.shape[:2] != shape:
            raise ValueError(f"layer {layer!r}: size {arr.shape[:2]} differs from {shape}")
        shape = arr.shape[:2]
        prefix = f"{layer}." if layer else ""
        for i, c in enumerate(_CHANNELS[arr.shape[2]]):
            out[prefix + c] = np.ascontiguousarray(arr[..., i])
    if not out:
        raise ValueError("no layers to write")
    return out


def write_layers(path, layers: dict, metadata: dict | None = None) -> Path:
    """EXR with named layers ({"": rgb, "variance": rgb}) and typed header attributes."""
    import OpenEXR
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        if str(k) in STANDARD_ATTRIBUTES:
            raise ValueError(f"metadata key {k!r} is a standard EXR attribute")
        header[str(k)] = header_value(v)
    exr = OpenEXR.File(header, _channels(layers))

    def write(tmp):
        try:
            exr.write(tmp)
        except RuntimeError as e:      # OpenEXR reports I/O errors as RuntimeError
            raise OSError(" ".join(str(e).split())) from None
    _atomic(Path(path), write)
    return Path(path)


def write_exr(path, image, metadata: dict | None = None) -> Path:
    """EXR of one image (RGB, RGBA or Y) with typed header attributes."""
    return write_layers(path, {"": image}, metadata)


@contextlib.contextmanager
def _library_output_held():
    """Holds what the OpenEXR C++ library prints itself (warnings on stdout, errors on stderr)
    while a file is read: dropped when the read fails (the caller raises one clean line),
    passed on when it succeeds (it may be another thread's output)."""
    saved = []
    try:
        for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
            with contextlib.suppress(Exception):
                stream.flush()
            tmp = tempfile.TemporaryFile()
            saved.append((fd, os.dup(fd), tmp))
            os.dup2(tmp.fileno(), fd)
    except OSError:                    # no usable descriptors (embedded use): do not hold
        pass
    ok = False
    try:
        yield
        ok = True
    finally:
        for fd, orig, tmp in saved:
            os.dup2(orig, fd)
            os.close(orig)
            if ok:
                tmp.seek(0)
                data = tmp.read()
                if data:
                    os.write(fd, data)
            tmp.close()


def read_layers(path) -> tuple[dict, dict]:
    """({layer: HxWxC float32 array} with "" for the RGB layer, {header attribute: typed value}
    without the standard EXR attributes).  A file that is not a complete OpenEXR image raises
    ``ValueError("PATH: not an EXR written by render (...)")``."""
    import OpenEXR
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        with _library_output_held():
            with OpenEXR.File(str(path), separate_channels=True) as f:
                header = dict(f.header())
                channels = {n: np.asarray(c.pixels, dtype=np.float32)
                            for n, c in f.channels().items()}
    except (RuntimeError, ValueError, TypeError, OSError):
        raise ValueError(f"{path}: not an EXR written by render (not a complete OpenEXR image)") \
            from None
    groups: dict = {}
    for name, px in channels.items():
        layer, _, c = name.rpartition(".")
        groups.setdefault(layer, {})[c] = px
    layers = {}
    for layer, cs in groups.items():
        order = [c for c in ("R", "G", "B", "A") if c in cs] + \
            sorted(c for c in cs if c not in ("R", "G", "B", "A"))
        layers[layer] = np.stack([cs[c] for c in order], axis=-1)
    meta = {k: v for k, v in header.items() if k not in STANDARD_ATTRIBUTES}
    return layers, meta


def read_exr(path) -> np.ndarray:
    """The RGB layer of an EXR."""
    layers = read_layers(path)[0]
    if "" not in layers:
        raise ValueError(f"{path}: no RGB layer (layers: {', '.join(sorted(layers))})")
    return layers[""]
