r"""Experiments: error against time for every estimator on every scene, with charts and a report.

    python -m benchmarks run [--quick] [--scenes a b ...] [--methods m1 m2 ...] [--out DIR]
                             [--cache DIR] [--no-cache] [--report-only]

(needs the ``bench`` extra: ``.venv/bin/pip install -e '.[bench]'`` installs matplotlib and
flip-evaluator.)  Default output folder: ``benchmarks/results/experiments``.

**Scenes** (:data:`SCENES`, files in ``scenes/``): ``veach_mis``, ``cornell_box``,
``many_lights``, ``small_light`` (a tiny light: BSDF sampling fails), ``sharp_glossy`` (Phong
exponent 5000 under a large light: light sampling fails) and ``furnace`` (diffuse sphere of albedo
0.8 in a constant environment of radiance 1), each rendered 128 pixels wide (``--quick``: 64),
loaded with ``mi.load_file(path, **defines)``.

**Methods** (:data:`PATH_METHODS`, :data:`DIRECT_METHODS`), each a dict for ``mi.load_dict``
passed as ``mi.render(scene, integrator=...)``, in two groups with their own reference:

* group ``path`` (``max_depth`` 4, every scene): Mitsuba's ``path`` (the baseline), our
  ``nee_path`` with its defaults (power heuristic, light selection by power), ``nee_path`` with
  adaptive light selection, ``mis3`` (``selection=adaptive``) and ``bsdf_path`` (no light
  sampling);
* group ``direct`` (``max_depth`` 2: direct light only; ``veach_mis``, ``small_light``,
  ``sharp_glossy``): Mitsuba's ``direct`` (the baseline) against ``direct_mis`` with the balance
  and the power heuristic; on ``veach_mis`` also the heuristics cutoff, maximum, average and
  partition; on ``small_light`` and ``sharp_glossy`` the single techniques, light sampling only
  (``light_samples=1, bsdf_samples=0``) and BSDF sampling only (``0, 1``): the stability study.

**References** (one per scene and group): our ``nee_path`` with adaptive light selection at the
group's ``max_depth``, ``ref_spp`` samples per pixel (16384; quick 4096; 8x that on the
furnace, see below) in 16 passes with distinct seeds (a pass of more than 2^24 samples is the
mean of sub-renders), accumulated and written with :mod:`integrators.progressive` (EXR with a
variance layer, the run in its header).  Cached in ``$XDG_CACHE_HOME/integrators-bench`` (default
``~/.cache/integrators-bench``; ``--cache`` to change, ``--no-cache`` to re-render), file name
``REF_<scene>_<W>x<H>_d<depth>_<spp>spp_<key>.exr`` where the key hashes the scene file, the
integrators' sources, the reference integrator, the variant and Mitsuba's version, so a change
to any of them renders a new reference.  Next to it a ``.json`` holds its checks:

* against Mitsuba's ``path`` (same ``max_depth``): the 16 reference passes and 16 batches of
  ``path`` are compared by :func:`integrators.testing.image_test` (H0: same expected image;
  Welch per 4x4 block and channel, Sidak over blocks), and the relative difference of the image
  means is recorded;
* ``furnace`` against its closed form: the per-pass means over the pixels entirely inside the
  sphere's silhouette must be 0.8 and those entirely outside 1
  (:func:`integrators.testing.mean_test`).  The furnace reference *is* the closed form on those
  pixels; only the pixels the silhouette crosses come from the render (at 8x the spp: they hold
  all of ``bsdf_path``'s error, which is zero elsewhere);
* its own relMSE, ``mean(var / (ref^2 + 0.01))`` from the variance layer, is reported with its
  ratio to the smallest charted error (a warning when the ratio is below 10).

**Measurement** (one subprocess per scene: every BSDF alive in a process is compiled into every
kernel): at each budget of ``spp`` = 1, 2, 4, ..., 512 (quick: up to 128), every method renders
once untimed (a warm-up: kernels are compiled per spp value), then ``repeats`` timed rounds
(3; quick 1) in round-robin order, rotated every round, each render with its own seed.  Time
is ``perf_counter`` around ``mi.render(...); dr.eval(img); dr.sync_thread()``, the median over
the timed renders.  Errors against the reference are averaged over all renders of the point
(warm-up included: it is a valid image): ``rmse`` = sqrt(mean (x - ref)^2), ``relmse`` =
mean((x - ref)^2 / (ref^2 + 0.01)) over pixels and channels, ``flip`` = mean NVIDIA FLIP
(``flip_evaluator``, "LDR") between sRGB previews (linear values clipped to [0, 1], sRGB
curve) of the reference and the render; null when flip_evaluator is missing or fails (the
reason is in ``summary.json``'s ``meta``).

**Outputs** in the output folder: ``summary.json``, shaped
``{"scenes": {scene: {"reference": {...}, "methods": {label: {"integrator": {...}, "points":
[{"spp", "time_s", "rmse", "relmse", "flip"}, ...]}}, ...}}, "meta": {...}}``;
per scene ``<scene>_chart.png`` (log-log relMSE against time, one panel per group, the
reference's own relMSE dashed), ``<scene>_<group>_grid.png`` (equal time: each method rendered
once at the spp that takes about as long as the baseline at a quarter of the largest budget;
rows: sRGB image, a zoomed crop, the per-pixel relative squared error), and ``report.md``
(efficiency tables: 1 / (relMSE x time) at the largest budget relative to the group's
baseline, samples/s, the stability and heuristic studies, bias diagnostics).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "benchmarks" / "results" / "experiments"

PATH_DEPTH = 4      # max_depth of every path method and of its reference
DIRECT_DEPTH = 2    # direct light only


@dataclass(frozen=True)
class Settings:
    name: str
    width: int                  # image width in pixels (height from the scene's aspect)
    budgets: tuple              # spp per render, increasing
    repeats: int                # timed renders per method and budget (plus one warm-up)
    ref_spp: int                # reference samples per pixel
    ref_passes: int             # reference passes (batches for the check, variance layer)
    check_spp: int              # spp of each batch of Mitsuba's path in the check
    check_batches: int


FULL = Settings("full", 128, tuple(2 ** k for k in range(10)), 3, 16384, 16, 256, 16)
QUICK = Settings("quick", 64, tuple(2 ** k for k in range(8)), 1, 4096, 16, 64, 16)


@dataclass(frozen=True)
class Method:
    label: str
    group: str
    integrator: dict
    description: str


def _m(label, group, integ, desc):
    return Method(label, group, integ, desc)


PATH_METHODS = (
    _m("path", "path", {"type": "path", "max_depth": PATH_DEPTH},
       "Mitsuba's built-in `path` (NEE + BSDF sampling, power heuristic, uniform light "
       "selection): the baseline"),
    _m("nee_path", "path", {"type": "nee_path", "max_depth": PATH_DEPTH},
       "our `nee_path`, defaults (power heuristic, light selection by power)"),
    _m("nee_path_adaptive", "path",
       {"type": "nee_path", "max_depth": PATH_DEPTH, "light_selection": "adaptive"},
       "our `nee_path`, adaptive light selection (per-point irradiance bound)"),
    _m("mis3_adaptive", "path", {"type": "mis3", "max_depth": PATH_DEPTH, "selection": "adaptive"},
       "our `mis3` (one-sample MIS over cosine lobe, glossy lobe and light), technique "
       "probabilities adapted per vertex, balance heuristic"),
    _m("bsdf_path", "path", {"type": "bsdf_path", "max_depth": PATH_DEPTH},
       "our `bsdf_path`, BSDF sampling only (no light sampling)"),
)
HEURISTIC_NOTES = {
    "balance": "balance heuristic",
    "power": "power heuristic (beta 2)",
    "cutoff": "cutoff heuristic (alpha 0.1)",
    "maximum": "maximum heuristic",
    "average": "average (1 / number of techniques with non-zero pdf)",
    "partition": "partition (light hits count from light sampling only)",
}
DIRECT_METHODS = {
    "direct": _m("direct", "direct", {"type": "direct"},
                 "Mitsuba's built-in `direct` (1 emitter + 1 BSDF sample, power heuristic): the "
                 "baseline of the direct-light group"),
    **{f"direct_mis_{h}": _m(f"direct_mis_{h}", "direct", {"type": "direct_mis", "heuristic": h},
                             f"our `direct_mis`, 1 light + 1 BSDF sample, {HEURISTIC_NOTES[h]}")
       for h in HEURISTIC_NOTES},
    "light_only": _m("light_only", "direct",
                     {"type": "direct_mis", "light_samples": 1, "bsdf_samples": 0},
                     "our `direct_mis`, light sampling only (light_samples 1, bsdf_samples 0)"),
    "bsdf_only": _m("bsdf_only", "direct",
                    {"type": "direct_mis", "light_samples": 0, "bsdf_samples": 1},
                    "our `direct_mis`, BSDF sampling only (light_samples 0, bsdf_samples 1)"),
}
HEURISTIC_LABELS = ("direct", "direct_mis_balance", "direct_mis_power", "direct_mis_cutoff",
                    "direct_mis_maximum", "direct_mis_average", "direct_mis_partition")
STABILITY_LABELS = ("direct", "direct_mis_balance", "direct_mis_power", "light_only",
                    "bsdf_only")

GROUPS = {
    "path": {"max_depth": PATH_DEPTH, "baseline": "path",
             "title": f"path tracing, max_depth {PATH_DEPTH}"},
    "direct": {"max_depth": DIRECT_DEPTH, "baseline": "direct",
               "title": f"direct light, max_depth {DIRECT_DEPTH}"},
}


def _veach_defines(w):
    return {"width": str(w), "height": str(round(w * 216 / 384))}


def _res_defines(w):
    return {"res": str(w)}


# name -> defines(width), crop centre (fractions of width, height), direct-group methods,
# reference spp multiplier.  The furnace's reference is the closed form except on the pixels
# the silhouette crosses, whose noise is then all that bsdf_path (zero variance inside: cosine
# sampling of a diffuse BSDF under constant radiance) has: those pixels need more samples.
SCENES = {
    "veach_mis": (_veach_defines, (0.17, 0.33), HEURISTIC_LABELS, 1),
    "cornell_box": (_res_defines, (0.35, 0.8), (), 1),
    "many_lights": (_res_defines, (0.72, 0.42), (), 1),
    "small_light": (_res_defines, (0.62, 0.5), STABILITY_LABELS, 1),
    "sharp_glossy": (_res_defines, (0.5, 0.78), STABILITY_LABELS, 1),
    "furnace": (_res_defines, (0.8, 0.5), (), 8),
}


def scene_methods(scene: str) -> list:
    return list(PATH_METHODS) + [DIRECT_METHODS[k] for k in SCENES[scene][2]]


def all_labels() -> list:
    out = [m.label for m in PATH_METHODS]
    out += [k for k in DIRECT_METHODS if k not in out]
    return out


def reference_integrator(depth: int) -> dict:
    return {"type": "nee_path", "max_depth": depth, "light_selection": "adaptive"}


def cache_default() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "integrators-bench"


# =============================================================================================
# worker: one scene in this process
def srgb(x):
    import numpy as np
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


class Flip:
    """Mean FLIP between sRGB previews; disabled (None) with a reason when unavailable."""

    def __init__(self):
        self.reason = None
        try:
            import flip_evaluator
            self.mod = flip_evaluator
        except Exception as e:  # pragma: no cover - depends on the installation
            self.mod, self.reason = None, f"import flip_evaluator failed: {e!r}"

    def __call__(self, ref_srgb, test):
        if self.mod is None:
            return None
        import numpy as np
        try:
            _, mean, _ = self.mod.evaluate(np.ascontiguousarray(ref_srgb, dtype=np.float32),
                                           np.ascontiguousarray(srgb(test), dtype=np.float32),
                                           "LDR", inputsRGB=True, applyMagma=False)
            return float(mean)
        except Exception as e:  # pragma: no cover
            self.reason = f"flip_evaluator.evaluate failed: {e!r}"
            self.mod = None
            return None


def _code_hash() -> str:
    h = hashlib.sha1()
    for p in sorted((REPO / "integrators").glob("*.py")):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def _finite_or_none(x):
    return float(x) if x is not None and math.isfinite(x) else None


class Worker:
    def __init__(self, scene_name: str, settings: Settings, labels, cache: Path | None, out: Path):
        import integrators  # noqa: F401  (variant + plugin registration)
        import drjit as dr
        import mitsuba as mi
        import numpy as np
        self.dr, self.mi, self.np = dr, mi, np
        self.name, self.s, self.cache, self.out = scene_name, settings, cache, out
        defines_fn, self.crop_centre, _, ref_scale = SCENES[scene_name]
        self.ref_spp = settings.ref_spp * ref_scale
        self.defines = defines_fn(settings.width)
        self.path = REPO / "scenes" / f"{scene_name}.xml"
        self.scene = mi.load_file(str(self.path), **self.defines)
        film = self.scene.sensors()[0].film().crop_size()
        self.w, self.h = int(film[0]), int(film[1])
        if labels is None:
            self.methods = scene_methods(scene_name)
        else:  # the requested methods, plus the baseline of each group they belong to
            groups = {m.group for m in scene_methods(scene_name) if m.label in labels}
            keep = set(labels) | {GROUPS[g]["baseline"] for g in groups}
            self.methods = [m for m in scene_methods(scene_name) if m.label in keep]
        if not self.methods:
            raise SystemExit(f"{scene_name}: none of the requested methods applies")
        self.groups = {}
        for m in self.methods:
            self.groups.setdefault(m.group, []).append(m)
        self.integ = {m.label: mi.load_dict(dict(m.integrator)) for m in self.methods}
        self.flip = Flip()
        self.seed = 10
        self.emitter_mask = self.emitter_pixels()

    def lights(self) -> dict:
        """The scene's emitters and the selection pmf of ``light_selection=power`` (nee_path's
        default; Mitsuba's path selects uniformly)."""
        from integrators.light_selection import selection_pmf
        ems = self.scene.emitters()
        kinds = [str(e).split("[", 1)[0].strip() for e in ems]
        pmf = selection_pmf(self.scene, "power")
        return {"count": len(ems), "types": sorted(set(kinds)),
                "power_pmf_by_type": {k: [float(p) for p, kk in zip(pmf, kinds) if kk == k]
                                      for k in sorted(set(kinds))}}

    def emitter_pixels(self):
        """Pixels that see an emitter's surface directly, or get filter weight from a camera
        sample that does (4x4 rays per pixel; dilated by the reconstruction filter's radius).
        Environment emitters do not count.  Their error is the same lottery for every method
        (which camera samples hit the light), so a second relMSE leaves them out."""
        mi, np = self.mi, self.np
        sensor = self.scene.sensors()[0]
        k = 4
        ix, iy = np.meshgrid(np.arange(self.w * k), np.arange(self.h * k))
        u = ((ix + 0.5) / (self.w * k)).ravel()
        v = ((iy + 0.5) / (self.h * k)).ravel()
        ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
        si = self.scene.ray_intersect(ray)
        hit = si.is_valid() & (si.shape.emitter() != None)  # noqa: E711 (Dr.Jit pointer test)
        m = np.array(hit, dtype=bool).reshape(self.h, k, self.w, k).any(axis=(1, 3))
        r = max(0, math.ceil(float(sensor.film().rfilter().radius()) - 0.5))
        out = m.copy()
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                sh = np.zeros_like(m)
                sh[max(dy, 0):self.h + min(dy, 0), max(dx, 0):self.w + min(dx, 0)] = \
                    m[max(-dy, 0):self.h + min(-dy, 0), max(-dx, 0):self.w + min(-dx, 0)]
                out |= sh
        return out

    def log(self, msg):
        print(f"[{self.name}] {msg}", flush=True)

    def render(self, integ, spp, seed):
        dr, mi, np = self.dr, self.mi, self.np
        t0 = time.perf_counter()
        img = mi.render(self.scene, integrator=integ, spp=int(spp), seed=int(seed))
        dr.eval(img)
        dr.sync_thread()
        dt = time.perf_counter() - t0
        return np.array(img, dtype=np.float64)[..., :3], dt

    def next_seed(self):
        self.seed += 1
        return self.seed

    # -----------------------------------------------------------------------------------------
    # references
    def furnace_closed_form(self):
        """Expected image and a mask of the pixels whose value is known in closed form (entirely
        inside the unit sphere's silhouette: 0.8, entirely outside: 1).  Geometry from
        scenes/furnace.xml: camera on the axis at distance 4.5, fov 30 degrees along x, box
        filter (a pixel is the mean over its footprint)."""
        np = self.np
        t = math.tan(math.radians(30) / 2)
        r = math.tan(math.asin(1 / 4.5))            # silhouette radius on the image plane z=1
        px = 2 * t / self.w                          # pixel size on that plane (square pixels)
        xs = -t + px * np.arange(self.w + 1)
        ys = (-t * self.h / self.w) + px * np.arange(self.h + 1)
        x0, x1 = xs[:-1][None, :], xs[1:][None, :]
        y0, y1 = ys[:-1][:, None], ys[1:][:, None]
        far = np.sqrt(np.maximum(x0 ** 2, x1 ** 2) + np.maximum(y0 ** 2, y1 ** 2))
        nx = np.where((x0 <= 0) & (x1 >= 0), 0.0, np.minimum(np.abs(x0), np.abs(x1)))
        ny = np.where((y0 <= 0) & (y1 >= 0), 0.0, np.minimum(np.abs(y0), np.abs(y1)))
        near = np.sqrt(nx ** 2 + ny ** 2)
        margin = 0.02 * px
        inside = far < r - margin
        outside = near > r + margin
        value = np.where(inside, 0.8, 1.0)
        return (np.repeat(value[..., None], 3, axis=2), inside, outside)

    def reference(self, group: str) -> tuple:
        """(reference image, its variance, info dict) for a group, rendered or from the cache."""
        from integrators import progressive, testing
        mi, np = self.mi, self.np
        depth = GROUPS[group]["max_depth"]
        ref_int = reference_integrator(depth)
        s = self.s
        key = hashlib.sha1(json.dumps({
            "scene": hashlib.sha1(self.path.read_bytes()).hexdigest(), "code": _code_hash(),
            "integrator": ref_int, "variant": mi.variant(), "mitsuba": mi.__version__,
            "defines": self.defines, "spp": self.ref_spp, "passes": s.ref_passes,
            "check": [s.check_spp, s.check_batches]}, sort_keys=True).encode()).hexdigest()[:12]
        stem = f"REF_{self.name}_{self.w}x{self.h}_d{depth}_{self.ref_spp}spp_{key}"
        exr = json_path = None
        if self.cache is not None:
            exr, json_path = self.cache / f"{stem}.exr", self.cache / f"{stem}.json"
        if exr is not None and exr.exists() and json_path.exists():
            acc = progressive.read(exr)
            info = json.loads(json_path.read_text())
            info["cached"] = True
            self.log(f"reference {group}: cached {exr}")
        else:
            self.log(f"reference {group}: rendering {ref_int} at {self.ref_spp} spp "
                     f"({s.ref_passes} passes) ...")
            integ = mi.load_dict(dict(ref_int))
            per = self.ref_spp // s.ref_passes
            seed0 = 1_000_000 if group == "path" else 1_100_000
            acc, passes = None, []
            t0 = time.perf_counter()
            # each pass holds at most 2^24 samples (progressive.MAX_SAMPLES_PER_PASS) in
            # flight: a pass of many samples is the mean of sub-renders
            cap = max(1, progressive.MAX_SAMPLES_PER_PASS // (self.w * self.h))
            sub = max(1, math.ceil(per / cap))
            seed = seed0
            for k in range(s.ref_passes):
                parts = []
                for j in range(sub):
                    n = per // sub + (1 if j < per % sub else 0)
                    parts.append((self.render(integ, n, seed)[0], n))
                    seed += 1
                img = sum(x * n for x, n in parts) / per
                if acc is None:
                    acc = progressive.Accumulator.empty(img.shape, seed_first=seed0)
                acc.add(img, per, seed - 1)
                passes.append(img)
            acc.seconds = time.perf_counter() - t0
            passes = np.array(passes)
            # check against Mitsuba's path at the same max_depth
            self.log(f"reference {group}: checking against Mitsuba path "
                     f"({s.check_batches} x {s.check_spp} spp) ...")
            path_int = mi.load_dict({"type": "path", "max_depth": depth})
            seedp = 2_000_000 if group == "path" else 2_100_000
            t1 = time.perf_counter()
            pb = np.array([self.render(path_int, s.check_spp, seedp + k)[0]
                           for k in range(s.check_batches)])
            t_check = time.perf_counter() - t1
            r = testing.image_test(passes, pb)
            info = {
                "integrator": ref_int, "spp": acc.spp, "passes": acc.passes,
                "render_seconds": acc.seconds,
                "check_vs_mitsuba_path": {
                    "method": "integrators.testing.image_test: reference passes vs batches of "
                              "Mitsuba path (same max_depth), 4x4 blocks, Welch t, Sidak",
                    "path_integrator": {"type": "path", "max_depth": depth},
                    "path_batches": s.check_batches, "path_spp_per_batch": s.check_spp,
                    "p_value": r.p_value, "alpha": r.alpha, "passed": bool(r.passed),
                    "worst_block": list(r.worst_block),
                    "rel_diff_of_image_means": r.rel_diff,
                    "ref_image_mean": float(passes.mean()), "path_image_mean": float(pb.mean()),
                    "seconds": t_check},
            }
            if self.name == "furnace":
                _, inside, outside = self.furnace_closed_form()
                ti = testing.mean_test(passes[:, inside].mean(axis=1), 0.8)
                to = testing.mean_test(passes[:, outside].mean(axis=1), 1.0)
                info["check_vs_closed_form"] = {
                    "method": "integrators.testing.mean_test on the per-pass means over the "
                              "pixels entirely inside (0.8) / outside (1) the silhouette",
                    "inside_pixels": int(inside.sum()), "outside_pixels": int(outside.sum()),
                    "inside_mean": ti.mean.tolist(), "inside_p_value": ti.p_value,
                    "inside_passed": bool(ti.passed),
                    "outside_mean": to.mean.tolist(), "outside_p_value": to.p_value,
                    "outside_passed": bool(to.passed)}
            if exr is not None:
                exr.parent.mkdir(parents=True, exist_ok=True)
                progressive.write(exr, acc, {
                    "scene": str(self.path.relative_to(REPO)), "integrator": json.dumps(ref_int),
                    "variant": mi.variant(), "defines": json.dumps(self.defines)})
                json_path.write_text(json.dumps(info, indent=2) + "\n")
            info["cached"] = False
        ref, var = acc.mean(), acc.variance()
        if self.name == "furnace":
            value, inside, outside = self.furnace_closed_form()
            known = inside | outside
            ref = np.where(known[..., None], value, ref)
            var = np.where(known[..., None], 0.0, var)
            info["closed_form_pixels"] = int(known.sum())
            info["rendered_pixels"] = int((~known).sum())
            info["note"] = ("closed form (0.8 inside, 1 outside the silhouette) on every pixel "
                            "not crossed by the silhouette; the rendered reference on the "
                            f"{int((~known).sum())} pixels it crosses")
        info["file"] = str(exr) if exr is not None else None
        info["max_depth"] = depth
        info["relmse_self"] = float(np.mean(var / (ref ** 2 + 0.01)))
        chk = info["check_vs_mitsuba_path"]
        self.log(f"reference {group}: own relMSE {info['relmse_self']:.3g}; vs Mitsuba path "
                 f"p = {chk['p_value']:.3g} ({'passed' if chk['passed'] else 'FAILED'}), "
                 f"image means differ by {100 * chk['rel_diff_of_image_means']:.3f} %")
        if "check_vs_closed_form" in info:
            c = info["check_vs_closed_form"]
            self.log(f"reference vs closed form: inside {c['inside_mean']} "
                     f"(p {c['inside_p_value']:.3g}), outside {c['outside_mean']} "
                     f"(p {c['outside_p_value']:.3g})")
        return ref, var, info

    # -----------------------------------------------------------------------------------------
    def errors(self, img, ref, ref_srgb):
        np = self.np
        finite = bool(np.all(np.isfinite(img)))
        d2 = (img - ref) ** 2
        rmse = float(np.sqrt(np.mean(d2))) if finite else None
        relmse = float(np.mean(d2 / (ref ** 2 + 0.01))) if finite else None
        fl = self.flip(ref_srgb, np.nan_to_num(img)) if finite else None
        keep = ~self.emitter_mask
        relmse_ne = (float(np.mean((d2 / (ref ** 2 + 0.01))[keep])) if finite and keep.any()
                     else None)
        return rmse, relmse, fl, finite, relmse_ne

    def measure(self, refs):
        """Round-robin at each budget; returns {label: points} and per-method diagnostics."""
        np = self.np
        s = self.s
        points = {m.label: [] for m in self.methods}
        masked = {m.label: [] for m in self.methods}
        diag = {m.label: {"renders": 0, "nonfinite_renders": 0, "sum_spp": 0,
                          "means": [], "rel": [], "spps": [],
                          "acc": np.zeros((self.h, self.w, 3))}
                for m in self.methods}
        order = list(self.methods)
        t0 = time.perf_counter()
        for b in s.budgets:
            per = {m.label: {"t": [], "rmse": [], "relmse": [], "flip": [], "ne": []}
                   for m in self.methods}
            for rnd in range(1 + s.repeats):
                k = rnd % len(order)
                for m in order[k:] + order[:k]:
                    ref, _, _, ref_srgb = refs[m.group]
                    img, dt = self.render(self.integ[m.label], b, self.next_seed())
                    rmse, rel, fl, finite, ne = self.errors(img, ref, ref_srgb)
                    p = per[m.label]
                    if rnd > 0:                      # round 0 is the warm-up (compilation)
                        p["t"].append(dt)
                    for key, v in (("rmse", rmse), ("relmse", rel), ("flip", fl), ("ne", ne)):
                        if v is not None:
                            p[key].append(v)
                    d = diag[m.label]
                    d["renders"] += 1
                    if not finite:
                        d["nonfinite_renders"] += 1
                        continue
                    d["sum_spp"] += b
                    d["means"].append(float(img.mean()))
                    d["rel"].append(float(np.mean((img - ref) / np.sqrt(ref ** 2 + 0.01))))
                    d["spps"].append(b)
                    d["acc"] += b * img
            for m in self.methods:
                p = per[m.label]
                points[m.label].append({
                    "spp": b,
                    "time_s": float(np.median(p["t"])),
                    "rmse": float(np.mean(p["rmse"])) if p["rmse"] else None,
                    "relmse": float(np.mean(p["relmse"])) if p["relmse"] else None,
                    "flip": float(np.mean(p["flip"])) if p["flip"] else None,
                })
                masked[m.label].append(float(np.mean(p["ne"])) if p["ne"] else None)
            self.log(f"spp {b:5d}: " + ", ".join(
                f"{m.label} {points[m.label][-1]['relmse']:.3g}" if points[m.label][-1]['relmse']
                is not None else f"{m.label} n/a" for m in self.methods)
                + f"  ({time.perf_counter() - t0:.0f} s)")
        return points, diag, masked

    def diagnostics(self, points, diag, refs):
        """Bias diagnostics per method (see the report's notes)."""
        np = self.np
        out = {}
        for m in self.methods:
            d = diag[m.label]
            ref, var, info, _ = refs[m.group]
            res = {"renders": d["renders"], "nonfinite_renders": d["nonfinite_renders"],
                   "total_spp": d["sum_spp"]}
            if d["sum_spp"] > 0:
                spps = np.array(d["spps"], dtype=np.float64)
                S, n = spps.sum(), len(spps)
                # signed relative error per render, e_k = mean((x - ref) / sqrt(ref^2 + 0.01)):
                # its spp-weighted mean estimates the relative bias; each e_k has variance
                # sigma^2 / spp_k, so sum spp_k (e_k - mean)^2 / (n - 1) estimates sigma^2
                rel = np.array(d["rel"])
                bias = float((spps * rel).sum() / S)
                sigma2 = float((spps * (rel - bias) ** 2).sum() / max(n - 1, 1))
                ref_part = float((var / (ref ** 2 + 0.01)).sum()) / var.size ** 2
                se = math.sqrt(sigma2 / S + ref_part)
                means = np.array(d["means"])
                mean = float((spps * means).sum() / S)
                ref_mean = float(ref.mean())
                comb = d["acc"] / S
                rel_comb = float(np.mean((comb - ref) ** 2 / (ref ** 2 + 0.01)))
                last = points[m.label][-1]
                r = info["relmse_self"]
                pred = None
                if last["relmse"] is not None:
                    pred = max(last["relmse"] - r, 0.0) * last["spp"] / S + r
                res.update({
                    "signed_relative_error": bias,
                    "z_signed_relative_error": bias / se if se > 0 else None,
                    "image_mean": mean, "reference_image_mean": ref_mean,
                    "rel_diff_of_image_means": (mean - ref_mean) / ref_mean if ref_mean else None,
                    "relmse_of_all_renders_combined": rel_comb,
                    "relmse_combined_predicted_if_unbiased": pred,
                    "combined_over_predicted": (rel_comb / pred) if pred else None,
                })
            out[m.label] = res
        return out

    def equal_time(self, group, points, ref, ref_srgb):
        """One render per method at about the baseline's time at a quarter of the largest
        budget; returns {label: {spp, time_s, relmse, image}}."""
        methods = self.groups[group]
        base = GROUPS[group]["baseline"]
        bi = max(0, len(self.s.budgets) - 3)
        base_label = base if base in points else methods[0].label
        target = points[base_label][bi]["time_s"]
        out = {}
        for m in methods:
            last = points[m.label][-1]
            per_spp = last["time_s"] / last["spp"]
            spp = int(max(1, min(round(target / per_spp), 16 * self.s.budgets[-1])))
            self.render(self.integ[m.label], spp, self.next_seed())          # warm-up
            img, dt = self.render(self.integ[m.label], spp, self.next_seed())
            rmse, rel, fl, _, _ = self.errors(img, ref, ref_srgb)
            out[m.label] = {"spp": spp, "time_s": dt, "relmse": rel, "flip": fl, "image": img}
        return target, out

    # -----------------------------------------------------------------------------------------
    def run(self) -> dict:
        t_start = time.perf_counter()
        refs, ref_info = {}, {}
        for g in self.groups:
            ref, var, info = self.reference(g)
            refs[g] = (ref, var, info, srgb(ref))
            ref_info[g] = info
        # warm-up of every method at the smallest budget is part of round 0 of each budget
        points, diag, masked = self.measure(refs)
        diagnostics = self.diagnostics(points, diag, refs)
        groups = {}
        for g, methods in self.groups.items():
            ref, var, info, ref_srgb = refs[g]
            labels = [m.label for m in methods]
            base = GROUPS[g]["baseline"] if GROUPS[g]["baseline"] in labels else None
            eff = {}
            def inv(rel, t):
                return 1.0 / (rel * t) if rel and t > 0 else None

            for m in methods:
                pts = points[m.label]
                last = pts[-1]
                eff[m.label] = {
                    "spp": last["spp"], "time_s": last["time_s"],
                    "relmse": last["relmse"], "flip": last["flip"],
                    "efficiency": inv(last["relmse"], last["time_s"]),
                    "samples_per_s": self.w * self.h * last["spp"] / last["time_s"],
                    "relmse_without_emitter_pixels": masked[m.label][-1],
                    "efficiency_without_emitter_pixels": inv(masked[m.label][-1],
                                                             last["time_s"]),
                    "efficiency_3_largest": [inv(p["relmse"], p["time_s"]) for p in pts[-3:]],
                }

            def ratio(a, b):
                return a / b if a and b else None

            for m in methods:
                b = eff.get(base) if base else None
                e = eff[m.label]
                e["efficiency_vs_baseline"] = ratio(e["efficiency"], b and b["efficiency"])
                e["samples_per_s_vs_baseline"] = ratio(e["samples_per_s"],
                                                       b and b["samples_per_s"])
                e["efficiency_without_emitter_pixels_vs_baseline"] = ratio(
                    e["efficiency_without_emitter_pixels"],
                    b and b["efficiency_without_emitter_pixels"])
                # geometric mean of the per-budget ratios over the three largest budgets
                rs = [ratio(x, y) for x, y in zip(e["efficiency_3_largest"],
                                                  b["efficiency_3_largest"])] if b else []
                e["efficiency_vs_baseline_3_largest"] = (
                    math.exp(sum(math.log(r) for r in rs) / len(rs))
                    if rs and all(rs) else None)
            charted = [points[l][-1]["relmse"] for l in labels if points[l][-1]["relmse"]]
            min_charted = min(charted) if charted else None
            info["smallest_charted_relmse"] = min_charted
            info["smallest_charted_over_relmse_self"] = (
                min_charted / info["relmse_self"] if min_charted and info["relmse_self"] > 0
                else None)
            ratio = info["smallest_charted_over_relmse_self"]
            if ratio is not None:
                self.log(f"reference {g}: own relMSE {info['relmse_self']:.3g} is "
                         f"{ratio:.0f}x below the smallest charted relMSE {min_charted:.3g}"
                         + ("" if ratio >= 10 else "  ** WARNING: not far below **"))
            target, eq = self.equal_time(g, points, ref, ref_srgb)
            grid = f"{self.name}_{g}_grid.png"
            self.plot_grid(self.out / grid, g, ref, var, eq, target)
            groups[g] = {
                "max_depth": GROUPS[g]["max_depth"], "baseline": base, "methods": labels,
                "efficiency_at_largest_budget": eff,
                "equal_time": {"target_time_s": target,
                               "renders": {l: {k: v for k, v in r.items() if k != "image"}
                                           for l, r in eq.items()}},
                "grid_png": grid,
            }
        chart = f"{self.name}_chart.png"
        self.plot_chart(self.out / chart, points, ref_info)
        reference = dict(ref_info.get("path") or next(iter(ref_info.values())))
        if "direct" in ref_info and "path" in ref_info:
            reference["direct"] = ref_info["direct"]
        return {
            "file": str(self.path.relative_to(REPO)),
            "resolution": [self.w, self.h], "defines": self.defines,
            "reference": reference,
            "methods": {m.label: {"integrator": dict(m.integrator), "points": points[m.label]}
                        for m in self.methods},
            "groups": groups, "diagnostics": diagnostics, "chart_png": chart,
            "emitter_pixels": int(self.emitter_mask.sum()),
            "lights": self.lights(),
            "relmse_without_emitter_pixels": masked,
            "flip_unavailable_reason": self.flip.reason,
            "worker_seconds": time.perf_counter() - t_start,
        }

    # -----------------------------------------------------------------------------------------
    # figures
    def plot_chart(self, path, points, ref_info):
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import NullFormatter
        gs = list(self.groups)
        fig, axes = plt.subplots(1, len(gs), figsize=(4.6 * len(gs), 3.6), squeeze=False)
        for ax, g in zip(axes[0], gs):
            for i, m in enumerate(self.groups[g]):
                pts = [p for p in points[m.label] if p["relmse"]]
                base = m.label == GROUPS[g]["baseline"]
                ax.loglog([p["time_s"] for p in pts], [p["relmse"] for p in pts],
                          marker="o", ms=3, lw=2.2 if base else 1.3,
                          color="black" if base else f"C{i}",
                          label=m.label + (" (Mitsuba)" if m.integrator["type"] in
                                           ("path", "direct") else ""))
            r = ref_info[g]["relmse_self"]
            if r > 0:
                ax.axhline(r, color="gray", ls="--", lw=1, label="reference's own relMSE")
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel("time per render (s)")
            ax.set_ylabel("relMSE")
            ax.set_title(f"{self.name}: {GROUPS[g]['title']}", fontsize=9)
            ax.grid(True, which="major", alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)

    def crop_box(self):
        side = max(8, self.w // 4)
        cx, cy = self.crop_centre
        x0 = int(min(max(round(cx * self.w - side / 2), 0), self.w - side))
        y0 = int(min(max(round(cy * self.h - side / 2), 0), self.h - side))
        return x0, y0, side

    def plot_grid(self, path, group, ref, var, eq, target):
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.colors import LogNorm
        from matplotlib.patches import Rectangle
        np = self.np
        cols = [("reference", ref, var / (ref ** 2 + 0.01), None)]
        for label, r in eq.items():
            img = np.nan_to_num(r["image"])
            cols.append((label, img, (img - ref) ** 2 / (ref ** 2 + 0.01), r))
        n = len(cols)
        aspect = self.h / self.w
        pw = 1.35
        fig = plt.figure(figsize=(pw * n + 0.6, pw * (2 * aspect + 1) + 0.75))
        gsp = fig.add_gridspec(3, n + 1, height_ratios=[aspect, 1, aspect],
                               width_ratios=[1] * n + [0.08], wspace=0.04, hspace=0.06,
                               left=0.01, right=0.95, top=0.86, bottom=0.01)
        x0, y0, side = self.crop_box()
        norm = LogNorm(vmin=1e-4, vmax=10)
        im = None
        for j, (label, img, err, r) in enumerate(cols):
            pre = srgb(img)
            ax = fig.add_subplot(gsp[0, j])
            ax.imshow(pre, interpolation="nearest")
            ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), side, side, fill=False, ec="cyan", lw=0.7))
            if r is None:
                title = f"reference\n{self.ref_spp} spp"
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
        fig.suptitle(f"{self.name}, {GROUPS[group]['title']}: equal time ~{target:.2f} s "
                     "(rows: sRGB, crop x4, relative squared error; reference column: its own "
                     "expected error)", fontsize=7)
        fig.savefig(path, dpi=100)
        plt.close(fig)
        _shrink_png(path)


def _shrink_png(path):
    """Palette PNG (256 colours): a third of the size of an RGB one for these noisy images."""
    try:
        from PIL import Image
        img = Image.open(path).convert("RGB")
        img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
                     ).save(path, optimize=True)
    except Exception:
        pass


# =============================================================================================
# parent: one subprocess per scene, merge, report
def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks run",
                                 description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help=f"smaller run: {QUICK.width} px wide, spp up to {QUICK.budgets[-1]}, "
                         f"{QUICK.repeats} timed round(s), reference {QUICK.ref_spp} spp "
                         "(every scene and method)")
    ap.add_argument("--scenes", nargs="+", default=None, metavar="SCENE",
                    help=f"subset of: {' '.join(SCENES)}")
    ap.add_argument("--methods", nargs="+", default=None, metavar="LABEL",
                    help="subset of method labels (each group's baseline is always kept): "
                         + " ".join(all_labels()))
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output folder (default %(default)s)")
    ap.add_argument("--cache", default=str(cache_default()),
                    help="reference cache folder (default %(default)s)")
    ap.add_argument("--no-cache", action="store_true", help="render references afresh, keep none")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite report.md from OUT/summary.json, render nothing")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--worker-json", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    for sc in a.scenes or ():
        if sc not in SCENES:
            ap.error(f"unknown scene {sc!r}; one of {', '.join(SCENES)}")
    for m in a.methods or ():
        if m not in all_labels():
            ap.error(f"unknown method {m!r}; one of {', '.join(all_labels())}")
    return a


def _labels(args):
    return None if args.methods is None else sorted(set(args.methods))


def _check_deps():
    missing = []
    for mod in ("matplotlib", "flip_evaluator"):
        try:
            __import__(mod)
        except Exception:
            missing.append(mod)
    if "matplotlib" in missing:
        sys.exit("python -m benchmarks run needs matplotlib (and flip-evaluator): "
                 ".venv/bin/pip install -e '.[bench]'  (or: pip install matplotlib flip-evaluator)")
    if missing:
        print("warning: flip_evaluator missing (pip install flip-evaluator): FLIP recorded as null",
              file=sys.stderr)


def _home_relative(path) -> str:
    p, home = str(Path(path).resolve()), str(Path.home().resolve())
    return "~" + p[len(home):] if p == home or p.startswith(home + os.sep) else p


def _git_state():
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                             text=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain"], cwd=REPO,
                                    capture_output=True, text=True).stdout.strip())
        return {"commit": rev or None, "dirty": dirty}
    except Exception:
        return {"commit": None, "dirty": None}


def _machine():
    cpu = ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"platform": platform.platform(), "cpu_model": cpu, "cpu_count": os.cpu_count(),
            "python": platform.python_version()}


def worker_main(args):
    settings = QUICK if args.quick else FULL
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache = None if args.no_cache else Path(args.cache)
    w = Worker(args.worker, settings, _labels(args), cache, out)
    res = w.run()
    res["variant"] = w.mi.variant()
    res["mitsuba_version"] = w.mi.__version__
    res["drjit_version"] = w.dr.__version__
    Path(args.worker_json).write_text(json.dumps(res, indent=2) + "\n")


def main(argv=None):
    args = parse_args(argv)
    if args.worker:
        return worker_main(args)
    out = Path(args.out)
    if args.report_only:
        summary = json.loads((out / "summary.json").read_text())
        (out / "report.md").write_text(report(summary))
        print(f"wrote {out / 'report.md'}")
        return 0
    _check_deps()
    settings = QUICK if args.quick else FULL
    scenes = args.scenes or list(SCENES)
    out.mkdir(parents=True, exist_ok=True)
    if out.resolve().is_relative_to(REPO):
        # the root .gitignore ignores *.png outside benchmarks/results/: keep this folder's
        (out / ".gitignore").write_text("# the results snapshot keeps its PNGs (the root "
                                        ".gitignore ignores *.png elsewhere)\n!*.png\n")
    t0 = time.perf_counter()
    git = _git_state()   # before this run writes into a tracked results folder
    results, per_scene_s = {}, {}
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    with tempfile.TemporaryDirectory(prefix="bench-run-") as tmp:
        for sc in scenes:
            js = Path(tmp) / f"{sc}.json"
            cmd = [sys.executable, "-m", "benchmarks", "run", "--worker", sc,
                   "--worker-json", str(js), "--out", str(out), "--cache", args.cache]
            if args.quick:
                cmd.append("--quick")
            if args.no_cache:
                cmd.append("--no-cache")
            if args.methods:
                cmd += ["--methods", *args.methods]
            print(f"== {sc}: one process ({settings.name})", flush=True)
            ts = time.perf_counter()
            r = subprocess.run(cmd, cwd=REPO, env=env)
            per_scene_s[sc] = time.perf_counter() - ts
            if r.returncode != 0:
                print(f"== {sc}: worker failed with status {r.returncode}", file=sys.stderr)
                continue
            results[sc] = json.loads(js.read_text())
            print(f"== {sc}: {per_scene_s[sc]:.0f} s", flush=True)
    total = time.perf_counter() - t0
    first = next(iter(results.values()), {})
    flip_reasons = sorted({r.get("flip_unavailable_reason") for r in results.values()
                           if r.get("flip_unavailable_reason")})
    meta = {
        "command": " ".join(["python -m benchmarks run",
                             shlex.join(argv if argv is not None else sys.argv[1:])]).strip(),
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "git": git, "machine": _machine(),
        "variant": first.get("variant"), "mitsuba_version": first.get("mitsuba_version"),
        "drjit_version": first.get("drjit_version"),
        "settings": asdict(settings), "path_max_depth": PATH_DEPTH,
        "direct_max_depth": DIRECT_DEPTH,
        "reference_integrators": {g: reference_integrator(v["max_depth"])
                                  for g, v in GROUPS.items()},
        "reference_cache": None if args.no_cache else _home_relative(args.cache),
        "methods": {l: d for l, d in ((m.label, m.description) for m in
                                      list(PATH_METHODS) + list(DIRECT_METHODS.values()))},
        "flip": ("flip_evaluator.evaluate(ref, test, 'LDR') on sRGB previews (clip to [0,1], "
                 "sRGB curve), mean of the error map"),
        "flip_unavailable": flip_reasons or None,
        "seconds_per_scene": per_scene_s, "total_seconds": total,
        "failed_scenes": [s for s in scenes if s not in results],
    }
    summary = {"scenes": {k: v for k, v in results.items()}, "meta": meta}
    for v in summary["scenes"].values():
        for k in ("variant", "mitsuba_version", "drjit_version"):
            v.pop(k, None)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "report.md").write_text(report(summary))
    print(f"wrote {out / 'summary.json'}, {out / 'report.md'} and the PNGs "
          f"({total:.0f} s in all)")
    return 1 if meta["failed_scenes"] else 0


# =============================================================================================
# report
def _f(x, fmt=".3g"):
    return "n/a" if x is None else format(x, fmt)


def _eff_table(sc, g):
    grp = sc["groups"][g]
    eff = grp["efficiency_at_largest_budget"]
    lines = ["| method | spp | time (s) | relMSE | FLIP | M samples/s | samples/s vs baseline "
             "| efficiency 1/(relMSE x s) | **vs baseline** | vs baseline, 3 largest budgets "
             "| relMSE without emitter pixels | vs baseline, without emitter pixels |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for l in grp["methods"]:
        e = eff[l]
        lines.append(f"| `{l}` | {e['spp']} | {e['time_s']:.3f} | {_f(e['relmse'])} | "
                     f"{_f(e['flip'], '.3f')} | {e['samples_per_s'] / 1e6:.2f} | "
                     f"{_f(e['samples_per_s_vs_baseline'], '.2f')} | {_f(e['efficiency'])} | "
                     f"**{_f(e['efficiency_vs_baseline'], '.2f')}** | "
                     f"{_f(e.get('efficiency_vs_baseline_3_largest'), '.2f')} | "
                     f"{_f(e.get('relmse_without_emitter_pixels'))} | "
                     f"{_f(e.get('efficiency_without_emitter_pixels_vs_baseline'), '.2f')} |")
    return lines


def _ref_lines(name, ref, group):
    c = ref["check_vs_mitsuba_path"]
    ratio = ref.get("smallest_charted_over_relmse_self")
    lines = [
        f"- reference ({group}, max_depth {ref['max_depth']}): `{json.dumps(ref['integrator'])}` "
        f"at {ref['spp']} spp in {ref['passes']} passes"
        + (f" (rendered in {ref['render_seconds']:.0f} s)" if ref.get("render_seconds") else "")
        + ("; from the cache" if ref.get("cached") else "") + ".",
        f"  Own relMSE (variance layer) {_f(ref['relmse_self'])}, "
        + (f"**{ratio:.0f}x below** the smallest charted relMSE ({_f(ref['smallest_charted_relmse'])})"
           if ratio else "no charted error")
        + ("" if ratio is None or ratio >= 10 else " -- **WARNING: not far below; the smallest "
           "errors are partly the reference's**") + ".",
        f"  Against Mitsuba `path` (max_depth {ref['max_depth']}, {c['path_batches']} x "
        f"{c['path_spp_per_batch']} spp): image_test p = {c['p_value']:.3g} "
        f"({'passed' if c['passed'] else '**FAILED**'} at alpha {c['alpha']:g}), image means "
        f"differ by {100 * c['rel_diff_of_image_means']:.3f} %.",
    ]
    if "check_vs_closed_form" in ref:
        k = ref["check_vs_closed_form"]
        lines.append(
            f"  Against the closed form: mean over the {k['inside_pixels']} pixels inside the "
            f"silhouette {k['inside_mean'][0]:.5f} (expected 0.8, p = {k['inside_p_value']:.3g}, "
            f"{'passed' if k['inside_passed'] else '**FAILED**'}), over the "
            f"{k['outside_pixels']} outside {k['outside_mean'][0]:.5f} (expected 1, p = "
            f"{k['outside_p_value']:.3g}, {'passed' if k['outside_passed'] else '**FAILED**'}). "
            + ref.get("note", "") + ".")
    return lines


def _stability(summary):
    """Per scene: MIS vs the best single technique (efficiency and relMSE at equal spp)."""
    out = {}
    for name, sc in summary["scenes"].items():
        g = sc.get("groups", {}).get("direct")
        if not g:
            continue
        eff = g["efficiency_at_largest_budget"]
        singles = [l for l in ("light_only", "bsdf_only") if l in eff and eff[l]["efficiency"]]
        mis = [l for l in ("direct_mis_balance", "direct_mis_power")
               if l in eff and eff[l]["efficiency"]]
        if not singles or not mis:
            continue
        r = {}
        for suffix, ek, rk in (("", "efficiency", "relmse"),
                               ("_without_emitter_pixels", "efficiency_without_emitter_pixels",
                                "relmse_without_emitter_pixels")):
            if not all(eff[l].get(ek) for l in singles + mis):
                continue
            best_s = max(singles, key=lambda l: eff[l][ek])
            worst_s = min(singles, key=lambda l: eff[l][ek])
            best_m = max(mis, key=lambda l: eff[l][ek])
            r.update({
                "best_single" + suffix: best_s, "worst_single" + suffix: worst_s,
                "best_mis" + suffix: best_m,
                "efficiency_mis_over_best_single" + suffix: eff[best_m][ek] / eff[best_s][ek],
                "efficiency_mis_over_worst_single" + suffix: eff[best_m][ek] / eff[worst_s][ek],
                "relmse_best_single_over_mis_equal_spp" + suffix:
                    eff[best_s][rk] / eff[best_m][rk],
                "relmse_worst_single_over_mis_equal_spp" + suffix:
                    eff[worst_s][rk] / eff[best_m][rk],
            })
        r["spp"] = eff[mis[0]]["spp"]
        out[name] = r
    return out


def report(summary) -> str:
    meta = summary["meta"]
    s = meta["settings"]
    scenes = summary["scenes"]
    L = ["# Experiments: error against time", ""]
    L += [f"Generated by `{meta['command']}` on {meta['date_utc']} "
          f"({meta['machine']['cpu_model']}, {meta['machine']['cpu_count']} CPUs; "
          f"`{meta['variant']}`, Mitsuba {meta['mitsuba_version']}, Dr.Jit "
          f"{meta['drjit_version']}; commit {str(meta['git']['commit'])[:10]}"
          f"{' + local changes' if meta['git']['dirty'] else ''}). "
          f"Total wall time **{meta['total_seconds'] / 60:.1f} min** "
          f"({', '.join(f'{k} {v:.0f} s' for k, v in meta['seconds_per_scene'].items())}).", ""]
    L += ["Settings: " + f"`{s['name']}` run, images {s['width']} px wide, spp budgets "
          f"{', '.join(map(str, s['budgets']))}; at each budget one untimed warm-up render per "
          f"method (compilation) and {s['repeats']} timed round(s), round-robin (order rotated "
          "every round); time = median of the timed renders; errors = mean over all renders "
          f"of the point. Path methods use **max_depth {meta['path_max_depth']}**; the "
          f"direct-light group max_depth {meta['direct_max_depth']}. References: "
          f"`nee_path` with adaptive light selection at the group's max_depth, "
          f"{s['ref_spp']} spp in {s['ref_passes']} passes, cached in "
          f"`{meta['reference_cache']}`. Full description: `benchmarks/run.py`. "
          "relMSE = mean((x - ref)^2 / (ref^2 + 0.01)); efficiency = 1 / (relMSE x time) at "
          "the largest budget, relative to the group's Mitsuba baseline (`path`, `direct`). "
          "FLIP: " + meta["flip"] + (f" -- unavailable: {meta['flip_unavailable']}"
                                     if meta.get("flip_unavailable") else "") + ".", ""]
    L += ["Single renders on a shared 2-core machine: timings are noisy (about 10 %), and "
          "relMSE of heavy-tailed estimators (BSDF sampling of small lights) varies by large "
          "factors between renders; compare factors, not digits. A render's time includes "
          "the fixed cost of a `mi.render` call (our Python integrators are traced again on "
          "every call: a few ms), which dominates the smallest budgets of the cheap scenes "
          "(furnace) and bends their curves at the left.", ""]
    L += ["**Emitter pixels.** Where a camera ray sees an area light directly, every method "
          "computes the same thing (emission at the first hit), so the error there is the same "
          "lottery of which camera samples hit the light, independent of the sampling technique "
          "under test; with a tiny bright light (`small_light`: radius 0.01, radiance 20000, "
          "about one pixel plus its filter neighbours) it dominates the relMSE of every method "
          "that finds the light and makes single-point "
          "ratios between those methods noise. The tables therefore also give relMSE and "
          "efficiency over the other pixels (\"without emitter pixels\": pixels hit by a camera "
          "ray that sees an emitter's surface, 4x4 rays per pixel, dilated by the filter radius; "
          "environment emitters do not count). The charts and the main columns use all pixels. "
          "Emitter pixels per scene, and their share of the baseline's relMSE at the largest "
          "budget: " + "; ".join(_emitter_share(n, sc) for n, sc in scenes.items()) + ".", ""]
    # methods
    L += ["## Methods", "", "| label | integrator | description |", "|---|---|---|"]
    seen = {}
    for sc in scenes.values():
        for l, m in sc["methods"].items():
            seen.setdefault(l, m["integrator"])
    for l, integ in seen.items():
        L.append(f"| `{l}` | `{json.dumps(integ)}` | {meta['methods'].get(l, '')} |")
    L.append("")
    # headline
    L += ["## Headline: efficiency relative to Mitsuba `path` (max_depth 4)", ""]
    plabels = [m.label for m in PATH_METHODS if any(m.label in sc["methods"]
                                                     for sc in scenes.values())]
    def path_table(key):
        """One row per scene: the path group's ``key`` at the largest budget, per method."""
        rows = ["| scene | " + " | ".join(f"`{l}`" for l in plabels) + " |",
                "|---|" + "---:|" * len(plabels)]
        for name, sc in scenes.items():
            g = sc["groups"].get("path")
            if not g:
                continue
            e = g["efficiency_at_largest_budget"]
            rows.append(f"| {name} | " + " | ".join(
                _f(e[l].get(key), ".2f") if l in e else "" for l in plabels) + " |")
        return rows

    L += path_table("efficiency_vs_baseline")
    for key, title in (("efficiency_vs_baseline_3_largest",
                        "The same, geometric mean of the per-budget ratios over the three "
                        "largest budgets (a check on the noise of single points):"),
                       ("efficiency_without_emitter_pixels_vs_baseline",
                        "The same at the largest budget, relMSE over the pixels that do not see "
                        "an area light directly (see the notes):"),
                       ("samples_per_s_vs_baseline",
                        "Samples per second relative to `path` at the largest budget:")):
        L += ["", title, ""] + path_table(key)
    L.append("")
    dscenes = [n for n, sc in scenes.items() if "direct" in sc["groups"]]
    if dscenes:
        L += ["## Direct light (max_depth 2): efficiency relative to Mitsuba `direct`", ""]
        dl = []
        for n in dscenes:
            for l in scenes[n]["groups"]["direct"]["methods"]:
                if l not in dl:
                    dl.append(l)
        L += ["| scene | " + " | ".join(f"`{l}`" for l in dl) + " |", "|---|" + "---:|" * len(dl)]
        for n in dscenes:
            e = scenes[n]["groups"]["direct"]["efficiency_at_largest_budget"]
            L.append(f"| {n} | " + " | ".join(
                _f(e[l]["efficiency_vs_baseline"], ".2f") if l in e else "" for l in dl) + " |")
        L.append("")
    # stability
    stab = _stability(summary)
    if stab:
        L += ["## Stability: single techniques against MIS (direct light, max_depth 2)", "",
              "`light_only` = `direct_mis` with light_samples 1, bsdf_samples 0; `bsdf_only` = "
              "0, 1; MIS = 1 + 1 samples with the balance or power heuristic (twice the rays "
              "of a single technique: the efficiency counts that).", "",
              "| scene | pixels | best single | best MIS | efficiency MIS / best single | "
              "MIS / worst single | relMSE best single / MIS (equal spp) | worst single / MIS |",
              "|---|---|---|---|---:|---:|---:|---:|"]
        for n, r in stab.items():
            for suffix, what in (("", "all"), ("_without_emitter_pixels",
                                               "without emitter pixels")):
                if "best_single" + suffix not in r:
                    continue
                L.append(f"| {n} | {what} | `{r['best_single' + suffix]}` | "
                         f"`{r['best_mis' + suffix]}` | "
                         f"{r['efficiency_mis_over_best_single' + suffix]:.2f} | "
                         f"{r['efficiency_mis_over_worst_single' + suffix]:.3g} | "
                         f"{r['relmse_best_single_over_mis_equal_spp' + suffix]:.2f} | "
                         f"{r['relmse_worst_single_over_mis_equal_spp' + suffix]:.3g} |")
        L += ["", "The failing technique is visible in each scene's chart (the line far above "
              "the others) and in its `direct` image grid.", ""]
    if "veach_mis" in scenes and "direct" in scenes["veach_mis"]["groups"]:
        L += ["## MIS heuristics on veach_mis (direct_mis, 1 light + 1 BSDF sample)", "",
              *_eff_table(scenes["veach_mis"], "direct"), ""]
    # per scene
    L += _key_numbers(summary, stab)
    L += ["## Scenes", ""]
    for name, sc in scenes.items():
        w, h = sc["resolution"]
        L += [f"### {name}", "", f"`{sc['file']}` at {w}x{h} (defines "
              f"`{json.dumps(sc['defines'])}`).", ""]
        li = sc.get("lights")
        if li and li["count"] > 1:
            parts = []
            for k, v in li["power_pmf_by_type"].items():
                parts.append(f"{len(v)} x {k} (" + (f"{v[0]:.3f} each" if max(v) - min(v) < 1e-3
                                                     else f"{min(v):.3g}-{max(v):.3g}") + ")")
            L += [f"{li['count']} emitters; selection probabilities with `light_selection=power` "
                  f"(`nee_path`'s default; Mitsuba's `path` selects uniformly, "
                  f"{1 / li['count']:.3f} each): " + ", ".join(parts) + ".", ""]
        ref = sc["reference"]
        if "path" in sc["groups"]:
            L += _ref_lines(name, ref, "path")
        if "direct" in sc["groups"]:
            L += _ref_lines(name, ref.get("direct", ref), "direct")
        L += ["", f"![relMSE against time, {name}]({sc['chart_png']})", ""]
        for g, grp in sc["groups"].items():
            L += [f"**{GROUPS[g]['title']}**, efficiency at the largest budget:", "",
                  *_eff_table(sc, g), "",
                  f"Equal time (~{grp['equal_time']['target_time_s']:.2f} s per image: the "
                  "baseline's time at a quarter of the largest budget):", "",
                  f"![equal-time images, {name}, {g}]({grp['grid_png']})", ""]
        # diagnostics
        L += ["Bias diagnostics, all renders of a method combined (spp-weighted): the signed "
              "relative error mean((x - ref) / sqrt(ref^2 + 0.01)) with its z (standard error "
              "from the spread over renders and the reference's variance); the relative "
              "difference of the image means (dominated by the brightest pixels); the relMSE of "
              "the combined image over its prediction for an unbiased estimator, "
              "(relMSE_last - relMSE_ref) x spp_last / total_spp + relMSE_ref:", "",
              "| method | total spp | signed rel. error | z | image mean diff | "
              "combined relMSE / predicted | non-finite renders |",
              "|---|---:|---:|---:|---:|---:|---:|"]
        for l, d in sc["diagnostics"].items():
            sre = d.get("signed_relative_error")
            imd = d.get("rel_diff_of_image_means")
            L.append(f"| `{l}` | {d['total_spp']} | "
                     f"{'n/a' if sre is None else format(100 * sre, '+.3f') + ' %'} | "
                     f"{_f(d.get('z_signed_relative_error'), '+.1f')} | "
                     f"{'n/a' if imd is None else format(100 * imd, '+.3f') + ' %'} | "
                     f"{_f(d.get('combined_over_predicted'), '.2f')} | "
                     f"{d['nonfinite_renders']} |")
        L.append("")
    # notes
    notes = _notes(summary)
    L += ["## Flags", ""] + (notes or ["None raised."]) + [""]
    return "\n".join(L)


def _emitter_share(name, sc):
    n = sc.get("emitter_pixels")
    if n is None:
        return f"{name} n/a"
    w, h = sc["resolution"]
    parts = []
    for g in sc["groups"].values():
        b = g.get("baseline")
        if not b:
            continue
        e = g["efficiency_at_largest_budget"][b]
        if e["relmse"] and e.get("relmse_without_emitter_pixels") is not None:
            share = 1 - (w * h - n) * e["relmse_without_emitter_pixels"] / (w * h * e["relmse"])
            parts.append(f"{100 * share:.0f} % of `{b}`'s")
    return f"{name} {n} ({', '.join(parts) or 'n/a'})"


def _key_numbers(summary, stab):
    scenes = summary["scenes"]
    L = ["## Key numbers", ""]
    for name, sc in scenes.items():
        g = sc["groups"].get("path")
        if not g or not g.get("baseline"):
            continue
        e = g["efficiency_at_largest_budget"]
        ours = [l for l in g["methods"] if l != g["baseline"] and e[l]["efficiency_vs_baseline"]]
        if not ours:
            continue
        best = max(ours, key=lambda l: e[l]["efficiency_vs_baseline"])
        L.append(f"- {name}: best of ours `{best}` at **{e[best]['efficiency_vs_baseline']:.2f}x** "
                 f"the efficiency of Mitsuba `path`"
                 + (f"; `nee_path` {e['nee_path']['efficiency_vs_baseline']:.2f}x, at "
                    f"{e['nee_path']['samples_per_s_vs_baseline']:.2f}x its samples/s"
                    if "nee_path" in e and e["nee_path"]["efficiency_vs_baseline"] else "")
                 + (f"; without emitter pixels: `{best}` "
                    f"{e[best]['efficiency_without_emitter_pixels_vs_baseline']:.2f}x"
                    if sc.get("emitter_pixels") and
                    e[best].get("efficiency_without_emitter_pixels_vs_baseline") else "")
                 + (f"; geometric mean over the 3 largest budgets: "
                    f"{e[best]['efficiency_vs_baseline_3_largest']:.2f}x"
                    if e[best].get("efficiency_vs_baseline_3_largest") else "") + ".")
    sps = [sc["groups"]["path"]["efficiency_at_largest_budget"]["nee_path"]
           ["samples_per_s_vs_baseline"] for sc in scenes.values()
           if "path" in sc["groups"] and "nee_path" in sc["groups"]["path"]["methods"]
           and sc["groups"]["path"].get("baseline")]
    if sps:
        srt = sorted(sps)
        med = srt[len(srt) // 2] if len(srt) % 2 else 0.5 * (srt[len(srt) // 2 - 1]
                                                            + srt[len(srt) // 2])
        L.append(f"- `nee_path` samples/s relative to `path` (largest budget): median "
                 f"{med:.2f} over {len(sps)} scenes (range {srt[0]:.2f}-{srt[-1]:.2f}).")
    for n, r in stab.items():
        line = (f"- stability, {n}: `{r['best_mis']}` is {r['efficiency_mis_over_best_single']:.2f}x "
                f"as efficient as the best single technique (`{r['best_single']}`) and "
                f"{r['efficiency_mis_over_worst_single']:.3g}x the failing one "
                f"(`{r['worst_single']}`)")
        if "best_mis_without_emitter_pixels" in r:
            line += (f"; without the emitter pixels `{r['best_mis_without_emitter_pixels']}` "
                     f"{r['efficiency_mis_over_best_single_without_emitter_pixels']:.2f}x the "
                     f"best single (`{r['best_single_without_emitter_pixels']}`) and "
                     f"{r['efficiency_mis_over_worst_single_without_emitter_pixels']:.3g}x the "
                     "failing one")
        L.append(line + ".")
    L.append("")
    return L


def _notes(summary):
    out = []
    for name, sc in summary["scenes"].items():
        refs = [("path", sc["reference"])]
        if "direct" in sc["reference"]:
            refs.append(("direct", sc["reference"]["direct"]))
        for g, ref in refs:
            if not ref["check_vs_mitsuba_path"]["passed"]:
                out.append(f"- {name}: the {g} reference differs from Mitsuba `path` "
                           f"(p = {ref['check_vs_mitsuba_path']['p_value']:.3g}).")
            r = ref.get("smallest_charted_over_relmse_self")
            if r is not None and r < 10:
                out.append(f"- {name}: the {g} reference's own relMSE is only {r:.1f}x below "
                           "the smallest charted error.")
        for l, d in sc["diagnostics"].items():
            z, c = d.get("z_signed_relative_error"), d.get("combined_over_predicted")
            if z is not None and abs(z) > 4:
                out.append(f"- {name}, `{l}`: **looks biased**: signed relative error "
                           f"{100 * d['signed_relative_error']:+.3f} % against the reference, "
                           f"z = {z:+.1f}; image mean {100 * d['rel_diff_of_image_means']:+.3f} "
                           f"%; combined relMSE {_f(c, '.2f')}x its unbiased prediction.")
            elif c is not None and c > 2:
                out.append(f"- {name}, `{l}`: heavy-tailed (or biased below the noise): the "
                           f"combined image's relMSE is {c:.2f}x its prediction from the "
                           "largest budget, while its signed relative error agrees with the "
                           f"reference ({100 * d['signed_relative_error']:+.3f} %, z = "
                           f"{_f(z, '+.1f')}): rare large samples that the renders at the "
                           "largest budget mostly miss.")
            if d["nonfinite_renders"]:
                out.append(f"- {name}, `{l}`: {d['nonfinite_renders']} renders with NaN/Inf "
                           "(left out of the errors).")
    return out


if __name__ == "__main__":
    sys.exit(main())
