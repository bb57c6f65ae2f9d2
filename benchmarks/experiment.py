"""One scene of the experiments, in this process: references, measurement, figures, results.

:class:`Worker` is what ``python -m benchmarks run --worker SCENE`` runs (one process per scene:
every BSDF alive in a process is compiled into every kernel).  The method is described in
:mod:`benchmarks.run`; the parts live in :mod:`benchmarks.references` (the reference per group),
:mod:`benchmarks.timing` (round-robin rounds), :mod:`benchmarks.metrics` (errors) and
:mod:`benchmarks.plots` (chart and image grids).
"""
from __future__ import annotations

import math
from pathlib import Path

from . import plots, references, timing
from .config import GROUPS, REFERENCE_SEED, REPO, SCENES, Settings, scene_file, scene_methods
from .metrics import (Ciede2000, Flip, errors, relmse, relmse_self, signed_relative_error,
                      srgb)


class Worker:
    def __init__(self, scene_name: str, settings: Settings, labels, cache: Path | None, out: Path):
        import integrators  # noqa: F401  (variant + plugin registration)
        import drjit as dr
        import mitsuba as mi
        import numpy as np
        self.dr, self.mi, self.np = dr, mi, np
        self.name, self.s, self.cache, self.out = scene_name, settings, cache, out
        spec = SCENES[scene_name]
        self.crop_centre = spec.crop_centre
        self.ref_spp = settings.ref_spp * spec.ref_scale
        self.defines = spec.defines(settings.width)
        self.path = scene_file(scene_name)
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
        self.method = {m.label: m for m in self.methods}
        self.flip = Flip()
        self.ciede = Ciede2000()
        self.seed = 10
        self.emitter_mask = self.emitter_pixels()

    def resolved(self, m) -> dict:
        """The integrator's type and every parameter (defaults filled in) for ours; for
        Mitsuba's own, the dict it was loaded from."""
        params = getattr(self.integ[m.label], "params", None)
        return {"type": m.integrator["type"], **params} if isinstance(params, dict) \
            else dict(m.integrator)

    def lights(self) -> dict:
        """The scene's emitters and the selection pmf of ``light_selection=power`` (nee_path's
        default; Mitsuba's path selects uniformly)."""
        from integrators.sampling.light_selection import selection_pmf
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

    def next_seed(self, *_):
        self.seed += 1
        return self.seed

    def _render(self, spp):
        """render(label, seed) -> (image, seconds) at ``spp`` for :func:`timing.round_robin`.

        A method that learns from its own samples (``mis3`` with ``selection=learned``: a render
        call learns from its first share of samples, then renders the rest) forgets what it
        learned before each render (``reset_learning``), so its learning is in the measured
        time and nothing learned in one render helps another."""
        def render(label, seed):
            integ = self.integ[label]
            if hasattr(integ, "reset_learning"):
                integ.reset_learning()
            return timing.timed_render(self.scene, integ, spp, seed)
        return render

    def _rgb(self, img):
        return self.np.array(img, dtype=self.np.float64)[..., :3]

    # -----------------------------------------------------------------------------------------
    def reference(self, group: str) -> tuple:
        """(reference image, its variance, info) of a group (:mod:`benchmarks.references`)."""
        spec = references.ReferenceSpec(
            name=self.name, scene_path=self.path, defines=self.defines, width=self.w,
            height=self.h, max_depth=GROUPS[group]["max_depth"], spp=self.ref_spp,
            passes=self.s.ref_passes, seed_first=REFERENCE_SEED[group])
        return references.get(spec, self.scene, self.cache,
                              log=lambda msg: self.log(f"{group} {msg}"))

    # -----------------------------------------------------------------------------------------
    def measure(self, refs):
        """Round-robin at each budget; returns {label: points}, per-method diagnostics and the
        relMSE without emitter pixels per point."""
        np = self.np
        points = {m.label: [] for m in self.methods}
        masked = {m.label: [] for m in self.methods}
        diag = {m.label: {"renders": 0, "nonfinite_renders": 0, "sum_spp": 0,
                          "means": [], "rel": [], "spps": [],
                          "acc": np.zeros((self.h, self.w, 3))}
                for m in self.methods}
        group_of = {m.label: m.group for m in self.methods}
        keep = ~self.emitter_mask
        t0 = timing.clock()
        for b in self.s.budgets:
            per = {m.label: {"rmse": [], "relmse": [], "flip": [], "de2000": [],
                             "relmse_masked": []}
                   for m in self.methods}

            def on_render(label, rnd, warm, img, dt, b=b, per=per):
                # every render counts for the errors (the warm-up too: it is a valid image)
                img = self._rgb(img)
                ref, _, _, ref_srgb = refs[group_of[label]]
                e = errors(img, ref, ref_srgb, self.flip, keep, self.ciede)
                for key, values in per[label].items():
                    if e[key] is not None:
                        values.append(e[key])
                d = diag[label]
                d["renders"] += 1
                if not e["finite"]:
                    d["nonfinite_renders"] += 1
                    return
                d["sum_spp"] += b
                d["means"].append(float(img.mean()))
                d["rel"].append(signed_relative_error(img, ref))
                d["spps"].append(b)
                d["acc"] += b * img

            t = timing.round_robin(self._render(b), [m.label for m in self.methods],
                                   rounds=self.s.repeats, warmup=1, rotate=True,
                                   seed=self.next_seed, on_render=on_render)
            for m in self.methods:
                p, st = per[m.label], t.stats(m.label)
                points[m.label].append({
                    "spp": b,
                    "time_s": float(st["median"]),
                    "time_s_min": float(st["min"]), "time_s_max": float(st["max"]),
                    "rmse": float(np.mean(p["rmse"])) if p["rmse"] else None,
                    "relmse": float(np.mean(p["relmse"])) if p["relmse"] else None,
                    "flip": float(np.mean(p["flip"])) if p["flip"] else None,
                    "de2000": float(np.mean(p["de2000"])) if p["de2000"] else None,
                })
                masked[m.label].append(float(np.mean(p["relmse_masked"]))
                                       if p["relmse_masked"] else None)
            self.log(f"spp {b:5d}: " + ", ".join(
                f"{m.label} {points[m.label][-1]['relmse']:.3g}" if points[m.label][-1]['relmse']
                is not None else f"{m.label} n/a" for m in self.methods)
                + f"  ({timing.clock() - t0:.0f} s)")
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
                ref_part = relmse_self(ref, var) / var.size
                se = math.sqrt(sigma2 / S + ref_part)
                means = np.array(d["means"])
                mean = float((spps * means).sum() / S)
                ref_mean = float(ref.mean())
                comb = d["acc"] / S
                rel_comb = relmse(comb, ref)
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
        """One render per method (after a warm-up) at about the baseline's time at a quarter of
        the largest budget; returns (target seconds, {label: {spp, time_s, relmse, image}})."""
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
            shot = {}

            def keep(label, rnd, warm, img, dt, shot=shot):
                if not warm:
                    shot["image"], shot["time_s"] = self._rgb(img), dt

            timing.round_robin(self._render(spp), [m.label], rounds=1, warmup=1,
                               seed=self.next_seed, on_render=keep)
            e = errors(shot["image"], ref, ref_srgb, self.flip, ciede=self.ciede)
            out[m.label] = {"spp": spp, "time_s": shot["time_s"], "relmse": e["relmse"],
                            "flip": e["flip"], "de2000": e["de2000"],
                            "image": shot["image"]}
        return target, out

    # -----------------------------------------------------------------------------------------
    def run(self) -> dict:
        t_start = timing.clock()
        refs, ref_info = {}, {}
        for g in self.groups:
            ref, var, info = self.reference(g)
            refs[g] = (ref, var, info, srgb(ref))
            ref_info[g] = info
        # warm-up of every method at each budget is round 0 of that budget
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
                    "de2000": last.get("de2000"),
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
            r = info["smallest_charted_over_relmse_self"]
            if r is not None:
                self.log(f"reference {g}: own relMSE {info['relmse_self']:.3g} is "
                         f"{r:.0f}x below the smallest charted relMSE {min_charted:.3g}"
                         + ("" if r >= 10 else "  ** WARNING: not far below **"))
            target, eq = self.equal_time(g, points, ref, ref_srgb)
            grid = f"{self.name}_{g}_grid.png"
            plots.grid(self.out / grid, self.name, g, ref, var, self.ref_spp, eq, target,
                       self.crop_centre)
            groups[g] = {
                "max_depth": GROUPS[g]["max_depth"], "baseline": base, "methods": labels,
                "efficiency_at_largest_budget": eff,
                "equal_time": {"target_time_s": target,
                               "renders": {l: {k: v for k, v in r.items() if k != "image"}
                                           for l, r in eq.items()}},
                "grid_png": grid,
            }
        chart = f"{self.name}_chart.png"
        plots.chart(self.out / chart, self.name, self.groups, points, ref_info)
        return {
            "file": str(self.path.relative_to(REPO)),
            "resolution": [self.w, self.h], "defines": self.defines,
            "reference": ref_info,
            "methods": {m.label: {"integrator": self.resolved(m), "given": dict(m.integrator),
                                  "points": points[m.label]}
                        for m in self.methods},
            "groups": groups, "diagnostics": diagnostics, "chart_png": chart,
            "emitter_pixels": int(self.emitter_mask.sum()),
            "lights": self.lights(),
            "relmse_without_emitter_pixels": masked,
            "flip_unavailable_reason": self.flip.reason,
            "de2000_unavailable_reason": self.ciede.reason,
            "worker_seconds": timing.clock() - t_start,
        }
