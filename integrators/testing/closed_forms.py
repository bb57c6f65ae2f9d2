"""Closed-form radiance and irradiance for the test scenes (plain numpy, no rendering).

* :func:`lambert_polygon_irradiance` - Lambert's formula for a uniformly emitting polygon;
* :func:`rectangle_vertices` - the corners of Mitsuba's ``rectangle`` shape under a transform;
* :func:`point_light_irradiance` - inverse-square law with the cosine;
* :func:`closed_sphere_radiance` / :func:`closed_box_radiance` - the geometric series inside a
  closed diffuse enclosure that emits everywhere (truncated at ``max_depth``);
* :func:`furnace_radiance` - a convex object of albedo rho in a constant environment;
* :func:`fresnel_dielectric`, :func:`thin_dielectric_reflectance` and
  :func:`sphere_interface_radiance` - a lossless (smooth or thin dielectric) sphere in a constant
  environment, truncated at ``max_depth``.
"""
from __future__ import annotations

import math

import numpy as np


def lambert_polygon_irradiance(p, n, vertices) -> float:
    """Irradiance at ``p`` (normal ``n``) from a polygon of unit radiance (Lambert 1760).

    E = 1/2 sum_i Theta_i (n . g_i), Theta_i the angle the i-th edge subtends at p and g_i the
    unit normal of the plane through p and that edge.  The polygon must lie entirely above the
    tangent plane of p (no clipping is done) and face p."""
    p, n = np.asarray(p, float), np.asarray(n, float)
    r = [np.asarray(v, float) - p for v in vertices]
    r = [v / np.linalg.norm(v) for v in r]
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        theta = math.acos(float(np.clip(np.dot(a, b), -1, 1)))
        g = np.cross(a, b)
        g /= np.linalg.norm(g)
        total += theta * float(np.dot(n, g))
    return abs(0.5 * total)


def rectangle_vertices(to_world) -> list:
    """World-space corners of Mitsuba's ``rectangle`` shape ([-1,1]^2 at z=0) under to_world
    (a ``mi.ScalarTransform4f``)."""
    import mitsuba as mi
    corners = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    return [np.array(to_world @ mi.ScalarPoint3f(*c), dtype=float) for c in corners]


def point_light_irradiance(p, n, light_pos, intensity: float) -> float:
    """Irradiance at ``p`` (normal ``n``) from an isotropic point light: I cos / d^2."""
    d = np.asarray(light_pos, float) - np.asarray(p, float)
    dist2 = float(np.dot(d, d))
    cos = float(np.dot(np.asarray(n, float), d)) / math.sqrt(dist2)
    return intensity * max(cos, 0.0) / dist2


def closed_sphere_radiance(le: float, rho: float, max_depth: int = -1) -> float:
    """Radiance inside a closed diffuse enclosure (albedo rho) emitting le everywhere.

    Every bounce sees the same emission: L = le sum_{k < max_depth} rho^k (-1: le / (1-rho)).
    ``max_depth`` counts like Mitsuba's: 1 = only the directly visible emitter."""
    if max_depth < 0:
        return le / (1.0 - rho)
    return le * sum(rho ** k for k in range(max_depth))


#: the same series holds in any closed enclosure (the cube of :func:`scenes.closed_box_scene`)
closed_box_radiance = closed_sphere_radiance


def furnace_radiance(rho: float, env: float = 1.0) -> float:
    """A convex object of (energy-conserving, white-furnace) albedo rho in a constant
    environment ``env``: L = rho env (plus nothing from inter-reflection: it is convex)."""
    return rho * env


def fresnel_dielectric(cos_i: float, eta: float) -> float:
    """Unpolarised Fresnel reflectance of a smooth dielectric interface for light arriving at
    ``cos_i`` > 0 from the side of index n_i, ``eta`` = n_t / n_i (1 under total internal
    reflection)."""
    sin_t2 = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin_t2 >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin_t2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def thin_dielectric_reflectance(cos_i: float, eta: float) -> float:
    """Reflectance of a thin dielectric sheet (both faces and every inter-reflection between
    them): R = 2 F / (1 + F), F the Fresnel reflectance of one face; it transmits 1 - R."""
    f = fresnel_dielectric(cos_i, eta)
    return 2.0 * f / (1.0 + f)


def sphere_interface_radiance(r: float, max_depth: int = -1, env: float = 1.0) -> float:
    """Radiance seen on a lossless sphere in a constant environment ``env`` whose surface
    reflects a fraction ``r`` and transmits 1 - r at every hit (a smooth or thin dielectric
    sphere, radiance in units of the outside medium).

    Inside a sphere every chord meets the surface at the same angle at both ends, so every hit
    of a path sees the same r: the path escapes at its first hit by reflection (r), or enters
    and escapes after k internal reflections ((1 - r)^2 r^k, k + 3 path vertices counting the
    environment).  Truncated at ``max_depth`` (Mitsuba's counting; -1: the whole series, which
    sums to ``env``: nothing is lost)."""
    if max_depth < 0:
        return env
    if max_depth < 2:
        return 0.0
    return env * (r + (1.0 - r) ** 2 * sum(r ** k for k in range(max_depth - 2)))
