"""Image files: EXR (linear radiance, through the ``OpenEXR`` module) and an sRGB PNG preview
(Mitsuba's Bitmap), both written atomically, alone or as a group.

A file is first written to a hidden temporary name beside the target (``.STEM.PID.RANDOM.SUFFIX``)
and then renamed over the target (``os.replace``), so a reader never sees a half-written image
and an interrupted or failed write leaves the previous file intact.  Files that belong together
(a render's EXR and its PNG) are written with :func:`write_together`: all temporaries first, then
all renames, undone if one fails, so they are replaced as a group or not at all.  Temporaries
that a killed process left (its PID no longer alive) are removed by the next write of the same
file.  Write errors are :class:`WriteError` (an OSError) naming the output, not the temporary.

EXR layout: named layers, the main layer as channels ``R, G, B`` and a layer ``name`` as
``name.R, name.G, name.B`` (or as the film names them: ``Y``, ``Y, A``, ``R, G, B, A``,
``X, Y, Z``, ...; by count when not given: 1 ``Y``, 2 ``YA``, 4 ``RGBA``), 32-bit float, ZIP
compression.
Header attributes are typed: Python ints as EXR ``int`` (32-bit; an int outside that range is
written as a string, never wrapped), floats as ``float`` (32-bit), strings as ``string``,
dicts and lists as JSON strings.  Any EXR reader (``mi.Bitmap``, OpenImageIO, Blender) loads
the RGB layer.
"""
from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

from .interrupt import test_pause

#: header attributes every EXR has; ``read_layers`` leaves them out of the metadata it returns
STANDARD_ATTRIBUTES = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
    "screenWindowCenter", "screenWindowWidth", "type"})


class WriteError(OSError):
    """An output could not be written; the message names the output (never a temporary file)
    and the reason, on one line: ``cannot write PATH: REASON``."""

    def __init__(self, err, path, reason):
        super().__init__(err, f"cannot write {path}: {reason}")
        self.filename = str(path)

    def __str__(self):
        return self.strerror


def _reason(e: BaseException, tmp: str | None, path: Path) -> str:
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    text = " ".join(str(e).split())
    if tmp:
        text = text.replace(str(tmp), str(path)).replace(os.path.basename(tmp), path.name)
    return text or type(e).__name__


def _test_fault(point: str) -> None:
    """Test-only hook: ``INTEGRATORS_TEST_FAULT=point[:ERRNO],...`` makes the step ``point``
    (``exr-write``, ``png-write``, ``exr-rename``, ``png-rename``) fail with that OSError
    (default ENOSPC), as a full disk or a failing rename would."""
    spec = os.environ.get("INTEGRATORS_TEST_FAULT")
    if not spec:
        return
    for item in spec.split(","):
        name, _, code = item.partition(":")
        if name == point:
            num = getattr(errno, code or "ENOSPC", errno.ENOSPC)
            raise OSError(num, os.strerror(num))


def _temporary(path: Path, tag: str = "") -> str:
    """A new hidden temporary file beside ``path``: ``.STEM.PID.RANDOM[.bak].SUFFIX`` (the
    process id lets a later run tell a dead process's leftovers from a live one's)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.{os.getpid()}.",
                               suffix=f"{tag}{path.suffix}", dir=path.parent)
    os.close(fd)
    return tmp


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def remove_stale_temporaries(path) -> list:
    """Remove the hidden temporary files of ``path`` that a killed process left (SIGKILL,
    power loss) -- those of processes no longer alive, and any of the older naming scheme
    (``.STEM.RANDOM.SUFFIX``) an hour old or more -- and return their names.  Those of a
    live process (a concurrent render of the same output) are left alone."""
    path = Path(path)
    stem, suffix = re.escape(path.stem), re.escape(path.suffix)
    current = re.compile(rf"^\.{stem}\.(\d+)\.\w+(?:\.bak)?{suffix}$")
    legacy = re.compile(rf"^\.{stem}\.\w{{8}}{suffix}$")
    removed = []
    try:
        names = os.listdir(path.parent if str(path.parent) else ".")
    except OSError:
        return removed
    for name in names:
        m = current.match(name)
        f = path.parent / name
        try:
            stale = (m is not None and not _alive(int(m.group(1)))) or \
                (m is None and legacy.match(name) is not None
                 and time.time() - f.stat().st_mtime > 3600)
            if stale:
                f.unlink()
                removed.append(name)
        except OSError:
            continue
    return removed


@contextlib.contextmanager
def _directory_lock(directory: Path):
    """An exclusive lock on ``directory`` while outputs in it are renamed, so that concurrent
    writers of the same outputs replace them pair by pair (best effort: no lock where the
    platform or file system has none)."""
    fd = None
    try:
        import fcntl
        fd = os.open(directory, os.O_RDONLY)
        fcntl.flock(fd, fcntl.LOCK_EX)
    except (ImportError, OSError):
        if fd is not None:
            os.close(fd)
        fd = None
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)          # releases the lock


def _backup(path: Path) -> str | None:
    """A second name for the current ``path`` (a hard link, else a copy), to restore it if a
    later rename of the same group fails; None if ``path`` does not exist."""
    if not path.exists():
        return None
    tmp = _temporary(path, ".bak")
    try:
        os.unlink(tmp)
        os.link(path, tmp)
    except OSError:
        try:
            shutil.copy2(path, tmp)
        except OSError:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            return None
    return tmp


def write_together(items) -> list:
    """Write files that belong together (an EXR and its PNG preview) atomically as a group.

    ``items`` are ``(path, writer)`` pairs; ``writer(tmp)`` writes a whole file.  Every file is
    first written to a hidden temporary file beside its path; only when all were written are
    they renamed over their paths, and if a rename fails the ones already renamed are put back
    (the previous file restored, or the new one removed where there was none), so the paths are
    replaced all together or not at all.  Stale temporaries of these paths left by killed
    processes are removed first (:func:`remove_stale_temporaries`).  Errors raise
    :class:`WriteError` naming the output path.  Returns the paths."""
    items = [(Path(p), w) for p, w in items]
    tmps: list = []
    try:
        for path, writer in items:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                remove_stale_temporaries(path)
                tmp = _temporary(path)
            except OSError as e:
                raise WriteError(e.errno, path, _reason(e, None, path)) from None
            tmps.append(tmp)
            try:
                if tmps[:1] != [tmp]:
                    test_pause(path.suffix.lstrip(".").lower())
                _test_fault(f"{path.suffix.lstrip('.').lower()}-write")
                writer(tmp)
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp, 0o666 & ~umask)
            except WriteError:
                raise
            except (OSError, RuntimeError) as e:
                raise WriteError(getattr(e, "errno", None) or errno.EIO, path,
                                 _reason(e, tmp, path)) from None
        with _directory_lock(items[0][0].parent):
            done: list = []           # (path, backup of its previous version or None)
            backups: list = []
            try:
                for (path, _), tmp in zip(items, tmps):
                    try:
                        backup = _backup(path) if len(items) > 1 else None
                        backups.append(backup)
                        if done:
                            test_pause("rename")
                        _test_fault(f"{path.suffix.lstrip('.').lower()}-rename")
                        os.replace(tmp, path)
                    except OSError as e:
                        raise WriteError(e.errno, path, _reason(e, tmp, path)) from None
                    done.append((path, backup))
            except BaseException:
                for path, backup in reversed(done):      # put back what was replaced
                    with contextlib.suppress(OSError):
                        if backup is not None:
                            os.replace(backup, path)
                        else:
                            os.unlink(path)
                raise
            finally:
                for backup in backups:
                    if backup is not None and os.path.exists(backup):
                        with contextlib.suppress(OSError):
                            os.unlink(backup)
    finally:
        for tmp in tmps:
            if os.path.exists(tmp):
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
    return [p for p, _ in items]


def write_bytes(path, data) -> None:
    """Write ``data`` to ``path`` through Python's own I/O and fsync it, so that a full disk or
    an I/O error is an OSError (the OpenEXR and Mitsuba writers ignore them: on a full disk
    they leave an empty file and report success).  ``path`` may be a binary stream."""
    if hasattr(path, "write"):
        path.write(data)
        return
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _atomic(path: Path, write) -> None:
    write_together([(Path(path), write)])


def write_text(path, text: str) -> Path:
    """A text file (JSON, Markdown), written atomically."""
    _atomic(Path(path), lambda tmp: write_bytes(tmp, text.encode()))
    return Path(path)


def write_with(path, writer) -> Path:
    """Atomic write by any ``writer(tmp_path)`` that writes a whole file (a matplotlib figure,
    a PIL image); the temporary name keeps the suffix, so writers that infer the format work."""
    _atomic(Path(path), writer)
    return Path(path)


def to_bitmap(image, metadata: dict | None = None, channels=None) -> "mi.Bitmap":
    """A Mitsuba Bitmap of ``image`` (HxW or HxWxC); ``channels`` names its channels (default
    by count: Y, YA, RGB, RGBA)."""
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    names = channel_names(arr.shape[2], channels)
    fmt = _PIXEL_FORMATS.get("".join(names), mi.Bitmap.PixelFormat.MultiChannel)
    bmp = mi.Bitmap(arr, fmt) if fmt != mi.Bitmap.PixelFormat.MultiChannel else \
        mi.Bitmap(arr, fmt, list(names))
    if metadata:
        meta = bmp.metadata()
        for k, v in metadata.items():
            meta[str(k)] = str(v)
    return bmp


def encode_png(image, channels=None):
    """A writer (``writer(path)``) of the sRGB preview of ``image``: values clipped to [0, 1]
    and encoded with Mitsuba's sRGB transfer curve.  RGB(A) as is, XYZ(A) converted to sRGB,
    luminance (Y, YA) as grey; other channel sets show their first channel as grey."""
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    names = "".join(channel_names(arr.shape[2], channels))
    if names.startswith(("RGB", "XYZ")):
        arr, names = arr[..., :3], names[:3]
    elif names.startswith("Y"):
        arr, names = arr[..., :1], "Y"
    else:
        arr, names = arr[..., :1], "Y"
    bmp = to_bitmap(np.ascontiguousarray(arr), channels=tuple(names))
    png = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)

    def write(tmp):
        stream = mi.MemoryStream()
        png.write(stream, mi.Bitmap.FileFormat.PNG)
        write_bytes(tmp, stream.raw_buffer()[:stream.size()])
    return write


def write_png(path, image, channels=None) -> Path:
    """sRGB preview (:func:`encode_png`), written atomically."""
    write_together([(Path(path), encode_png(image, channels))])
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


_CHANNELS = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
_PIXEL_FORMATS = {"Y": mi.Bitmap.PixelFormat.Y, "YA": mi.Bitmap.PixelFormat.YA,
                  "RGB": mi.Bitmap.PixelFormat.RGB, "RGBA": mi.Bitmap.PixelFormat.RGBA,
                  "XYZ": mi.Bitmap.PixelFormat.XYZ, "XYZA": mi.Bitmap.PixelFormat.XYZA}
#: channel orders read back (a file lists its channels alphabetically)
_KNOWN_ORDERS = [tuple(k) for k in ("RGBA", "RGB", "XYZA", "XYZ", "YA", "Y")]


def channel_names(count: int, channels=None) -> tuple:
    """Names of ``count`` channels: ``channels`` (a string of one-letter names, or a sequence
    of names) if given and of that length, else by count (Y, YA, RGB, RGBA; C0, C1, ... for
    more)."""
    if channels:
        names = tuple(channels)
        if len(names) == count:
            return names
    return _CHANNELS.get(count) or tuple(f"C{i}" for i in range(count))


def _channels(layers: dict, channels=None) -> dict:
    out, shape = {}, None
    for layer, img in layers.items():
        arr = np.asarray(img, dtype=np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3 or arr.shape[2] < 1:
            raise ValueError(f"layer {layer!r}: shape {arr.shape}; expected HxW or HxWxC")
        if shape is not None and arr.shape[:2] != shape:
            raise ValueError(f"layer {layer!r}: size {arr.shape[:2]} differs from {shape}")
        shape = arr.shape[:2]
        prefix = f"{layer}." if layer else ""
        for i, c in enumerate(channel_names(arr.shape[2], channels)):
            out[prefix + c] = np.ascontiguousarray(arr[..., i])
    if not out:
        raise ValueError("no layers to write")
    return out


def encode_exr(layers: dict, metadata: dict | None = None, channels=None):
    """A writer (``writer(path)``) of an EXR with named layers ({"": rgb, "variance": rgb}),
    every layer's channels named ``channels`` (default by count, see :func:`channel_names`),
    and typed header attributes.  Bad layers raise ValueError here, before anything is
    written."""
    import OpenEXR
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        if str(k) in STANDARD_ATTRIBUTES:
            raise ValueError(f"metadata key {k!r} is a standard EXR attribute")
        header[str(k)] = header_value(v)
    exr = OpenEXR.File(header, _channels(layers, channels))

    def write(tmp):
        buf = io.BytesIO()
        exr.write(buf)
        write_bytes(tmp, buf.getbuffer())
    return write


def write_layers(path, layers: dict, metadata: dict | None = None, channels=None) -> Path:
    """EXR with named layers ({"": rgb, "variance": rgb}) and typed header attributes
    (:func:`encode_exr`), written atomically."""
    write_together([(Path(path), encode_exr(layers, metadata, channels))])
    return Path(path)


def write_exr(path, image, metadata: dict | None = None, channels=None) -> Path:
    """EXR of one image (RGB, RGBA, Y, ...) with typed header attributes."""
    return write_layers(path, {"": image}, metadata, channels)


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


def read_layers_named(path) -> tuple[dict, dict, dict]:
    """:func:`read_layers` and the channel names of every layer ({layer: ("R", "G", "B")})."""
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
    layers, names = {}, {}
    for layer, cs in groups.items():
        order = next((list(k) for k in _KNOWN_ORDERS if set(k) == set(cs)), None) or \
            sorted(cs, key=lambda c: (not c[1:].isdigit(), int(c[1:]) if c[1:].isdigit()
                                      else 0, c))
        layers[layer] = np.stack([cs[c] for c in order], axis=-1)
        names[layer] = tuple(order)
    meta = {k: v for k, v in header.items() if k not in STANDARD_ATTRIBUTES}
    return layers, meta, names


def read_layers(path) -> tuple[dict, dict]:
    """({layer: HxWxC float32 array} with "" for the RGB layer, {header attribute: typed value}
    without the standard EXR attributes).  A file that is not a complete OpenEXR image raises
    ``ValueError("PATH: not an EXR written by render (...)")``."""
    layers, meta, _ = read_layers_named(path)
    return layers, meta


def read_exr(path) -> np.ndarray:
    """The RGB layer of an EXR."""
    layers = read_layers(path)[0]
    if "" not in layers:
        raise ValueError(f"{path}: no RGB layer (layers: {', '.join(sorted(layers))})")
    return layers[""]
