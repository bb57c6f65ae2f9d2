"""Small test scenes with closed-form radiance (dicts for mi.load_dict)."""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from integrators import testing

RHO = 0.5
POINTS = [(0.0, 0.0, 0.0), (0.7, 0.3, 0.0), (1.6, -1.1, 0.0)]


def light_rect(center, half, height_axis_flip=True):
    T = mi.ScalarTransform4f
    return (T().translate(list(center)) @ T().rotate([1, 0, 0], 180) @
            T().scale([half[0], half[1], 1.0]))


RECTS = [  # (to_world, radiance): a small bright light and a big dim one, facing down
    (light_rect((0.2, 0.1, 1.0), (0.25, 0.15)), 12.0),
    (light_rect((-1.0, 2.5, 2.0), (1.0, 0.6)), 1.5),  # placed so neither light shadows the other
]


def plane_scene(rects=RECTS, points=(), sensors_at=POINTS, spp=4096, bsdf=None):
    """Diffuse plane z=0 (albedo RHO) lit by downward-facing rectangles and point lights;
    one radiancemeter per point of ``sensors_at``.  Returns (scene dict, expected radiances)."""
    d = {"type": "scene",
         "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(20.0),
                   "bsdf": bsdf or {"type": "diffuse", "reflectance": RHO}}}
    for i, (tw, le) in enumerate(rects):
        d[f"rect{i}"] = {"type": "rectangle", "to_world": tw,
                         "emitter": {"type": "area", "radiance": le}}
    for i, (pos, inten) in enumerate(points):
        d[f"point{i}"] = {"type": "point", "position": list(pos), "intensity": inten}
    expected = []
    for j, p in enumerate(sensors_at):
        e = sum(le * testing.lambert_polygon_irradiance(p, (0, 0, 1),
                                                        testing.rectangle_vertices(tw))
                for tw, le in rects)
        e += sum(testing.point_light_irradiance(p, (0, 0, 1), pos, inten) for pos, inten in points)
        expected.append(RHO / math.pi * e)
        d[f"sensor{j}"] = testing.radiancemeter(p, np.add(p, (0.3, 0.2, 0.25)), spp)
    return d, expected


def furnace_scene(bsdf, env=1.0, spp=4096):
    """Unit sphere in a constant environment, one radiancemeter looking at it."""
    return {"type": "scene", "env": {"type": "constant", "radiance": env},
            "ball": {"type": "sphere", "bsdf": bsdf},
            "sensor": testing.radiancemeter((0.0, 0.0, 1.0), (0.5, 0.3, 3.0), spp)}


def closed_sphere_scene(rho, le, spp=4096):
    """Camera inside a closed diffuse sphere (normals inward) that emits le everywhere."""
    return {"type": "scene",
            "shell": {"type": "sphere", "radius": 1.0, "flip_normals": True,
                      "bsdf": {"type": "diffuse", "reflectance": rho},
                      "emitter": {"type": "area", "radiance": le}},
            "sensor": testing.radiancemeter((0.0, 0.0, -1.0), (0.1, 0.2, 0.3), spp)}


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
            "sensor": testing.radiancemeter((0.0, 0.0, -1.0), (0.1, 0.2, 0.3), spp)}
