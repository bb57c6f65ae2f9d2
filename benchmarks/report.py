"""``report.md`` of the experiments, from ``summary.json`` alone (``--report-only`` reruns it).

Every number in the report is read from the summary; the text that describes how the run was
made (command, settings, reference integrators) comes from its ``meta``, so a report rewritten
from an older summary still describes that run.
"""
from __future__ import annotations

import json

from .config import GROUPS, PATH_METHODS, SCENE_NOTES, STABILITY_FACTOR


def _integrator_text(integ: dict) -> str:
    mitsuba = integ.get("type") in ("path", "direct")
    return ("Mitsuba's " if mitsuba else "our ") + f"`{json.dumps(integ)}`"


def _references_text(meta) -> str:
    """The reference integrator of each group, as the summary records it."""
    refs = meta.get("reference_integrators") or {}
    return "; ".join(f"{g}: {_integrator_text(i)}" for g, i in refs.items()) or "n/a"


def _f(x, fmt=".3g"):
    return "n/a" if x is None else format(x, fmt)


def _eff_table(sc, g):
    grp = sc["groups"][g]
    eff = grp["efficiency_at_largest_budget"]
    lines = ["| method | spp | time (s) | relMSE | FLIP | ΔE00 | M samples/s "
             "| samples/s vs baseline "
             "| efficiency 1/(relMSE x s) | **vs baseline** | vs baseline, 3 largest budgets "
             "| relMSE without emitter pixels | vs baseline, without emitter pixels |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for l in grp["methods"]:
        e = eff[l]
        lines.append(f"| `{l}` | {e['spp']} | {e['time_s']:.3f} | {_f(e['relmse'])} | "
                     f"{_f(e['flip'], '.3f')} | {_f(e.get('de2000'), '.3f')} | "
                     f"{e['samples_per_s'] / 1e6:.2f} | "
                     f"{_f(e['samples_per_s_vs_baseline'], '.2f')} | {_f(e['efficiency'])} | "
                     f"**{_f(e['efficiency_vs_baseline'], '.2f')}** | "
                     f"{_f(e.get('efficiency_vs_baseline_3_largest'), '.2f')} | "
                     f"{_f(e.get('relmse_without_emitter_pixels'))} | "
                     f"{_f(e.get('efficiency_without_emitter_pixels_vs_baseline'), '.2f')} |")
    return lines


def _ref_lines(name, ref, group):
    ratio = ref.get("smallest_charted_over_relmse_self")
    lines = [
        f"- reference ({group}, max_depth {ref['max_depth']}): {_integrator_text(ref['integrator'])} "
        f"at {ref['spp']} spp in {ref['passes']} passes"
        + (f" (rendered in {ref['render_seconds']:.0f} s)" if ref.get("render_seconds") else "")
        + ("; from the cache" if ref.get("cached") else "")
        + (f"; cache key `{ref['key']}`" if ref.get("key") else "") + ".",
        f"  Own relMSE (variance layer) {_f(ref['relmse_self'])}, "
        + (f"**{ratio:.0f}x below** the smallest charted relMSE ({_f(ref['smallest_charted_relmse'])})"
           if ratio else "no charted error")
        + ("" if ratio is None or ratio >= 10 else " -- **WARNING: not far below; the smallest "
           "errors are partly the reference's**") + ".",
    ]
    c = ref.get("check_vs_mitsuba_path")       # summaries whose reference was not Mitsuba's
    if c:
        lines.append(
            f"  Against Mitsuba `path` (max_depth {ref['max_depth']}, {c['path_batches']} x "
            f"{c['path_spp_per_batch']} spp): image_test p = {c['p_value']:.3g} "
            f"({'passed' if c['passed'] else '**FAILED**'} at alpha {c['alpha']:g}), image means "
            f"differ by {100 * c['rel_diff_of_image_means']:.3f} %.")
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
        r["within_stated_factor"] = {
            suffix or "all": r["efficiency_mis_over_best_single" + suffix] >= 1 / STABILITY_FACTOR
            for suffix in ("", "_without_emitter_pixels")
            if "efficiency_mis_over_best_single" + suffix in r}
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
          f"{_references_text(meta)}, {s['ref_spp']} spp (times a per-scene factor, see the "
          f"scenes) in {s['ref_passes']} passes, cached in `{meta['reference_cache']}`. "
          "Full description: `benchmarks/run.py`. "
          "relMSE = mean((x - ref)^2 / (ref^2 + 0.01)); efficiency = 1 / (relMSE x time) at "
          "the largest budget, relative to the group's Mitsuba baseline (`path`, `direct`). "
          "FLIP: " + meta["flip"] + (f" -- unavailable: {meta['flip_unavailable']}"
                                     if meta.get("flip_unavailable") else "") + "."
          + (" ΔE00 (CIEDE2000, colour-science; about 1 is a just-noticeable difference): "
             + meta["de2000"] + (f" -- unavailable: {meta['de2000_unavailable']}"
                                 if meta.get("de2000_unavailable") else "") + "."
             if meta.get("de2000") else ""), ""]
    cl = meta.get("cluster")
    if cl:
        L += [f"Run on a Dask cluster ({cl['how']}, {cl['slots']} task slots): the "
              f"references first ({cl['reference_tasks']} tasks), then one task per scene, "
              "each task the same worker process as a sequential run (one scene per "
              "process). Errors are those of a sequential run (same seeds); the timings of "
              "scenes that ran at the same time on one machine share its cores.", ""]
    spreads = sorted((p["time_s_max"] - p["time_s_min"]) / p["time_s"]
                     for sc in scenes.values() for m in sc["methods"].values()
                     for p in m["points"] if p.get("time_s_max") is not None and p["time_s"] > 0)
    noise = (f"the spread (max - min) / median of a point's timed renders has median "
             f"{100 * spreads[len(spreads) // 2]:.0f} % and 90th percentile "
             f"{100 * spreads[int(0.9 * (len(spreads) - 1))]:.0f} %" if spreads and s["repeats"] > 1
             else "one timed render per point in this run: spread not measured")
    L += [f"Single renders on a shared 2-core machine: timings are noisy ({noise}), and "
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
            seen.setdefault(l, m.get("given", m["integrator"]))
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
              f"Stated bound: MIS at least 1/{STABILITY_FACTOR:g} as efficient as the best single "
              "technique (it casts both techniques' rays, so where one technique finds nothing "
              f"it pays {STABILITY_FACTOR:g}x for the same error).", "",
              "| scene | pixels | best single | best MIS | efficiency MIS / best single | "
              f"within {STABILITY_FACTOR:g}x | "
              "MIS / worst single | relMSE best single / MIS (equal spp) | worst single / MIS |",
              "|---|---|---|---|---:|---|---:|---:|---:|"]
        for n, r in stab.items():
            for suffix, what in (("", "all"), ("_without_emitter_pixels",
                                               "without emitter pixels")):
                if "best_single" + suffix not in r:
                    continue
                L.append(f"| {n} | {what} | `{r['best_single' + suffix]}` | "
                         f"`{r['best_mis' + suffix]}` | "
                         f"{r['efficiency_mis_over_best_single' + suffix]:.2f} | "
                         + ("yes" if r["efficiency_mis_over_best_single" + suffix]
                            >= 1 / STABILITY_FACTOR else "**no**") + " | "
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
        for g, ref in sc["reference"].items():
            L += _ref_lines(name, ref, g)
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
                    if e[best].get("efficiency_vs_baseline_3_largest") else "")
                 + (f" ({SCENE_NOTES[name]})" if name in SCENE_NOTES else "") + ".")
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
        ok = all(r.get("within_stated_factor", {}).values())
        line += (f"; {'within' if ok else '**outside**'} the stated {STABILITY_FACTOR:g}x bound")
        L.append(line + ".")
    L.append("")
    return L


def _notes(summary):
    out = []
    for name, sc in summary["scenes"].items():
        for g, ref in sc["reference"].items():
            c = ref.get("check_vs_mitsuba_path")
            if c and not c["passed"]:
                out.append(f"- {name}: the {g} reference differs from Mitsuba `path` "
                           f"(p = {c['p_value']:.3g}).")
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


