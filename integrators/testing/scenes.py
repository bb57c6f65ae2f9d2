"""Small scenes with closed-form radiance (dicts for ``mi.load_dict``), each seen by a
``radiancemeter`` (one ray, 1x1 film) at a point whose radiance is known.

Two levels:

* one-call cases returning :class:`ClosedForm` ``(scene, expected)`` for one sensor, ready for
  :func:`integrators.testing.assert_unbiased`: :func:`closed_box`, :func:`closed_sphere`,
  :func:`polygon_light_plane`, :func:`furnace`, and the lossless white furnaces
  :func:`dielectric_furnace` (smooth or thin glass), :func:`mirror_furnace` and
  :func:`back_face_furnace` (a two-sided BSDF seen from its back);
* the building blocks: :func:`closed_box_scene`, :func:`closed_sphere_scene`,
  :func:`furnace_scene` (dicts) and :func:`plane_scene` (dict and one expected value per sensor).

Expected values are for RGB variants: in spectral variants an emitter of constant spectrum 1 is
not sRGB white (compare with Mitsuba's ``path`` in the same variant instead).
"""
from __future__ import annotations

import math
from typing import NamedTuple, Union

import mitsuba as mi
import numpy as np

from .closed_forms import (closed_sphere_radiance, fresnel_dielectric, furnace_radiance,
                           lambert_polygon_irradiance, point_light_irradiance, rectangle_vertices,
                           sphere_interface_radiance, thin_dielectric_reflectance)
from .stats import radiancemeter

#: albedo of the diffuse plane of :func:`plane_scene`
RHO = 0.5
#: the default sensor points on that plane
POINTS = [(0.0, 0.0, 0.0), (0.7, 0.3, 0.0), (1.6, -1.1, 0.0)]
#: where the plane's radiancemeters look from, relative to their target point
VIEW = (0.3, 0.2, 0.25)


class ClosedForm(NamedTuple):
    """A scene dict and the radiance its (first) sensor measures, in closed form."""
    scene: dict
    expected: Union[float, list]


def light_rect(center, half, height_axis_flip=True):
    """``to_world`` of a rectangle light centred at ``center`` with half-sizes ``half`` (x, y),
    facing down (-z)."""
    T = mi.ScalarTransform4f
    return (T().translate(list(center)) @ T().rotate([1, 0, 0], 180) @
            T().scale([half[0], half[1], 1.0]))


#: (to_world, radiance) of two rectangle lights facing down: a small bright one and a big dim
#: one, placed so that neither shadows the other from the plane
RECTS = [(light_rect((0.2, 0.1, 1.0), (0.25, 0.15)), 12.0),
         (light_rect((-1.0, 2.5, 2.0), (1.0, 0.6)), 1.5)]


def plane_radiance(p, rects=RECTS, points=(), rho=RHO) -> float:
    """Radiance leaving the diffuse plane z = 0 (albedo ``rho``) at ``p``: rho / pi times the
    irradiance of the rectangles (Lambert's formula) and point lights.  ``rects`` are
    (to_world, radiance) of downward-facing rectangles that nothing shadows."""
    e = sum(le * lambert_polygon_irradiance(p, (0, 0, 1), rectangle_vertices(tw))
            for tw, le in rects)
    e += sum(point_light_irradiance(p, (0, 0, 1), pos, inten) for pos, inten in points)
    return rho / math.pi * e


def plane_scene(rects=RECTS, points=(), sensors_at=POINTS, spp=4096, bsdf=None, rho=RHO,
                view=VIEW):
    """Diffuse plane z=0 (albedo ``rho``) lit by downward-facing rectangles (``rects``:
    (to_world, radiance), default :data:`RECTS`) and point lights (``points``:
    (position, intensity)); one radiancemeter per point of ``sensors_at``, looking from
    ``point + view``.  Returns (scene dict, expected radiance per sensor).  The expected values
    hold for the diffuse plane only: with another ``bsdf`` they mean nothing."""
    d = {"type": "scene",
         "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(20.0),
                   "bsdf": bsdf or {"type": "diffuse", "reflectance": rho}}}
    for i, (tw, le) in enumerate(rects):
        d[f"rect{i}"] = {"type": "rectangle", "to_world": tw,
                         "emitter": {"type": "area", "radiance": le}}
    for i, (pos, inten) in enumerate(points):
        d[f"point{i}"] = {"type": "point", "position": list(pos), "intensity": inten}
    expected = []
    for j, p in enumerate(sensors_at):
        expected.append(plane_radiance(p, rects, points, rho))
        d[f"sensor{j}"] = radiancemeter(p, np.add(p, view), spp)
    return d, expected


#: where :func:`furnace_scene` looks from, relative to its target (0, 0, 1) on the unit sphere
FURNACE_VIEW = (0.5, 0.3, 2.0)
#: an oblique view (cos 0.36 to the normal: the smooth dielectric of eta 1.5 reflects 16 %)
OBLIQUE_VIEW = (1.5, 0.4, 0.6)


def furnace_scene(bsdf, env=1.0, spp=4096, flip_normals=False, view=FURNACE_VIEW):
    """Unit sphere in a constant environment, one radiancemeter looking at its point (0, 0, 1)
    from ``(0, 0, 1) + view``.  ``flip_normals``: the sphere's normals point inwards, so the
    radiancemeter sees the back side of its BSDF."""
    ball = {"type": "sphere", "bsdf": bsdf}
    if flip_normals:
        ball["flip_normals"] = True
    return {"type": "scene", "env": {"type": "constant", "radiance": env}, "ball": ball,
            "sensor": radiancemeter((0.0, 0.0, 1.0), np.add((0.0, 0.0, 1.0), view), spp)}


def view_cosine(view=FURNACE_VIEW) -> float:
    """Cosine between the normal at (0, 0, 1) and the direction to the radiancemeter of
    :func:`furnace_scene`."""
    v = np.asarray(view, float)
    return float(v[2] / np.linalg.norm(v))


def closed_sphere_scene(rho, le, spp=4096):
    """Camera inside a closed diffuse sphere (normals inward) that emits le everywhere.

    Mitsuba 3.9's sphere emitter is slightly inconsistent for points on the sphere itself, so
    integrators with light sampling (MIS) read about +0.1 % here: test those in
    :func:`closed_box_scene`."""
    return {"type": "scene",
            "shell": {"type": "sphere", "radius": 1.0, "flip_normals": True,
                      "bsdf": {"type": "diffuse", "reflectance": rho},
                      "emitter": {"type": "area", "radiance": le}},
            "sensor": radiancemeter((0.0, 0.0, -1.0), (0.1, 0.2, 0.3), spp)}


def closed_box_scene(rho, le, spp=4096):
    """Camera inside a closed diffuse cube (normals inward) that emits le everywhere.

    Integrators with light sampling are tested here rather than in the sphere: for a point on a
    sphere emitter itself, Mitsuba's sphere ``sample_direction`` pdf and ``pdf_direction``
    disagree, which biases MIS slightly with the power heuristic (Mitsuba's own ``path`` gives
    2.0011 for 2) and a lot with the discontinuous ``maximum`` heuristic (1.54)."""
    return {"type": "scene",
            "box": {"type": "cube", "flip_normals": True,
                    "bsdf": {"type": "diffuse", "reflectance": rho},
                    "emitter": {"type": "area", "radiance": le}},
            "sensor": radiancemeter((0.0, 0.0, -1.0), (0.1, 0.2, 0.3), spp)}


# ---------------------------------------------------------------------------------------------
# one-call cases: (scene dict, expected radiance) for one sensor
def closed_box(rho=0.5, le=1.0, max_depth=-1, spp=4096) -> ClosedForm:
    """Inside a closed emitting diffuse cube: L = le sum_{k < max_depth} rho^k
    (le / (1 - rho) for max_depth = -1).  Every path integrator (all bounces, any light
    sampling) must give it; ``max_depth`` counts like Mitsuba's (2 = direct light: le (1+rho))."""
    return ClosedForm(closed_box_scene(rho, le, spp), closed_sphere_radiance(le, rho, max_depth))


def closed_sphere(rho=0.5, le=1.0, max_depth=-1, spp=4096) -> ClosedForm:
    """The same series inside a closed emitting sphere (for integrators without light
    sampling; see :func:`closed_sphere_scene`)."""
    return ClosedForm(closed_sphere_scene(rho, le, spp), closed_sphere_radiance(le, rho, max_depth))


def polygon_light_plane(at=(0.7, 0.3, 0.0), rects=RECTS, points=(), spp=4096,
                        rho=RHO) -> ClosedForm:
    """A diffuse plane (albedo ``rho``) under rectangle lights (default: :data:`RECTS`)
    and point lights, seen at ``at``: rho / pi times Lambert's polygon irradiance plus
    I cos / d^2 per point light.  Direct light only: give a path tracer ``max_depth`` 2."""
    d, [expected] = plane_scene(rects, points, sensors_at=[tuple(at)], spp=spp, rho=rho)
    return ClosedForm(d, expected)


def furnace(rho=0.6, env=1.0, bsdf=None, spp=4096) -> ClosedForm:
    """A unit sphere in a constant environment ``env``: L = rho env for a BSDF of albedo
    ``rho`` at every angle (default: ``diffuse`` with reflectance ``rho``).  Pass ``bsdf``
    (a dict) only for a BSDF whose directional albedo is exactly ``rho``."""
    bsdf = bsdf or {"type": "diffuse", "reflectance": rho}
    return ClosedForm(furnace_scene(bsdf, env, spp), furnace_radiance(rho, env))


# ---------------------------------------------------------------------------------------------
# white furnaces: lossless or back-facing surfaces in a constant environment
def dielectric_furnace(eta=1.5, max_depth=-1, thin=False, env=1.0, spp=4096,
                       view=OBLIQUE_VIEW) -> ClosedForm:
    """A smooth (``dielectric``) or thin (``thindielectric``) glass sphere of relative index
    ``eta`` in a constant environment ``env``: lossless, so L = env at unlimited depth; truncated
    at ``max_depth``, L = env (r + (1-r)^2 sum_{k < max_depth-2} r^k) with r the reflectance at
    the viewing angle (:func:`~integrators.testing.closed_forms.sphere_interface_radiance`)."""
    cos_i = view_cosine(view)
    if thin:
        bsdf = {"type": "thindielectric", "int_ior": float(eta), "ext_ior": 1.0}
        r = thin_dielectric_reflectance(cos_i, eta)
    else:
        bsdf = {"type": "dielectric", "int_ior": float(eta), "ext_ior": 1.0}
        r = fresnel_dielectric(cos_i, eta)
    return ClosedForm(furnace_scene(bsdf, env, spp, view=view),
                      sphere_interface_radiance(r, max_depth, env))


def mirror_furnace(max_depth=-1, env=1.0, spp=4096, view=OBLIQUE_VIEW) -> ClosedForm:
    """A perfect mirror sphere (``conductor`` with ``material`` none: reflectance 1) in a
    constant environment: L = env from ``max_depth`` 2 on (a convex mirror reflects every ray
    straight to the environment), 0 at ``max_depth`` 1."""
    bsdf = {"type": "conductor", "material": "none"}
    return ClosedForm(furnace_scene(bsdf, env, spp, view=view),
                      env if (max_depth < 0 or max_depth >= 2) else 0.0)


def back_face_furnace(front=0.2, back=0.7, max_depth=-1, env=1.0, spp=4096,
                      view=OBLIQUE_VIEW, twosided=True) -> ClosedForm:
    """A sphere with inward normals (``flip_normals``) in a constant environment, seen from
    outside: the radiancemeter sees the back side of its BSDF, a ``twosided`` pair of diffuse
    BSDFs (albedo ``front`` on the front side, ``back`` on the back side).  The sphere is
    convex, so L = back env from ``max_depth`` 2 on.  ``twosided=False``: a one-sided diffuse
    BSDF of albedo ``front``, black from the back (L = 0)."""
    if twosided:
        bsdf = {"type": "twosided", "front": {"type": "diffuse", "reflectance": front},
                "back": {"type": "diffuse", "reflectance": back}}
        value = back * env
    else:
        bsdf = {"type": "diffuse", "reflectance": front}
        value = 0.0
    return ClosedForm(furnace_scene(bsdf, env, spp, flip_normals=True, view=view),
                      value if (max_depth < 0 or max_depth >= 2) else 0.0)
