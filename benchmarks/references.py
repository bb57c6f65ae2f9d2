"""Reference images: Mitsuba's own ``path``, rendered in passes, cached under the run record's key.

**The reference integrator** is Mitsuba's built-in ``path`` at the group's ``max_depth``
(:func:`benchmarks.config.reference_integrator`; at ``max_depth`` 2 it computes direct light
only, the reference of the ``direct`` group), never one of the estimators under test: a
reference rendered by an estimator would hide that estimator's own bias.

**Rendering** (:func:`render`): ``spp`` samples per pixel in ``passes`` passes with distinct
seeds ``seed_first, seed_first + 1, ...``; a pass of more than 2^24 samples
(:data:`integrators.app.progressive.MAX_SAMPLES_PER_PASS`) is the mean of equal sub-renders,
each with its own seed.  The passes accumulate in an :class:`integrators.app.progressive.
Accumulator` (mean and a variance layer), written as an EXR with the run in its header.

**Cache** (:func:`get`): file ``REF_<scene>_<W>x<H>_d<depth>_<spp>spp_<key>.exr`` in the cache
folder, where ``key`` is :meth:`integrators.app.record.RunRecord.key` of the reference's run
record (scene path and SHA-1 of the scene file, integrator and its parameters, variant,
defines, spp, seed range) with the extra values of :meth:`ReferenceSpec.key_extra`: the film
size, Mitsuba's version, the number of passes, and the SHA-1 of the sources of those of our
plugins the scene file uses (a scene with ``<bsdf type="phong">`` runs our Phong code inside
Mitsuba's ``path``).  A change to any of them renders a new reference.  Next to the EXR,
``<stem>.json`` holds the record, the key, the extra values and the reference's checks.

**Closed form** (:data:`CLOSED_FORMS`): on ``furnace`` the per-pass means over the pixels
entirely inside the sphere's silhouette must be 0.8 and those entirely outside 1
(:func:`integrators.testing.mean_test`); the reference used *is* the closed form on those pixels
(:func:`apply_closed_form`), the render only on the pixels the silhouette crosses.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .config import REPO, reference_integrator
from .metrics import relmse_self
from .timing import clock, timed_render

FURNACE_INSIDE, FURNACE_OUTSIDE = 0.8, 1.0


# =============================================================================================
# the key
def _plugin_sources(scene_path) -> list:
    """Source files of our non-integrator plugins (BSDFs) that ``scene_path`` names
    (``type="name"``), with the package modules every plugin imports; empty when it names none.
    Integrators named in the file do not count: the reference replaces the scene's integrator."""
    import sys

    from integrators import registry
    text = Path(scene_path).read_text()
    used = set(re.findall(r'type\s*=\s*"([^"]+)"', text))
    files = set()
    for name, p in registry.plugins().items():
        if name in used and p.kind != "integrator":
            files.add(Path(sys.modules[p.template.__module__].__file__))
    if files:
        pkg = Path(sys.modules["integrators"].__file__).parent
        files |= set(pkg.glob("*.py"))             # registry, params, common, ...
        files |= set((pkg / "plugins").glob("base.py"))
    return sorted(files)


def plugin_code_sha1(scene_path) -> str:
    """SHA-1 over the names and contents of :func:`_plugin_sources` (``"none"`` if empty)."""
    files = _plugin_sources(scene_path)
    if not files:
        return "none"
    h = hashlib.sha1()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@dataclass
class ReferenceSpec:
    """One reference: which scene (file and defines, film size), depth, samples and seeds."""
    name: str                       # scene name (file name stem), for the cache file name
    scene_path: Path
    defines: dict
    width: int
    height: int
    max_depth: int
    spp: int
    passes: int
    seed_first: int
    extra: tuple = field(default=())   # further key values a caller adds

    def __post_init__(self):
        if self.passes < 1 or self.spp < self.passes or self.spp % self.passes:
            raise ValueError(f"reference spp {self.spp} is not a positive multiple of its "
                             f"{self.passes} passes")
        self.scene_path = Path(self.scene_path)
        self.defines = {k: str(v) for k, v in self.defines.items()}

    def integrator(self) -> dict:
        return reference_integrator(self.max_depth)

    @property
    def per_pass(self) -> int:
        return self.spp // self.passes

    @property
    def sub_renders(self) -> int:
        """Renders per pass (each at most MAX_SAMPLES_PER_PASS samples)."""
        from integrators.app.progressive import MAX_SAMPLES_PER_PASS
        cap = max(1, MAX_SAMPLES_PER_PASS // (self.width * self.height))
        return max(1, math.ceil(self.per_pass / cap))

    @property
    def seed_last(self) -> int:
        return self.seed_first + self.passes * self.sub_renders - 1

    def record(self):
        """The run record of this reference (:class:`integrators.app.record.RunRecord`)."""
        import mitsuba as mi

        from integrators.app.record import RunRecord
        integ = mi.load_dict(dict(self.integrator()))
        return RunRecord.for_scene(self.scene_path, integ, mi.variant(), self.defines,
                                   spp=self.spp, seed_first=self.seed_first,
                                   seed_last=self.seed_last, passes=self.passes)

    def key_extra(self) -> list:
        import mitsuba as mi
        return [f"film {self.width}x{self.height}", f"mitsuba {mi.__version__}",
                f"passes {self.passes}", f"plugins {plugin_code_sha1(self.scene_path)}",
                *map(str, self.extra)]

    def key(self, record=None) -> str:
        return (record or self.record()).key(*self.key_extra())

    def stem(self, key: str | None = None) -> str:
        return (f"REF_{self.name}_{self.width}x{self.height}_d{self.max_depth}_{self.spp}spp_"
                f"{key or self.key()}")


# =============================================================================================
# closed forms
def furnace_closed_form(w: int, h: int):
    """(expected image, inside mask, outside mask) of scenes/furnace.xml at ``w`` x ``h``: the
    pixels entirely inside the unit sphere's silhouette are 0.8, entirely outside 1.  Geometry
    from the scene file: camera on the axis at distance 4.5, fov 30 degrees along x, box filter
    (a pixel is the mean over its footprint)."""
    t = math.tan(math.radians(30) / 2)
    r = math.tan(math.asin(1 / 4.5))            # silhouette radius on the image plane z=1
    px = 2 * t / w                               # pixel size on that plane (square pixels)
    xs = -t + px * np.arange(w + 1)
    ys = (-t * h / w) + px * np.arange(h + 1)
    x0, x1 = xs[:-1][None, :], xs[1:][None, :]
    y0, y1 = ys[:-1][:, None], ys[1:][:, None]
    far = np.sqrt(np.maximum(x0 ** 2, x1 ** 2) + np.maximum(y0 ** 2, y1 ** 2))
    nx = np.where((x0 <= 0) & (x1 >= 0), 0.0, np.minimum(np.abs(x0), np.abs(x1)))
    ny = np.where((y0 <= 0) & (y1 >= 0), 0.0, np.minimum(np.abs(y0), np.abs(y1)))
    near = np.sqrt(nx ** 2 + ny ** 2)
    margin = 0.02 * px
    inside = far < r - margin
    outside = near > r + margin
    value = np.where(inside, FURNACE_INSIDE, FURNACE_OUTSIDE)
    return np.repeat(value[..., None], 3, axis=2), inside, outside


#: scene name -> closed form (w, h) -> (image, inside mask, outside mask)
CLOSED_FORMS: dict[str, Callable] = {"furnace": furnace_closed_form}


def check_closed_form(passes: np.ndarray, inside, outside) -> dict:
    from integrators import testing
    ti = testing.mean_test(passes[:, inside].mean(axis=1), FURNACE_INSIDE)
    to = testing.mean_test(passes[:, outside].mean(axis=1), FURNACE_OUTSIDE)
    return {
        "method": "integrators.testing.mean_test on the per-pass means over the pixels "
                  f"entirely inside ({FURNACE_INSIDE:g}) / outside ({FURNACE_OUTSIDE:g}) the "
                  "silhouette",
        "inside_pixels": int(inside.sum()), "outside_pixels": int(outside.sum()),
        "inside_mean": ti.mean.tolist(), "inside_p_value": ti.p_value,
        "inside_passed": bool(ti.passed),
        "outside_mean": to.mean.tolist(), "outside_p_value": to.p_value,
        "outside_passed": bool(to.passed)}


def apply_closed_form(name: str, ref, var, info: dict):
    """(ref, var) with the closed form on the pixels where it is known (none: unchanged)."""
    if name not in CLOSED_FORMS:
        return ref, var
    h, w = ref.shape[:2]
    value, inside, outside = CLOSED_FORMS[name](w, h)
    known = inside | outside
    info["closed_form_pixels"] = int(known.sum())
    info["rendered_pixels"] = int((~known).sum())
    info["note"] = (f"closed form ({FURNACE_INSIDE:g} inside, {FURNACE_OUTSIDE:g} outside the "
                    "silhouette) on every pixel not crossed by the silhouette; the rendered "
                    f"reference on the {int((~known).sum())} pixels it crosses")
    return (np.where(known[..., None], value, ref), np.where(known[..., None], 0.0, var))


# =============================================================================================
# rendering and the cache
def render(spec: ReferenceSpec, scene):
    """(Accumulator, per-pass images) of Mitsuba's ``path`` on the loaded ``scene``."""
    import mitsuba as mi

    from integrators.app import progressive
    integ = mi.load_dict(dict(spec.integrator()))
    per, sub = spec.per_pass, spec.sub_renders
    acc, passes = None, []
    seed = spec.seed_first
    t0 = clock()
    for _ in range(spec.passes):
        parts = []
        for j in range(sub):
            n = per // sub + (1 if j < per % sub else 0)
            img, _ = timed_render(scene, integ, n, seed)
            parts.append((np.array(img, dtype=np.float64)[..., :3], n))
            seed += 1
        img = sum(x * n for x, n in parts) / per
        if acc is None:
            acc = progressive.Accumulator.empty(img.shape, seed_first=spec.seed_first)
        acc.add(img, per, seed - 1)
        passes.append(img)
    acc.seconds = clock() - t0
    return acc, np.array(passes)


def get(spec: ReferenceSpec, scene, cache: Path | None, log: Callable[[str], None] = print):
    """(reference image, its variance, info) for ``spec``: from ``cache`` when there, else
    rendered (and stored when ``cache`` is not None).  Closed forms (:data:`CLOSED_FORMS`) are
    checked on the rendered passes and applied to the returned image."""
    import mitsuba as mi

    from integrators.app import progressive
    from integrators.app.imageio import write_text
    record = spec.record()
    extra = spec.key_extra()
    key = record.key(*extra)
    stem = spec.stem(key)
    exr = json_path = None
    if cache is not None:
        exr, json_path = Path(cache) / f"{stem}.exr", Path(cache) / f"{stem}.json"
    ref_int = spec.integrator()
    if exr is not None and exr.exists() and json_path.exists():
        acc = progressive.read(exr)
        info = json.loads(json_path.read_text())
        info["cached"] = True
        log(f"reference: cached {exr}")
    else:
        log(f"reference: rendering Mitsuba {ref_int} at {spec.spp} spp ({spec.passes} passes, "
            f"key {key}) ...")
        acc, passes = render(spec, scene)
        record.seconds = acc.seconds
        info = {"integrator": ref_int, "record": record.to_dict(), "key": key,
                "key_extra": extra, "spp": acc.spp, "passes": acc.passes,
                "render_seconds": acc.seconds,
                "nonfinite_values": int((~np.isfinite(passes)).sum())}
        if spec.name in CLOSED_FORMS:
            _, inside, outside = CLOSED_FORMS[spec.name](spec.width, spec.height)
            info["check_vs_closed_form"] = check_closed_form(passes, inside, outside)
        if exr is not None:
            try:
                scene_name = str(Path(spec.scene_path).resolve().relative_to(REPO))
            except ValueError:
                scene_name = str(spec.scene_path)
            progressive.write(exr, acc, {
                "scene": scene_name, "integrator": json.dumps(ref_int),
                "variant": mi.variant(), "defines": json.dumps(spec.defines),
                "record": record.to_json(), "key": key})
            write_text(json_path, json.dumps(info, indent=2) + "\n")
        info["cached"] = False
    ref, var = acc.mean(), acc.variance()
    ref, var = apply_closed_form(spec.name, ref, var, info)
    info["file"] = str(exr) if exr is not None else None
    info["max_depth"] = spec.max_depth
    info["relmse_self"] = relmse_self(ref, var)
    log(f"reference: own relMSE {info['relmse_self']:.3g}")
    if "check_vs_closed_form" in info:
        c = info["check_vs_closed_form"]
        log(f"reference vs closed form: inside {c['inside_mean']} (p {c['inside_p_value']:.3g}), "
            f"outside {c['outside_mean']} (p {c['outside_p_value']:.3g})")
    return ref, var, info
