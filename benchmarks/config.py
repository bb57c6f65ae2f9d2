"""What the experiments measure: scenes, methods, groups, settings, and where things go.

Pure data (no Mitsuba import): the CLI validates its arguments against it before any process
loads Mitsuba.  Described in full in :mod:`benchmarks.run`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

REPO = Path(__file__).resolve().parent.parent
SCENES_DIR = REPO / "scenes"
DEFAULT_OUT = REPO / "out" / "experiments"        # untracked (the root .gitignore)
SNAPSHOT = REPO / "benchmarks" / "results" / "experiments"   # the committed full run

PATH_DEPTH = 4      # max_depth of every path method and of its reference
DIRECT_DEPTH = 2    # direct light only


@dataclass(frozen=True)
class Settings:
    name: str
    width: int                  # image width in pixels (height from the scene's aspect)
    budgets: tuple              # spp per render, increasing
    repeats: int                # timed renders per method and budget (plus one warm-up)
    ref_spp: int                # reference samples per pixel (times the scene's ref_scale)
    ref_passes: int             # reference passes (variance layer; furnace closed-form test)


FULL = Settings("full", 128, tuple(2 ** k for k in range(10)), 3, 16384, 16)
QUICK = Settings("quick", 64, tuple(2 ** k for k in range(8)), 1, 4096, 16)


@dataclass(frozen=True)
class Method:
    label: str
    group: str
    integrator: dict
    description: str


PATH_METHODS = (
    Method("path", "path", {"type": "path", "max_depth": PATH_DEPTH},
           "Mitsuba's built-in `path` (NEE + BSDF sampling, power heuristic, uniform light "
           "selection): the baseline"),
    Method("nee_path", "path", {"type": "nee_path", "max_depth": PATH_DEPTH},
           "our `nee_path`, defaults (power heuristic, light selection by power)"),
    Method("nee_path_adaptive", "path",
           {"type": "nee_path", "max_depth": PATH_DEPTH, "light_selection": "adaptive"},
           "our `nee_path`, adaptive light selection (per-point irradiance bound)"),
    Method("mis3", "path", {"type": "mis3", "max_depth": PATH_DEPTH},
           "our `mis3` with its defaults: the BSDF's own sample continues every path, the "
           "light-sample allocation (probability below one, expected count up to 4 above) "
           "learned per region for the image's relMSE x time from the render's own first "
           "samples (a sixteenth in all; learning is in the time), adaptive light selection, "
           "balance heuristic"),
    Method("mis3_fixed", "path",
           {"type": "mis3", "max_depth": PATH_DEPTH, "selection": "fixed"},
           "our `mis3` with the lecture's p-vector 1/3 each (a light sample with probability "
           "1/3, a lobe by the rest; every path continues), balance heuristic"),
    Method("mis3_adaptive", "path",
           {"type": "mis3", "max_depth": PATH_DEPTH, "selection": "adaptive"},
           "our `mis3` (one-sample MIS over cosine lobe, glossy lobe and light), technique "
           "probabilities adapted per vertex, balance heuristic"),
    Method("bsdf_path", "path", {"type": "bsdf_path", "max_depth": PATH_DEPTH},
           "our `bsdf_path`, BSDF sampling only (no light sampling)"),
    Method("bdpt", "path", {"type": "bdpt", "max_depth": PATH_DEPTH},
           "our `bdpt`, bidirectional path tracing: every (s, t) strategy, light tracing onto "
           "the film, power heuristic by ratio recurrences (area, point and spot lights only)"),
)
#: methods that render only some scenes (bdpt refuses environment emitters)
ONLY_ON = {"bdpt": ("cornell_box", "many_lights", "small_light", "sharp_glossy", "specular_box",
                    "caustic", "ajar_door", "glass_shade")}
HEURISTIC_NOTES = {
    "balance": "balance heuristic",
    "power": "power heuristic (beta 2)",
    "cutoff": "cutoff heuristic (alpha 0.1)",
    "maximum": "maximum heuristic",
    "average": "average (1 / number of techniques with non-zero pdf)",
    "partition": "partition (light hits count from light sampling only)",
}
# the direct group compares sampling techniques and heuristics, so every direct_mis method
# selects lights uniformly, as Mitsuba's direct does (the default, power, would change the
# light pmf as well: on veach_mis it gives the dim sky a third of the light samples)
DIRECT_SEL = {"light_selection": "uniform"}
DIRECT_METHODS = {
    "direct": Method("direct", "direct", {"type": "direct"},
                     "Mitsuba's built-in `direct` (1 emitter + 1 BSDF sample, power heuristic, "
                     "uniform light selection): the baseline of the direct-light group"),
    **{f"direct_mis_{h}": Method(f"direct_mis_{h}", "direct",
                                 {"type": "direct_mis", "heuristic": h, **DIRECT_SEL},
                                 f"our `direct_mis`, 1 light + 1 BSDF sample, {HEURISTIC_NOTES[h]}"
                                 ", uniform light selection")
       for h in HEURISTIC_NOTES},
    "light_only": Method("light_only", "direct",
                         {"type": "direct_mis", "light_samples": 1, "bsdf_samples": 0,
                          **DIRECT_SEL},
                         "our `direct_mis`, light sampling only (light_samples 1, bsdf_samples 0)"),
    "bsdf_only": Method("bsdf_only", "direct",
                        {"type": "direct_mis", "light_samples": 0, "bsdf_samples": 1,
                         **DIRECT_SEL},
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

#: seed of a group's first reference pass (the references of the two groups are independent)
REFERENCE_SEED = {"path": 1_000_000, "direct": 1_100_000}


def _veach_defines(w):
    return {"width": str(w), "height": str(round(w * 216 / 384))}


def _res_defines(w):
    return {"res": str(w)}


class Scene(NamedTuple):
    defines: Callable[[int], dict]   # width -> the scene file's defines
    crop_centre: tuple               # of the zoomed crop, fractions of width and height
    direct_methods: tuple            # labels of the direct group's methods (none: no group)
    ref_scale: int                   # reference spp = settings.ref_spp x ref_scale


# The furnace's reference is the closed form except on the pixels the silhouette crosses, whose
# noise is then all that bsdf_path (zero variance inside: cosine sampling of a diffuse BSDF under
# constant radiance) has: those pixels need more samples.  many_lights: the reference is Mitsuba's
# path, which selects among the 64 lights uniformly; at 16384 spp its own relMSE would be only
# about 3x below nee_path_adaptive's error at 512 spp (estimated from the snapshot run), so 8x.
SCENES = {
    "veach_mis": Scene(_veach_defines, (0.17, 0.33), HEURISTIC_LABELS, 1),
    "cornell_box": Scene(_res_defines, (0.35, 0.8), (), 1),
    "many_lights": Scene(_res_defines, (0.72, 0.42), (), 8),
    "small_light": Scene(_res_defines, (0.62, 0.5), STABILITY_LABELS, 1),
    "sharp_glossy": Scene(_res_defines, (0.5, 0.78), STABILITY_LABELS, 1),
    "furnace": Scene(_res_defines, (0.8, 0.5), (), 8),
    "specular_box": Scene(_res_defines, (0.33, 0.72), (), 4),
    # issue 17 (bdpt): light reaches what the camera sees through glass or a gap; path's
    # references need more samples there (caustics)
    "caustic": Scene(_res_defines, (0.5, 0.72), (), 8),
    "ajar_door": Scene(_res_defines, (0.45, 0.8), (), 4),
    "glass_shade": Scene(_res_defines, (0.3, 0.3), (), 8),
}

# the stability study's stated bound: MIS (1 light + 1 BSDF sample) is at least 1/STABILITY_FACTOR
# as efficient as the best single technique (it pays for both techniques' rays; where one
# technique finds nothing, MIS at best ties the other at equal samples, so 2x is the cost of
# the wasted rays).  Checked in the report.
STABILITY_FACTOR = 2.0

# remarks a reader needs next to a scene's headline numbers
SCENE_NOTES = {
    "furnace": "BSDF sampling is exact inside the silhouette here, since cosine sampling of a "
               "diffuse BSDF under constant radiance has zero variance: `bsdf_path`'s ratio only "
               "measures the silhouette pixels",
}


def scene_file(name: str) -> Path:
    return SCENES_DIR / f"{name}.xml"


def scene_methods(scene: str) -> list:
    return [m for m in PATH_METHODS if scene in ONLY_ON.get(m.label, (scene,))] + \
        [DIRECT_METHODS[k] for k in SCENES[scene].direct_methods]


def all_methods() -> list:
    return list(PATH_METHODS) + [m for k, m in DIRECT_METHODS.items()
                                 if k not in {p.label for p in PATH_METHODS}]


def all_labels() -> list:
    return [m.label for m in all_methods()]


def reference_integrator(depth: int) -> dict:
    """The reference of a group: Mitsuba's own ``path`` at the group's ``max_depth`` (at 2 it
    is direct light only), never one of the estimators under test."""
    return {"type": "path", "max_depth": int(depth)}


def cache_default() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "integrators-bench"
