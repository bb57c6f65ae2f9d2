r"""Subpaths for bidirectional estimators: random walks from the camera and from the lights,
their vertices stored per depth, and the recursive MIS quantities of every vertex.

A walk draws its random numbers only through ``sampler.next_1d()`` / ``sampler.next_2d()``,
so any sampler with those two methods can drive it (a primary-sample-space Metropolis sampler
included).

**Vertex storage.**  A light subpath's vertices live in flat Dr.Jit arrays, one entry per lane
and depth slot: ``index = lane * cap + k`` (:class:`VertexStore`), written with ``dr.scatter``
inside the walk loop and read with ``dr.gather`` by the connection loops.  Only vertices with a
smooth lobe are stored (a connection through a delta lobe has zero density); ``cap`` bounds the
stored vertices per lane (``max_depth - 2`` for BDPT, enough for every connection the path
length allows).

**MIS by ratio recurrences.**  The balance (or power) weight of strategy (s, t) is
``1 / sum_i (p_i / p_s)^beta`` over every strategy i that builds the same path.  Rather than
re-evaluating the densities of every strategy, each subpath vertex carries two running sums
(Georgiev et al. 2012, "Implementing vertex connection and merging", the recursive form of
Veach's ratio recurrence used by pbrt-v4's ``MISWeight``): for a vertex v reached by a walk,

* ``dvcm`` = (the reverse strategy's density of the previous vertex, relative to the forward
  density of v), the ratio for the strategy that connects one vertex earlier;
* ``dvc`` = the sum of the ratios of every strategy that connects two or more vertices earlier.

At a connection the sum over one side's strategies is
``Mis(p_other_side_A(v)) * (dvcm + dvc * Mis(p_rev_sigma(v -> previous)))``: one density of
the other side (area measure) and one reverse BSDF density at v complete the recurrence.  Every
factor is raised to ``beta`` separately (``Mis``), which gives the power heuristic exactly.

Updates (``Mis`` applied to every factor; cosines use the geometric normal; d the segment
length):

* start of a light walk at y0 (area light chosen with probability p_sel, position pdf p_A,
  cosine direction pdf p_w): ``dvc = cos0 / (p_sel p_A p_w)``; at the first hit y1:
  ``dvcm = p_nee_w(y1 -> y0) cos0 / (p_A p_w)``
  (next-event estimation's density of y0; the selection probability cancels, or, when
  next-event estimation picks lights by another pmf (``nee_sel``: adaptive, bvh), the ratio
  of its pmf at y1 to the light subpath's enters ``dvcm``); a delta light
  (point, spot; direction pdf p_w): ``dvc = 0`` (no strategy hits it), ``dvcm = d^2 / p_w``;
  an environment (direction pdf p_dir, then a point on the disk perpendicular to it that covers
  the scene's bounding sphere, area pdf p_disk = 1/(pi r^2); as pbrt-v4's BDPT and SmallVCM):
  ``dvc = 1 / (p_sel p_dir p_disk)``, ``dvcm = p_nee_w(direction) / (p_dir p_disk)`` at y1, with no
  d^2 and no cosine at the light end (y0 is a direction);
* start of a camera walk: ``dvcm = 1 / p_film_w`` (the film-wide solid-angle density of the
  camera ray, so that light tracing with one light path per camera sample needs no count
  factor), ``dvc = 0`` (no strategy hits the pinhole);
* at every later hit: ``dvcm *= d^2``; then at every hit ``dvcm /= cos_in``, ``dvc /= cos_in``;
* a smooth scattering with forward density p_f and reverse density p_r (solid angle):
  ``dvc = cos_out / p_f * (dvc p_r + dvcm)``, ``dvcm = 1 / p_f``;
* a delta scattering (or a null interface): ``dvcm = 0`` (no strategy can connect there),
  ``dvc *= cos_out`` (forward and reverse delta densities cancel).

Russian roulette changes the throughput only, never the densities the weights use: each
strategy stays unbiased and the weights still sum to one, so the sum is unbiased.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import record_once, safe_div
from .roulette import Roulette


# ---- MIS in "ratio space" --------------------------------------------------------------------
class Mis:
    """``Mis(x) = x`` (balance heuristic) or ``x^beta`` (power heuristic), applied to every
    density ratio; products of ratios stay exact for both."""

    def __init__(self, heuristic: str = "balance", beta: float = 2.0):
        if heuristic not in ("balance", "power"):
            raise ValueError(f"heuristic = {heuristic!r}; allowed: balance, power")
        self.power = heuristic == "power"
        self.beta = float(beta)

    def __call__(self, x):
        x = dr.maximum(mi.Float(x), 0.0)
        if not self.power or self.beta == 1.0:
            return x
        if self.beta == 2.0:
            return x * x
        return dr.select(x > 0, dr.power(x, self.beta), 0.0)


def finite_weight(denominator):
    """1 / denominator where it is finite and >= 1, else 0 (a ratio overflow means another
    strategy is infinitely better: this one's weight is 0)."""
    ok = dr.isfinite(denominator) & (denominator >= 1.0)
    return dr.select(ok, dr.rcp(dr.select(ok, denominator, 1.0)), 0.0)


def spectrum_channels() -> int:
    return dr.size_v(mi.Spectrum)


def is_delta_sample(bs):
    return mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)


def with_wi(si, wi):
    """A copy of ``si`` whose incident direction (local) is ``wi``: for reverse densities."""
    si2 = mi.SurfaceInteraction3f(si)
    si2.wi = wi
    return si2


def reverse_pdf(bsdf, ctx, si, wo_local, active, lambert=None):
    """Density of sampling the direction back along ``si.wi`` when arriving from ``wo_local``.
    Callers mask it with ``dvc > 0``: it only ever multiplies ``dvc`` (zero at a camera
    subpath's first vertex and after a delta light), so those lanes skip the BSDF call.  With a
    :class:`LambertTable`, Mitsuba's ``diffuse`` BSDFs take their density in closed form
    (cos(wi) / pi on the upper hemisphere, whatever the other direction) without a BSDF call."""
    if lambert is None:
        return bsdf.pdf(ctx, with_wi(si, wo_local), si.wi, active)
    lam = lambert.is_lambert(bsdf, active)
    cos_i = mi.Frame3f.cos_theta(si.wi)
    closed = dr.select((mi.Frame3f.cos_theta(wo_local) > 0) & (cos_i > 0), cos_i * dr.inv_pi, 0.0)
    called = bsdf.pdf(ctx, with_wi(si, wo_local), si.wi, active & ~lam)
    return dr.select(active, dr.select(lam, closed, called), 0.0)


class LambertTable:
    """BSDF registry id -> whether it is Mitsuba's ``diffuse`` (``SmoothDiffuse``), whose
    sampling density cos(wo) / pi does not depend on the incident direction."""

    def __init__(self, scene):
        import numpy as np
        rows = []
        for shape in scene.shapes():
            b = shape.bsdf()
            if b is not None:
                i = int(np.array(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(b))).ravel()[0])
                rows.append((i, str(b).split("[", 1)[0] == "SmoothDiffuse"))
        table = np.zeros(max([i for i, _ in rows], default=0) + 1, np.float32)
        for i, lam in rows:
            table[i] = 1.0 if lam else 0.0
        self.table = mi.Float(table)
        self.size = len(table)

    def is_lambert(self, bsdf, active):
        i = dr.reinterpret_array(mi.UInt32, bsdf)
        return dr.gather(mi.Float, self.table, i, active & (i < self.size)) > 0.5


def shading_correction(si, wo_world):
    """Veach's adjoint correction for shading normals on light subpaths (as Mitsuba's
    ``ptracer``): |cos_s(wi) <n_g, wo>| / |cos_s(wo) <n_g, wi>|; 0 where a side disagrees."""
    wi_world = si.to_world(si.wi)
    wo_local = si.to_local(wo_world)
    wi_g, wo_g = dr.dot(si.n, wi_world), dr.dot(si.n, wo_world)
    ok = (wi_g * mi.Frame3f.cos_theta(si.wi) > 0) & (wo_g * mi.Frame3f.cos_theta(wo_local) > 0)
    num = dr.abs(mi.Frame3f.cos_theta(si.wi) * wo_g)
    den = dr.abs(mi.Frame3f.cos_theta(wo_local) * wi_g)
    return dr.select(ok & (den > 0), num / dr.select(den > 0, den, 1.0), 0.0)


# ---- vertex storage ----------------------------------------------------------------------------
class VertexStore:
    """Light-subpath vertices in flat arrays, ``index = lane * cap + k``.

    Per vertex: position, geometric normal, shading frame, uv, incident direction (local), the
    BSDF (as its registry id), the throughput ``beta``, ``dvcm``, ``dvc`` and the vertex depth
    (segments from the light).  ``count`` holds the number of stored vertices per lane."""

    VEC3 = ("p", "n", "s", "t", "sn", "wi")

    def __init__(self, lanes: int, cap: int):
        self.lanes, self.cap = int(lanes), int(cap)
        size = max(self.lanes * self.cap, 1)
        self.nc = spectrum_channels()
        self.f = {}
        for name in self.VEC3:
            for c in range(3):
                self.f[f"{name}{c}"] = dr.zeros(mi.Float, size)
        self.f["u"] = dr.zeros(mi.Float, size)
        self.f["v"] = dr.zeros(mi.Float, size)
        for c in range(self.nc):
            self.f[f"beta{c}"] = dr.zeros(mi.Float, size)
        self.f["dvcm"] = dr.zeros(mi.Float, size)
        self.f["dvc"] = dr.zeros(mi.Float, size)
        self.bsdf = dr.zeros(mi.UInt32, size)
        self.depth = dr.zeros(mi.UInt32, size)
        self.count = dr.zeros(mi.UInt32, max(self.lanes, 1))

    def put(self, index, si, bsdf, beta, dvcm, dvc, depth, active):
        vals = {}
        for name, vec in (("p", si.p), ("n", si.n), ("s", si.sh_frame.s), ("t", si.sh_frame.t),
                          ("sn", si.sh_frame.n), ("wi", si.wi)):
            for c in range(3):
                vals[f"{name}{c}"] = vec[c]
        vals["u"], vals["v"] = si.uv[0], si.uv[1]
        b = mi.unpolarized_spectrum(beta)
        for c in range(self.nc):
            vals[f"beta{c}"] = b[c]
        vals["dvcm"], vals["dvc"] = dvcm, dvc
        for k, v in vals.items():
            dr.scatter(self.f[k], v, index, active)
        dr.scatter(self.bsdf, dr.reinterpret_array(mi.UInt32, bsdf), index, active)
        dr.scatter(self.depth, mi.UInt32(depth), index, active)

    def evaluate(self):
        dr.eval(self.f, self.bsdf, self.depth, self.count)

    def get(self, index, active):
        """(si, bsdf, beta, dvcm, dvc, depth) of the stored vertices at ``index``."""
        g = {k: dr.gather(mi.Float, v, index, active) for k, v in self.f.items()}
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p = mi.Point3f(g["p0"], g["p1"], g["p2"])
        si.n = mi.Normal3f(g["n0"], g["n1"], g["n2"])
        si.sh_frame = mi.Frame3f(mi.Vector3f(g["s0"], g["s1"], g["s2"]),
                                 mi.Vector3f(g["t0"], g["t1"], g["t2"]),
                                 mi.Vector3f(g["sn0"], g["sn1"], g["sn2"]))
        si.wi = mi.Vector3f(g["wi0"], g["wi1"], g["wi2"])
        si.uv = mi.Point2f(g["u"], g["v"])
        si.t = mi.Float(1.0)              # a valid interaction
        beta = mi.Spectrum([g[f"beta{c}"] for c in range(self.nc)]) if self.nc > 1 \
            else mi.Spectrum(g["beta0"])
        bsdf = dr.reinterpret_array(mi.BSDFPtr, dr.gather(mi.UInt32, self.bsdf, index, active))
        depth = dr.gather(mi.UInt32, self.depth, index, active)
        return si, bsdf, beta, g["dvcm"], g["dvc"], depth


# ---- emitter tables ------------------------------------------------------------------------------
class EmitterTables:
    """Per-emitter constants the light walk and the weights need, gathered by emitter id:
    ``is_area`` (1 for an area light), ``is_inf`` (1 for an environment: ``constant``,
    ``envmap``), ``pos_pdf`` (1/area: the area light's position density, uniform on its shape;
    for an environment the area density 1/(pi r^2) of the point on the disk, perpendicular to
    the emitted direction, that covers the scene's bounding sphere), ``dir_pdf`` (a delta
    light's constant direction density: 1/(4 pi) for a point light, 1/(2 pi (1 - cos cutoff))
    for a spot, measured from Mitsuba's own ``sample_ray``)."""

    def __init__(self, scene):
        import numpy as np
        emitters = scene.emitters()
        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.emitters_dr()), dtype=np.int64)
        n = int(ids.max()) + 1 if len(ids) else 1
        is_area = np.zeros(n, np.float32)
        is_inf = np.zeros(n, np.float32)
        pos_pdf = np.zeros(n, np.float32)
        dir_pdf = np.zeros(n, np.float32)
        for e, i in zip(emitters, ids):
            shape = e.get_shape()
            if shape is not None:
                is_area[i] = 1.0
                pos_pdf[i] = 1.0 / max(float(shape.surface_area()[0]), 1e-30)
            elif mi.has_flag(e.flags(), mi.EmitterFlags.Infinite):
                is_inf[i] = 1.0
                pos_pdf[i] = environment_disk_pdf(e, scene)
            else:
                dir_pdf[i] = delta_direction_pdf(e)
        self.is_area = mi.Float(is_area)
        self.is_inf = mi.Float(is_inf)
        self.pos_pdf = mi.Float(pos_pdf)
        self.dir_pdf = mi.Float(dir_pdf)

    def lookup(self, emitter, active):
        i = dr.reinterpret_array(mi.UInt32, emitter)
        return (dr.gather(mi.Float, self.is_area, i, active) > 0.5,
                dr.gather(mi.Float, self.pos_pdf, i, active),
                dr.gather(mi.Float, self.dir_pdf, i, active))

    def infinite(self, emitter, active):
        """Whether ``emitter`` is an environment (``constant``, ``envmap``)."""
        i = dr.reinterpret_array(mi.UInt32, emitter)
        return dr.gather(mi.Float, self.is_inf, i, active) > 0.5


def environment_direction_pdf(emitter, d_env, active):
    """Solid-angle density of the environment direction ``d_env`` (pointing from the scene
    towards the environment) under the emitter's own direction sampling (``sample_ray`` and
    ``sample_direction`` share it), without the selection probability."""
    it = dr.zeros(mi.Interaction3f)
    ds = dr.zeros(mi.DirectionSample3f)
    ds.d = d_env
    ds.emitter = emitter
    return emitter.pdf_direction(it, ds, active)


def environment_disk_pdf(emitter, scene) -> float:
    """Area density 1/(pi r^2) of the emitted ray's origin on the disk of ``sample_ray``
    (r: the radius of the emitter's own bounding sphere), measured from Mitsuba's weights:
    weight = L / (p_dir p_disk), so p_disk = L / (p_dir weight)."""
    import numpy as np
    n = 64
    u = mi.Point2f(dr.linspace(mi.Float, 0.05, 0.95, n), dr.linspace(mi.Float, 0.9, 0.1, n))
    ray, w = emitter.sample_ray(0.0, 0.5, mi.Point2f(0.5, 0.5), u, True)
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = ray.d                       # the environment is seen along -ray.d
    si.p = ray.o
    le = emitter.eval(si, True)
    p_dir = environment_direction_pdf(emitter, -ray.d, True)
    a = np.array(mi.unpolarized_spectrum(le)[0], dtype=np.float64).ravel()
    b = np.array(mi.unpolarized_spectrum(w)[0], dtype=np.float64).ravel()
    p = np.array(p_dir, dtype=np.float64).ravel()
    a, b, p = np.broadcast_arrays(a, b, p)
    ok = (a > 0) & (b > 0) & (p > 0) & np.isfinite(a) & np.isfinite(b)
    if ok.any():
        return float(np.median(a[ok] / (p[ok] * b[ok])))
    r = float(scene.bbox().bounding_sphere().radius)      # a black environment
    return 1.0 / (np.pi * max(r * r, 1e-30))


def delta_direction_pdf(emitter) -> float:
    """Direction density of a delta light's ``sample_ray`` (uniform over its sphere or cone):
    the intensity it emits along a sampled direction over the ray weight (intensity / pdf)."""
    import numpy as np
    n = 64
    u = mi.Point2f(dr.linspace(mi.Float, 0.05, 0.95, n), dr.linspace(mi.Float, 0.9, 0.1, n))
    ray, w = emitter.sample_ray(0.0, 0.5, mi.Point2f(0.5, 0.5), u, True)
    it = dr.zeros(mi.Interaction3f)
    it.p = ray.o + ray.d
    _, w_dir = emitter.sample_direction(it, mi.Point2f(0.5, 0.5), True)
    a = np.array(mi.unpolarized_spectrum(w_dir)[0], dtype=np.float64).ravel()   # I / 1^2
    b = np.array(mi.unpolarized_spectrum(w)[0], dtype=np.float64).ravel()       # I / p
    a, b = np.broadcast_arrays(a, b)
    ok = (a > 0) & (b > 0) & np.isfinite(a) & np.isfinite(b)
    return float(np.median(a[ok] / b[ok])) if ok.any() else 1.0 / (4.0 * np.pi)


# ---- the light walk ------------------------------------------------------------------------------
class LightWalk:
    """A light subpath: the start on a light, then BSDF sampling in importance mode with
    Russian roulette.  At every smooth vertex y_i (i >= 1) it stores the vertex (when a slot is
    free and i <= ``store_depth``) and calls ``on_vertex(si, bsdf, beta, dvcm, dvc, i, active,
    sampler)``
    (light tracing to the camera).  ``nee_sel``: next-event estimation's light selection where
    it differs from ``sel`` (the light subpath's; a pmf per shading point: adaptive, bvh), whose
    pmf at y1 enters y1's ``dvcm``.  Random numbers: 1 + 2 + 2 at the start, then per vertex
    whatever ``on_vertex`` draws, 1 + 2 for the BSDF sample, 1 for roulette when it is on."""

    def __init__(self, mis: Mis, roulette: Roulette, max_vertices: int, store_depth: int,
                 lambert: LambertTable | None = None):
        self.mis, self.rr, self.lambert = mis, roulette, lambert
        self.max_vertices = int(max_vertices)   # deepest y_i used (segments from the light)
        self.store_depth = int(store_depth)     # deepest y_i stored for connections

    def start(self, scene, sel, tables, sampler, active):
        """Sample y0 and the first direction: (emitter, ray, beta, dvc, pdf_e, area, inf, y0,
        n0, cos0, p_dir, active) with ``pdf_e`` the emission density without the selection
        probability (area light: p_A p_w; delta light: p_w; environment: p_dir p_disk) and
        ``p_dir`` an environment's direction density (next-event estimation's density of y0
        seen from y1: a direction, so no distance or cosine at the light end)."""
        u_sel = sampler.next_1d(active)
        u_pos = sampler.next_2d(active)
        u_dir = sampler.next_2d(active)
        emitter, pick = sel.sample(u_sel, active)
        active = active & (pick > 0)
        is_area, pos_pdf, dir_pdf = tables.lookup(emitter, active)
        area = active & is_area
        inf = active & ~is_area & tables.infinite(emitter, active)
        other = active & ~is_area
        # area light: uniform position on the shape, cosine-weighted direction
        ps, _ = emitter.sample_position(0.0, u_pos, area)
        local = mi.warp.square_to_cosine_hemisphere(u_dir)
        si0 = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
        si0.wi = local
        le = emitter.eval(si0, area)
        pdf_area = ps.pdf * local.z * dr.inv_pi
        ray_area = si0.spawn_ray(si0.to_world(local))
        beta_area = le * safe_div(dr.pi, ps.pdf)
        # delta light (point, spot) and environment (a direction, then a point on the disk
        # covering the bounding sphere): Mitsuba's own emitted-ray sampler
        ray_d, w_d = emitter.sample_ray(0.0, 0.5, u_pos, u_dir, other)
        p_dir = environment_direction_pdf(emitter, -ray_d.d, inf)
        ray = dr.select(area, ray_area, ray_d)
        beta = dr.select(area, beta_area, w_d) * safe_div(1.0, pick)
        pdf_e = dr.select(area, pdf_area, dr.select(inf, p_dir * pos_pdf, dir_pdf))
        cos0 = dr.select(area, local.z, 1.0)
        # the selection probability is part of the emission density (as the camera side's
        # ratios of hitting this light include it); it cancels in dvcm at y1
        dvc = dr.select(area | inf, self.mis(safe_div(cos0, pick * pdf_e)), 0.0)
        beta = dr.select(active, beta, 0.0)
        return emitter, ray, beta, dvc, pdf_e, area, inf, ps.p, ps.n, cos0, p_dir, active

    @record_once
    @dr.syntax
    def walk(self, scene, sel, tables, sampler, store: VertexStore, lane, active,
             on_vertex=None, nee_sel=None):
        mis = self.mis
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        emitter, ray, beta, dvc, pdf_e, area, inf, y0, n0, cos0, p_dir, active = \
            self.start(scene, sel, tables, sampler, mi.Bool(active))
        dvcm = mi.Float(0.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(1)
        count = mi.UInt32(0)
        active = active & (depth <= self.max_vertices) & dr.any(beta != 0)
        while dr.hint(active, label="bdpt light walk"):
            si = scene.ray_intersect(ray, active)
            active &= si.is_valid()
            cos_in = dr.abs(dr.dot(si.n, ray.d))
            dist2 = dr.square(si.t)
            # the first hit: next-event estimation's density of y0 over the emission density
            first = depth == 1
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p, ds.n = y0, n0
            ds.d = dr.normalize(y0 - si.p)
            ds.dist = si.t
            ds.emitter = emitter
            it = dr.zeros(mi.Interaction3f)
            it.p, it.n = si.p, si.n
            p_nee = emitter.pdf_direction(it, ds, active & first & area)
            dvcm_first = dr.select(area, mis(safe_div(p_nee * cos0, pdf_e)),
                                   dr.select(inf, mis(safe_div(p_dir, pdf_e)),
                                             mis(safe_div(dist2, pdf_e))))
            if dr.hint(nee_sel is not None, mode="scalar"):
                # next-event estimation picks the light by its own pmf at y1
                dvcm_first *= mis(safe_div(nee_sel.pmf_at(si, emitter, active & first),
                                           sel.pmf(emitter, active & first)))
            dvcm = dr.select(first, dvcm_first, dvcm * mis(dist2))
            inv_cos = mis(safe_div(1.0, cos_in))
            dvcm *= inv_cos
            dvc *= inv_cos

            bsdf = si.bsdf(ray)
            smooth = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            do_store = smooth & (depth <= self.store_depth) & (count < store.cap)
            store.put(lane * store.cap + count, si, bsdf, beta, dvcm, dvc, depth, do_store)
            count = dr.select(do_store, count + 1, count)
            if dr.hint(on_vertex is not None, mode="scalar"):
                on_vertex(si, bsdf, beta, dvcm, dvc, depth, smooth, sampler)

            # continue: BSDF sample in importance mode
            bs, w = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
            wo = si.to_world(bs.wo)
            spec = is_delta_sample(bs)
            p_rev = reverse_pdf(bsdf, ctx, si, bs.wo, active & ~spec & (dvc > 0), self.lambert)
            cos_out = dr.abs(dr.dot(si.n, wo))
            dvc = dr.select(spec, dvc * mis(cos_out),
                            mis(safe_div(cos_out, bs.pdf)) * (dvc * mis(p_rev) + dvcm))
            dvcm = dr.select(spec, 0.0, mis(safe_div(1.0, bs.pdf)))
            beta *= w * shading_correction(si, wo)
            eta *= bs.eta
            active &= (bs.pdf > 0) | spec
            beta, active = self.rr(beta, eta, depth, sampler.next_1d(active), active)
            ray = si.spawn_ray(wo)
            depth += 1
            active &= depth <= self.max_vertices
        dr.scatter(store.count, count, lane)
        return count
