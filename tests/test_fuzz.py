"""Fuzz: random valid scenes rendered by every integrator (issue 12, item 6).

**Generator.** :func:`random_scene` turns a seed into a valid Mitsuba scene dict (numpy's
``default_rng``: a seed always gives the same scene): 2-5 shapes (sphere, cube, rectangle, disk,
cylinder) with random transforms (non-uniform scales except spheres and cylinder radii, some
``flip_normals``), sometimes a diffuse floor; each shape a random BSDF: ``diffuse``,
``dielectric``, ``roughdielectric``, ``thindielectric``, ``conductor`` and ``roughconductor``
(named metals, isotropic or anisotropic, beckmann or ggx), ``plastic``, ``roughplastic``,
``null``, ``twosided`` around a one-sided BSDF, ``mask``, ``blendbsdf``, ``principled`` and our
``phong`` (max rho_d + max rho_g <= 1, exponent 0 to 2000), reflectances sometimes a
checkerboard; lights of every type, each kind present or absent at random (at least one
light): 0-2 ``area`` lights on random shapes (RGB, or on a rectangle or disk sometimes a
bitmap texture with values above 1),
in half the scenes 0-2 ``point``, 0-1 ``spot`` (cutoff 5-80 degrees) and 0-1 ``directional``,
0-1 environment (``constant``, or ``envmap`` with a small random bitmap and a bright spot); a
perspective camera 3.5-6 away looking at the scene; an 8x8 to 16x16 film, box filter;
``max_depth`` 2-6 or unlimited; sometimes ``hide_emitters``.  Four restrictions come from
Mitsuba 3.9.1 itself, not from ours (see ``random_scene``): no ``null`` BSDF on an area light
(``path`` renders the light black, ``direct`` and ``volpath`` do not); bitmap-textured lights
only on unflipped rectangles and disks (elsewhere Mitsuba's texture-driven light sampling
disagrees with the emission a ray finds: on a cube ``bsdf_path`` reads 28 % above ``path``;
Mitsuba's own ``direct`` with light samples only reads 6 % above BSDF samples only on a
sphere, 23 % on a flipped rectangle); no ``hide_emitters`` in a scene with a ``null``,
``mask`` or ``thindielectric`` surface (``path`` and ``volpath`` hide the environment seen
through one, ``direct`` and ours do not); flipped normals only on a shape whose BSDF no other
shape shares (Mitsuba merges shapes of equal BSDFs and then refuses to load the scene).

**Checks.** Each scene is rendered by every configuration in :data:`OURS` (``bsdf_path`` in
each hemisphere mode, ``direct_mis``, ``nee_path`` with three rr / light-selection / heuristic
settings, ``mis3`` fixed and adaptive), 16 batches of 256 spp with distinct seeds:

* **finite**: every pixel of every batch finite (no NaN, no Inf), always, on every scene;
* **the same expected image as Mitsuba's** ``path`` at the scene's ``max_depth`` (for
  ``direct_mis``: ``path`` at ``max_depth`` 2, direct light at the first hit with emission found
  through delta lobes and null surfaces counted as ``direct_mis`` counts it; ``direct`` is not
  the reference: it makes point lights N times too bright, mitsuba3 #1861), rendered with the
  same budget and other seeds.  H0: the same expected image.  Welch t on the batch means
  (:func:`integrators.testing.image_test`), twice: per 4x4 block and channel, Sidak over them
  (a local bias), and over the whole image per channel (a small bias spread over the image);
  each rejected at the kit's alpha = 1.5e-5.

**Comparisons left out**, by rules fixed on the scene and on the noise alone, never on a
p-value or per integrator (every integrator still renders the scene for the finite check):

1. ``bsdf_path`` on scenes with point, spot or directional lights (BSDF sampling cannot reach
   them; it warns, and its image lacks their light by design);
2. scenes where Mitsuba's own ``path`` is too noisy for a t-test: median relative standard
   error of a 4x4 block of the reference above 2 % (heavy tails: caustics through rough glass
   from small lights, dark scenes lit through chains of delta surfaces), or a reference with
   non-finite pixels (Mitsuba's problem);
3. a comparison whose median block relative s.e. of the difference (both sides) is above 3 %
   (``bsdf_path`` finding small lights only by chance): a t-test on 16 heavy-tailed batch means
   is not trustworthy.  Where a comparison is made, a 10 % bias therefore gives |t| >= 3.3 in
   half the blocks, and far more over the whole image; most comparisons sit at 0.05-1 %.
4. scenes with a ``mask`` surface: Mitsuba 3.9.1's ``path`` renders one up to ``opacity``
   times too dark (``volpath``, ``direct`` and ours agree with each other there);
   ``test_reduced_mask_surface_matches_volpath`` compares ours on such a surface instead.

5. scenes with ``hide_emitters`` and an area light: Mitsuba's ``path`` and ``direct`` shade a
   camera path that passed a hidden light as if no area light were in the scene (no light from
   any of them, no shadow from the hidden one), ours keep them
   (``test_reduced_hide_emitters_closed_light``, an open discrepancy).

``test_fast_set_compared_every_integrator`` fails if these rules leave an integrator compared
on fewer than two fast scenes.

**False-failure budget** (union bound, alpha = 1.5e-5 per check, two checks per comparison):
the fast set (7 scenes x at most 9 comparisons x 2 = 126 checks, 78 made) and the ten reduced
cases add at most 0.2 % to a run's false-failure bound; the slow set (30 more scenes, at most
540 checks, about half of them made) at most 0.81 %.  The kit's end-of-run line counts
every check that ran.  Seeds are fixed, so a checkout passes or fails deterministically.

**Reduced cases** at the end of the file are fuzz failures minimised by removing scene
elements (a failing one stays, failing, until the plugin is fixed; then it is a regression
test).
"""
from __future__ import annotations

import math
import warnings
from collections import Counter

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.testing import assert_unbiased, batch_images, image_test

T = mi.ScalarTransform4f

SHAPES = ("sphere", "cube", "rectangle", "disk", "cylinder")
BSDFS = ("diffuse", "dielectric", "roughdielectric", "thindielectric", "conductor",
         "roughconductor", "plastic", "roughplastic", "null", "twosided", "phong",
         "mask", "blendbsdf", "principled")
#: how often each kind is drawn: mask less often, since a scene with one is not compared
#: with path (rule 4 of the module docstring)
BSDF_WEIGHTS = np.array([0.35 if k == "mask" else 1.0 for k in BSDFS]) / \
    sum(0.35 if k == "mask" else 1.0 for k in BSDFS)
#: reflecting-only BSDFs (what ``twosided`` may wrap)
ONE_SIDED = ("diffuse", "conductor", "roughconductor", "plastic", "roughplastic", "phong")
CONDUCTORS = ("Au", "Ag", "Al", "Cu", "Cr", "none")
LIGHTS = ("area", "point", "spot", "directional", "constant", "envmap")
DELTA_LIGHTS = ("point", "spot", "directional")
DEPTHS = (2, 3, 4, 5, 6, -1)


# ---- the generator ---------------------------------------------------------------------------
def _rgb(rng, lo, hi):
    return {"type": "rgb", "value": [float(v) for v in rng.uniform(lo, hi, 3)]}


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _reflectance(rng, lo=0.05, hi=0.95):
    """An RGB reflectance, or sometimes a checkerboard of two."""
    if rng.random() < 0.2:
        return {"type": "checkerboard", "color0": _rgb(rng, lo, hi), "color1": _rgb(rng, lo, hi),
                "to_uv": T().scale([float(rng.integers(1, 5))] * 3)}
    return _rgb(rng, lo, hi)


def random_bsdf(rng, kind=None):
    """A random BSDF dict of ``kind`` (random when None), parameters within their ranges."""
    kind = kind or str(rng.choice(BSDFS, p=BSDF_WEIGHTS))
    d = {"type": kind}
    if kind == "diffuse":
        d["reflectance"] = _reflectance(rng)
    elif kind in ("dielectric", "thindielectric"):
        d["int_ior"] = float(rng.uniform(1.05, 2.4))
    elif kind == "roughdielectric":
        d["int_ior"] = float(rng.uniform(1.05, 2.4))
        d["distribution"] = str(rng.choice(["beckmann", "ggx"]))
        d["alpha"] = float(rng.uniform(0.05, 0.8))
    elif kind in ("conductor", "roughconductor"):
        d["material"] = str(rng.choice(CONDUCTORS))
        if kind == "roughconductor":
            d["distribution"] = str(rng.choice(["beckmann", "ggx"]))
            if rng.random() < 0.3:
                d["alpha_u"], d["alpha_v"] = (float(a) for a in rng.uniform(0.05, 0.8, 2))
            else:
                d["alpha"] = float(rng.uniform(0.05, 0.8))
    elif kind in ("plastic", "roughplastic"):
        d["diffuse_reflectance"] = _reflectance(rng)
        d["int_ior"] = float(rng.uniform(1.2, 2.0))
        d["nonlinear"] = bool(rng.random() < 0.5)
        if kind == "roughplastic":
            d["distribution"] = str(rng.choice(["beckmann", "ggx"]))
            d["alpha"] = float(rng.uniform(0.05, 0.6))
    elif kind == "twosided":
        d["bsdf"] = random_bsdf(rng, str(rng.choice(ONE_SIDED)))
    elif kind == "phong":
        rho_d = rng.uniform(0.0, 1.0, 3)
        # phong refuses max(rho_d) + max(rho_g) > 1 (over texture and channels)
        rho_g = rng.uniform(0.0, 1.0, 3) * (1.0 - rho_d.max())
        d["diffuse_reflectance"] = {"type": "rgb", "value": [float(v) for v in rho_d]}
        d["specular_reflectance"] = {"type": "rgb", "value": [float(v) for v in rho_g]}
        d["exponent"] = 0.0 if rng.random() < 0.05 else \
            float(math.exp(rng.uniform(0.0, math.log(2000.0))))
    elif kind == "mask":
        d["opacity"] = float(rng.uniform(0.1, 0.9))
        d["bsdf"] = random_bsdf(rng, str(rng.choice(ONE_SIDED + ("dielectric",))))
    elif kind == "blendbsdf":
        d["weight"] = float(rng.uniform(0.0, 1.0))
        d["bsdf_0"] = random_bsdf(rng, str(rng.choice(ONE_SIDED)))
        d["bsdf_1"] = random_bsdf(rng, str(rng.choice(ONE_SIDED + ("dielectric",
                                                                   "roughdielectric"))))
    elif kind == "principled":
        d["base_color"] = _rgb(rng, 0.05, 0.95)
        for p in ("metallic", "spec_trans", "anisotropic", "sheen", "clearcoat"):
            if rng.random() < 0.5:
                d[p] = float(rng.uniform(0.0, 1.0))
        d["roughness"] = float(rng.uniform(0.05, 1.0))
    return d


def _kind(bsdf):
    inner = [bsdf[k] for k in ("bsdf", "bsdf_0", "bsdf_1") if k in bsdf]
    return bsdf["type"] + ("(" + ",".join(_kind(b) for b in inner) + ")" if inner else "")


def random_shape(rng, kind=None):
    """A random shape dict of ``kind`` (random when None) near the origin."""
    kind = kind or str(rng.choice(SHAPES))
    pos = rng.uniform(-1.0, 1.0, 3)
    axis, angle = _unit(rng), float(rng.uniform(0, 360))
    if kind in ("sphere", "cylinder"):      # spheres take no non-uniform scale
        s = float(rng.uniform(0.25, 0.7))
        scale = [s, s, s if kind == "sphere" else float(rng.uniform(0.3, 1.2))]
    else:
        scale = [float(v) for v in rng.uniform(0.25, 1.0, 3)]
    d = {"type": kind, "to_world": T().translate(pos.tolist()).rotate(axis.tolist(), angle)
         .scale(scale)}
    if kind != "sphere" and rng.random() < 0.2:
        d["flip_normals"] = True
    return d


def _radiance(rng, shape):
    """An area light's radiance: RGB, or sometimes a bitmap texture with values above 1, on an
    unflipped rectangle or disk only: on other shapes Mitsuba 3.9.1's texture-driven sampling
    of the light (uv -> surface point) disagrees with the emission a ray finds (a cube's faces
    share one uv square: bsdf_path 28 % above path; Mitsuba's direct, light samples only
    against BSDF samples only: sphere +6 %, stretched cylinder 1 %, flipped rectangle +23 %)."""
    kind = shape["type"]
    if kind != "cube" and rng.random() < 0.25 and kind in ("rectangle", "disk") \
            and not shape.get("flip_normals"):
        n = int(rng.integers(2, 5))
        img = rng.uniform(0.0, 8.0, (n, n, 3)).astype(np.float32)
        return {"type": "bitmap", "bitmap": mi.Bitmap(img), "raw": True,
                "filter_type": str(rng.choice(["nearest", "bilinear"]))}
    return _rgb(rng, 0.5, 8.0)


def random_scene(seed: int, res: int | None = None):
    """(scene dict, facts) for ``seed``; ``facts`` holds the kinds used, ``max_depth``,
    ``hide_emitters``, ``delta_lights`` (the scene has point, spot or directional lights) and
    ``mask`` (a surface has a mask BSDF).  ``res`` fixes the film size (default: 8-16)."""
    rng = np.random.default_rng(seed)
    facts = {"seed": seed, "shapes": [], "bsdfs": [], "lights": []}
    d = {"type": "scene"}
    for i in range(int(rng.integers(2, 6))):
        s = random_shape(rng)
        s["bsdf"] = random_bsdf(rng)
        facts["shapes"].append(s["type"])
        facts["bsdfs"].append(_kind(s["bsdf"]))
        d[f"shape{i}"] = s
    if rng.random() < 0.5:                                  # a floor for interreflection
        d["floor"] = {"type": "rectangle", "bsdf": random_bsdf(rng, "diffuse"),
                      "to_world": T().translate([0, -1.3, 0]).rotate([1, 0, 0], -90).scale(4.0)}
    counts = {"area": int(rng.integers(0, 3)), "point": 0, "spot": 0, "directional": 0}
    if rng.random() < 0.5:                                  # half the scenes: delta lights
        counts = {**counts, "point": int(rng.integers(0, 3)),
                  "spot": int(rng.random() < 0.4), "directional": int(rng.random() < 0.4)}
        if not (counts["point"] or counts["spot"] or counts["directional"]):
            counts[str(rng.choice(DELTA_LIGHTS))] = 1
    env = rng.random()
    counts["constant"], counts["envmap"] = int(env < 0.25), int(0.25 <= env < 0.5)
    if not any(counts.values()):                            # at least one light
        counts[str(rng.choice(LIGHTS))] = 1
    for k in LIGHTS:
        for j in range(counts[k]):
            facts["lights"].append(k)
            name = f"{k}{j}"
            if k == "area":
                s = random_shape(rng)
                # no null BSDF on a light: Mitsuba's path renders such a light black
                s["bsdf"] = random_bsdf(rng, str(rng.choice(["diffuse", "conductor",
                                                              "dielectric", "phong"])))
                s["emitter"] = {"type": "area", "radiance": _radiance(rng, s)}
                facts["shapes"].append(s["type"])
                facts["bsdfs"].append(_kind(s["bsdf"]))
                d[name] = s
            elif k == "point":
                d[name] = {"type": "point", "position": rng.uniform(-2.0, 2.0, 3).tolist(),
                           "intensity": _rgb(rng, 0.5, 10.0)}
            elif k == "spot":
                cutoff = float(rng.uniform(5.0, 80.0))
                d[name] = {"type": "spot", "intensity": _rgb(rng, 1.0, 20.0),
                           "cutoff_angle": cutoff,
                           "beam_width": float(cutoff * rng.uniform(0.1, 1.0)),
                           "to_world": T().look_at(rng.uniform(-2.5, 2.5, 3).tolist(),
                                                   rng.uniform(-0.5, 0.5, 3).tolist(),
                                                   _unit(rng).tolist())}
            elif k == "directional":
                d[name] = {"type": "directional",
                           "direction": (-_unit(rng) + [0.0, -1.0, 0.0]).tolist(),
                           "irradiance": _rgb(rng, 0.3, 4.0)}
            elif k == "constant":
                d["env"] = {"type": "constant", "radiance": _rgb(rng, 0.05, 1.0)}
            elif k == "envmap":
                h = int(rng.integers(2, 9))
                img = rng.uniform(0.0, 1.0, (h, 2 * h, 3)) ** 3
                img[rng.integers(h), rng.integers(2 * h)] *= 30.0      # a bright spot
                d["env"] = {"type": "envmap", "bitmap": mi.Bitmap(img.astype(np.float32)),
                            "scale": float(rng.uniform(0.2, 2.0)),
                            "to_world": T().rotate(_unit(rng).tolist(),
                                                   float(rng.uniform(0, 360)))}
    # Mitsuba 3.9.1 merges shapes whose BSDFs are equal (every null, conductors of one named
    # metal) and then fails to load the scene when one of them has flipped normals
    # ("Mesh::merge(): the two meshes are incompatible"): flip only a shape whose BSDF is unique
    bsdfs = Counter(repr(v["bsdf"]) for v in d.values() if isinstance(v, dict) and "bsdf" in v)
    for v in d.values():
        if isinstance(v, dict) and v.get("flip_normals") and bsdfs[repr(v["bsdf"])] > 1:
            del v["flip_normals"]
    if res is None:
        res = int(rng.integers(8, 17))
    eye = _unit(rng) * rng.uniform(3.5, 6.0)
    up = [0, 1, 0] if abs(eye[1]) < 0.9 * np.linalg.norm(eye) else [1, 0, 0]
    d["sensor"] = {"type": "perspective", "fov": float(rng.uniform(35, 60)),
                   "to_world": T().look_at(eye.tolist(), rng.uniform(-0.3, 0.3, 3).tolist(), up),
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}}}
    facts["max_depth"] = int(rng.choice(DEPTHS))
    # hide_emitters behind a surface with a null component (null, mask, thindielectric's
    # straight transmission) is Mitsuba's own open question: path and volpath hide the
    # environment seen through one, direct (and ours) do not; volpath also hides an area light
    # there, path and direct do not.  hide_emitters is only drawn for scenes without them.
    see_through = any(k in b for b in facts["bsdfs"] for k in ("null", "mask", "thindielectric"))
    facts["hide_emitters"] = bool(rng.random() < 0.3) and not see_through
    facts["delta_lights"] = any(k in DELTA_LIGHTS for k in facts["lights"])
    facts["mask"] = any("mask" in b for b in facts["bsdfs"])
    return d, facts


# ---- the integrators -------------------------------------------------------------------------
#: name -> integrator dict (``max_depth`` and ``hide_emitters`` come from the scene)
OURS = {
    "bsdf_path-uniform": {"type": "bsdf_path", "hemisphere": "uniform"},
    "bsdf_path-cosine": {"type": "bsdf_path", "hemisphere": "cosine"},
    "bsdf_path-bsdf": {"type": "bsdf_path", "hemisphere": "bsdf"},
    "direct_mis": {"type": "direct_mis", "light_samples": 2, "bsdf_samples": 1},
    "nee_path": {"type": "nee_path"},
    "nee_path-rrfixed-uniform": {"type": "nee_path", "rr": "fixed", "rr_depth": 2,
                                 "light_selection": "uniform", "heuristic": "balance"},
    "nee_path-adaptive": {"type": "nee_path", "light_selection": "adaptive",
                          "light_samples": 2},
    "mis3-fixed": {"type": "mis3", "selection": "fixed"},
    "mis3-adaptive": {"type": "mis3", "selection": "adaptive"},
}

SPP, BATCHES, BLOCK = 256, 16, 4
MAX_REF_REL_SE = 0.02     # reference too noisy for a t-test above this (rule in the docstring)
MAX_REL_SE = 0.03         # a comparison noisier than this is left out (rule 3)

#: fast set: chosen from the generator's facts and the reference's noise alone (every shape,
#: BSDF and light kind, unlimited depth, hide_emitters; four scenes comparable without delta
#: lights, so bsdf_path is compared too) - see test_fast_set_covers_the_generator
FAST_SEEDS = (6, 21, 24, 28, 48, 59, 79)
SLOW_SEEDS = tuple(range(100, 130))


def integrator_dict(name: str, facts: dict) -> dict:
    d = dict(OURS[name])
    if d["type"] != "direct_mis":
        d["max_depth"] = facts["max_depth"]
    if facts["hide_emitters"]:
        d["hide_emitters"] = True
    return d


def reference_dict(name: str, facts: dict) -> dict:
    d = {"type": "path", "max_depth": 2 if OURS[name]["type"] == "direct_mis"
         else facts["max_depth"]}
    if facts["hide_emitters"]:
        d["hide_emitters"] = True
    return d


def block_rel_se(x: np.ndarray, block: int = BLOCK) -> float:
    """Median over blocks and channels (black ones left out) of the relative standard error of
    a block's mean, from (batches, H, W, C) renders: the noise of one side alone."""
    k, h, w, c = x.shape
    block = max(1, min(block, h, w))
    h2, w2 = h // block, w // block
    b = x[:, :h2 * block, :w2 * block].reshape(k, h2, block, w2, block, c).mean(axis=(2, 4))
    m, se = b.mean(0), np.sqrt(b.var(0, ddof=1) / k)
    lit = m != 0
    return float(np.median(se[lit] / np.abs(m[lit]))) if lit.any() else float("inf")


_scenes: dict = {}
_refs: dict = {}


def scene_of(seed: int):
    if seed not in _scenes:
        d, facts = random_scene(seed)
        _scenes.clear()                 # one scene at a time (tests run seed by seed)
        _refs.clear()
        _scenes[seed] = (mi.load_dict(d), facts)
    return _scenes[seed]


def reference(seed: int, ref: dict) -> np.ndarray:
    key = (seed, tuple(sorted(ref.items())))
    if key not in _refs:
        scene, _ = scene_of(seed)
        _refs[key] = batch_images(scene, mi.load_dict(ref), batches=BATCHES, spp=SPP,
                                  seed0=1_000_003)
    return _refs[key]


def not_comparable(name: str, facts: dict, ref: np.ndarray) -> str | None:
    """Why ``name`` is not compared with the reference on this scene (None: it is)."""
    if OURS[name]["type"] == "bsdf_path" and facts["delta_lights"]:
        return "bsdf_path cannot reach point, spot or directional lights"
    if facts["mask"]:
        return ("Mitsuba's path renders a mask surface `opacity` times too dark "
                "(test_reduced_mask_surface_matches_volpath checks ours on one)")
    if facts["hide_emitters"] and "area" in facts["lights"]:
        return ("hide_emitters with area lights: Mitsuba's path shades a camera path that passed "
                "a hidden light as if no area light were there "
                "(test_reduced_hide_emitters_closed_light)")
    if not np.all(np.isfinite(ref)):
        return "Mitsuba's path gave non-finite pixels"
    rel = block_rel_se(ref)
    if not rel <= MAX_REF_REL_SE:
        return (f"Mitsuba's path too noisy for a t-test: median block relative s.e. "
                f"{100 * rel:.2f} % > {100 * MAX_REF_REL_SE:g} %")
    return None


def describe(facts: dict) -> str:
    return (f"scene seed {facts['seed']} (shapes {facts['shapes']}, bsdfs {facts['bsdfs']}, "
            f"lights {facts['lights']}, max_depth {facts['max_depth']}, hide_emitters "
            f"{facts['hide_emitters']})")


#: (seed, name) of the fast set checked in this run, and how often each integrator was compared
_done: set = set()
_compared: Counter = Counter()


def check_scene(seed: int, name: str):
    scene, facts = scene_of(seed)
    ref = reference(seed, reference_dict(name, facts))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="bsdf_path: BSDF sampling cannot reach")
        ours = batch_images(scene, mi.load_dict(integrator_dict(name, facts)),
                            batches=BATCHES, spp=SPP)
    _done.add((seed, name))
    bad = ~np.isfinite(ours)
    assert not bad.any(), (f"{name}: {int(bad.any(axis=-1).sum())} non-finite pixels in "
                           f"{ours.shape[0]} renders of {describe(facts)}")
    why = not_comparable(name, facts, ref)
    if why is not None:
        pytest.skip(f"finite; not compared with path: {why}")
    # two views of H0, each at the kit's alpha: 4x4 blocks (a local bias) and the whole image
    # as one block (a small bias spread over the image)
    r = image_test(ours, ref, block=BLOCK)
    r_image = image_test(ours, ref, block=max(ours.shape[1:3]))
    if not r.rel_se <= MAX_REL_SE:          # decided on the noise alone, before any p-value
        pytest.skip(f"finite; too noisy to compare: median block relative s.e. of the "
                    f"difference {100 * r.rel_se:.2f} % > {100 * MAX_REL_SE:g} %")
    _compared[name] += 1
    ref_d = reference_dict(name, facts)
    where = (f"{name} {integrator_dict(name, facts)} vs path max_depth {ref_d['max_depth']} on "
             f"{describe(facts)}: image means {ours.mean():.5g} vs {ref.mean():.5g}")
    assert r.passed, f"{where}: H0 {r.h0} rejected (4x4 blocks): {r}"
    assert r_image.passed, f"{where}: H0 {r_image.h0} rejected (whole image): {r_image}"


@pytest.mark.parametrize("name", list(OURS))
@pytest.mark.parametrize("seed", FAST_SEEDS)
def test_fuzz_scene(seed, name):
    check_scene(seed, name)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(OURS))
@pytest.mark.parametrize("seed", SLOW_SEEDS)
def test_fuzz_scene_slow(seed, name):
    check_scene(seed, name)


def test_fast_set_compared_every_integrator():
    """The skip rules must leave every integrator compared on at least two fast scenes (runs
    after the fast set; skipped when only part of it ran)."""
    if not all((s, n) in _done for s in FAST_SEEDS for n in OURS):
        pytest.skip("needs the whole fast set in this run")
    few = {n: _compared[n] for n in OURS if _compared[n] < 2}
    assert not few, f"compared with path on fewer than two fast scenes: {few}"


# ---- reduced cases: fuzz failures minimised by removing scene elements --------------------------
def rough_glass_from_inside():
    """A rough dielectric rectangle seen from its back (inside the glass) under a white sky."""
    return {"type": "scene",
            "env": {"type": "constant", "radiance": 1.0},
            "glass": {"type": "rectangle",
                      "bsdf": {"type": "roughdielectric", "int_ior": 1.5, "distribution": "ggx",
                               "alpha": 0.35}},
            "sensor": {"type": "perspective", "fov": 30,
                       "to_world": T().look_at([0, -1.5, -3], [0, 0, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8,
                                "rfilter": {"type": "box"}}}}


@pytest.mark.parametrize("params", [{}, {"p_cosine": 0.0, "p_glossy": 1.0, "p_light": 0.0}],
                         ids=["default", "glossy-only"])
def test_reduced_mis3_rough_glass_from_inside(params):
    """Reduced from the fuzz (an early seed 39: a rough glass rectangle under a constant sky):
    mis3 read 2 % bright with its defaults and 3.6 % with the glossy lobe alone, while
    bsdf_path, nee_path and direct_mis agreed with path.  roughdielectric's sample() returns
    some directions with weight 0 (the sampled microfacet is invalid for them) that eval() and
    pdf() score through another, valid microfacet; mis3 weighted its lobe samples by eval/pdf
    and so counted those directions twice (fixed in e498dde: a lobe sample the BSDF weights
    zero is invalid).  A regression test now."""
    assert_unbiased(rough_glass_from_inside(), {"type": "path", "max_depth": 2},
                    {"type": "mis3", "max_depth": 2, **params}, spp=1024, batches=16)


def masked_panel():
    """A mask (opacity 0.25) over a diffuse panel, lit by an area light, nothing behind it."""
    return {"type": "scene",
            "panel": {"type": "rectangle", "bsdf": {"type": "mask", "opacity": 0.25,
                                                    "bsdf": {"type": "diffuse",
                                                             "reflectance": 0.5}}},
            "light": {"type": "rectangle", "emitter": {"type": "area", "radiance": 3.0},
                      "to_world": T().look_at([0.5, 1.0, 1.5], [0, 0, 0], [0, 1, 0]).scale(1.0)},
            "sensor": {"type": "perspective", "fov": 40,
                       "to_world": T().look_at([0, -1, 4], [0, 0, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8,
                                "rfilter": {"type": "box"}}}}


@pytest.mark.parametrize("name", ["bsdf_path-bsdf", "direct_mis", "nee_path", "mis3-fixed"])
def test_reduced_mask_surface_matches_volpath(name):
    """Reduced from the fuzz (scene seed 115, direct_mis 46 % above path at max_depth 2): on
    this panel Mitsuba 3.9.1's path reads `opacity` times the value of volpath, direct and all
    of ours (0.0080 against 0.0308; in front of a wall, where the ray that passes through
    finds something, it agrees), so the fuzz does not compare scenes with a mask against path.
    Ours are checked here against volpath (unlimited depth: volpath does not count null
    crossings as bounces, and its shadow rays pass null surfaces, so no point light either)
    and direct_mis against direct."""
    d = dict(OURS[name])
    if name == "direct_mis":
        d["light_samples"] = 1
        ref = {"type": "direct"}
    else:
        d["max_depth"] = -1
        ref = {"type": "volpath", "max_depth": -1}
    assert_unbiased(masked_panel(), ref, d, spp=2048, batches=16, max_rel_se=0.01)


def closed_light_in_front():
    """A cube light between the camera and a ball it lights, a dim sky; hide_emitters."""
    return {"type": "scene",
            "env": {"type": "constant", "radiance": 0.5},
            "ball": {"type": "sphere", "radius": 0.5, "center": [0, 0, -0.6],
                     "bsdf": {"type": "diffuse", "reflectance": 0.8}},
            "light": {"type": "cube", "to_world": T().translate([0, 0, 0.6]).scale(0.4),
                      "emitter": {"type": "area", "radiance": 2.0}},
            "sensor": {"type": "perspective", "fov": 30,
                       "to_world": T().look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8,
                                "rfilter": {"type": "box"}}}}


@pytest.mark.xfail(strict=True, reason="known open discrepancy (issue 12): with hide_emitters, "
                   "Mitsuba's path and direct shade a camera path that passed a hidden area light "
                   "as if no area light were there (the ball behind reads 0.398, the same as with "
                   "the light removed; ours 0.79: lit by it and partly shadowed from the sky)")
@pytest.mark.parametrize("name", ["bsdf_path-bsdf", "direct_mis", "nee_path", "mis3-fixed"])
def test_reduced_hide_emitters_closed_light(name):
    """Reduced from the fuzz (an early seed 177: a phong ball behind a cube light, hide_emitters;
    every one of ours 28 % above path; slow seed 105 the same).  Measured in Mitsuba 3.9.1 (path
    and direct agree): a camera ray whose first hit is an emitting shape goes on past it (the
    red ball behind is seen: rgb 0.398, 0.05, 0.05 = 0.5 x its albedo), but the rest of that
    path gets nothing from any area light and its sky light is not blocked by the hidden shape:
    the ball reads the same as with the cube removed (0.403).  With a second area light beside
    it and no sky the ball reads 0.000 through the cube, 0.066 with the cube removed.  Camera
    rays that do not meet an emitter first are unaffected.  Ours skip every emitting surface
    along the camera ray and then shade normally (the hidden light still lights and shadows),
    so the centre reads 0.79 against 0.39.  Whether to copy Mitsuba here is open; the fuzz
    leaves such scenes out of its comparisons (rule 5)."""
    d = {**OURS[name], "hide_emitters": True}
    if name == "direct_mis":
        ref = {"type": "path", "max_depth": 2, "hide_emitters": True}
    else:
        d["max_depth"] = 3
        ref = {"type": "path", "max_depth": 3, "hide_emitters": True}
    assert_unbiased(closed_light_in_front(), ref, d, spp=1024, batches=16, max_rel_se=0.01)


# ---- the generator itself --------------------------------------------------------------------
def test_generator_is_deterministic_and_valid():
    a, fa = random_scene(3)
    b, fb = random_scene(3)
    assert fa == fb and a.keys() == b.keys()
    for seed in range(100):
        d, facts = random_scene(seed)
        scene = mi.load_dict(d)                    # valid: Mitsuba and our plugins accept it
        assert len(scene.emitters()) >= 1, describe(facts)


def test_fast_set_covers_the_generator():
    kinds = Counter()
    for seed in FAST_SEEDS:
        _, f = random_scene(seed)
        kinds.update(f["shapes"])
        kinds.update(b.split("(")[0] for b in f["bsdfs"])
        kinds.update(f["lights"])
        kinds.update(["depth unlimited" if f["max_depth"] < 0 else "depth bounded",
                      "hide_emitters" if f["hide_emitters"] else "emitters shown"])
    missing = [k for k in SHAPES + BSDFS + LIGHTS + ("depth unlimited", "hide_emitters")
               if not kinds[k]]
    assert not missing, f"the fast set lacks {missing}"
