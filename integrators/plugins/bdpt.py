r"""Integrator ``bdpt``: bidirectional path tracing (Veach 1997, ch. 10).

Every camera sample traces a **light subpath** y_0 y_1 ... (a light chosen by
``light_selection``, a point on it, a direction, then BSDF sampling in importance mode) and a
**camera subpath** z_0 z_1 ... (the camera ray, then BSDF sampling), both with Russian roulette,
and combines every strategy (s, t) (s light vertices, t camera vertices) that builds a path of at
most ``max_depth`` segments (s + t - 1; longer than ``bidir_depth``: s = 0 and 1 only, below):

* s = 0: the camera subpath hits an area light or escapes to the environment;
* s = 1: next-event estimation at camera vertex z_{t-1} (a fresh light sample, as pbrt-v4);
* t = 1: light tracing: each smooth light vertex y_i (i >= 1) is connected to the pinhole and its
  contribution splatted onto the film at the pixel it projects to (an image block with atomic
  adds; 1/spp and the sensor's importance as Mitsuba's ``ptracer``); each pixel's splat sum is
  divided by the integral of its reconstruction filter over the film, so that it estimates the
  same filtered pixel value as the camera samples' weighted mean (any filter, edges included);
* s, t >= 2: a shadow ray between y_{s-1} and z_{t-1} (both with a smooth lobe).

The strategy s = 1, t = 1 (a point on a light projected onto the film) is not used: emitters seen
directly come from s = 0 alone, with weight 1 (as in SmallVCM).

**MIS**: ``heuristic`` = ``balance`` | ``power`` (exponent ``beta``) over all strategies of a path,
computed with the ratio recurrences of :mod:`integrators.sampling.subpath` (two running sums
per vertex, updated as the walks go; no strategy's full density is re-evaluated).  Strategies
that cannot produce a path get weight zero: a delta lobe (mirror, glass, null interface) cannot
be an end of a connection, a delta light (point, spot) cannot be hit, the pinhole cannot be hit.
The light-tracing strategies take the camera's film-wide directional density, so with one light
subpath per camera sample no count factor enters the weights.

**Depth** (``max_depth``, Mitsuba's meaning: -1 unlimited, the default; 1 emitters seen directly;
0 nothing): light vertices are stored per lane and depth in flat Dr.Jit arrays
(``lane * cap + k``), so the light subpath is finite: paths of at most D = ``bidir_depth``
segments (default 16; ``max_depth`` where that is shorter) are built by every strategy, and
longer ones, up to ``max_depth`` (Russian roulette ends them), by the camera subpath's s = 0
and s = 1 alone.  The weights of a path of k > D segments are those of path tracing with
next-event estimation (the heuristic over s = 0 and s = 1: the camera-side sums' terms of
s >= 2 are dropped), so for every path length the weights of the strategies that can build it
sum to one and the image is unbiased for any ``max_depth``; ``bidir_depth`` trades the cost of
long light subpaths and their connections for bidirectional weights on long paths.  Storage is
about (27 + channels) x 4 bytes per stored vertex (``cap = D - 2``); renders with more samples
than fit in ``MEMORY_BUDGET`` are done in chunks of whole samples per pixel (each with its own
seed) inside one ``render`` call.

**Environment lights** (``constant``, ``envmap``; as pbrt-v4's BDPT and SmallVCM): a light
subpath from the environment samples a direction with the emitter's own density p_dir, then a
point on the disk perpendicular to it that covers the scene's bounding sphere (area density
p_disk = 1/(pi r^2)), both by Mitsuba's ``sample_ray``; its emission density p_dir p_disk takes
the place of an area light's position and direction densities, with no 1/d^2 and no cosine at
the light end (y0 is a direction).  A camera subpath that escapes the scene is the strategy
s = 0 on the environment; next-event estimation samples it as any light.

**Scope**: area lights (uniform position on the shape; textured emitters refused), point and
spot lights, ``constant`` and ``envmap`` environments; ``directional`` (a delta direction) and
other emitters (``projector``) are refused in one line.  Sensors: ``perspective`` (pinhole:
every strategy) and ``radiancemeter`` (its delta direction cannot be connected to: no light
tracing, its weight is zero).  JIT variants only (``llvm_*``/``cuda_*``, RGB or mono); scalar
and spectral variants are refused in one line.  No media.

**hide_emitters** (as the other integrators): area emitters are transparent to camera rays and
the environment seen directly is black; light tracing (t = 1) sees through area emitters too
and never splats a light vertex that lies on one, so every strategy produces the same paths.

**light_selection**: ``uniform`` and ``power`` choose the light of a light subpath and of a light
sample by the same pmf.  ``adaptive``, ``bvh`` and ``ris`` depend on the shading point, which the light
subpath's start has not: they choose the light of next-event estimation (s = 1) only, and the
light subpath starts by the ``power`` pmf; the weights take each strategy's own pmf (the ratio
of the two enters next-event estimation's weight and the first light vertex's ``dvcm``).

**Strategy images** (``strategy_images=true``): AOV layers ``s<s>_t<t>`` (R, G, B) hold each
strategy's weighted contribution (Veach's strategy figure: which strategy carries a scene); they
sum to the image.  ``heuristic=none`` weights every strategy 1, so that each layer estimates all
paths of its length (the check of the strategies and of the weights in the tests); they need
``max_depth`` within 0 .. ``bidir_depth`` (every path built by every strategy).

**Chunks and seeds**: a chunk k > 0 of a render with seed ``seed`` uses the sampler seed
``seed + k * 0x9E3779B9`` (mod 2^32); only renders of more samples than ``MEMORY_BUDGET``
holds have such chunks.

``render()`` does the work (``mi.render``, the ``render`` command, its passes, merge and Ctrl-C
call it as for the other integrators); ``sample()`` is not used (it raises): a per-camera-sample
estimate cannot hold the light-tracing splats.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..common import (depth_limit, direction_sample, emitted, emitter_at, is_jit,
                      record_once, safe_div, widen)
from ..params import Param, ParameterError
from ..registry import plugin
from ..sampling import light_selection, roulette
from ..sampling.subpath import (EmitterTables, LambertTable, LightWalk, Mis, VertexStore,
                                environment_direction_pdf, finite_weight,
                                is_delta_sample, reverse_pdf, shading_correction,
                                spectrum_channels)
from .base import (HIDE_EMITTERS, MAX_DEPTH, IntegratorTemplate, SceneError, _on_emitter,
                   skip_emitters)

#: the most segments a path built by every strategy can have (``bidir_depth``)
MAX_BDPT_DEPTH = 64
#: its default: paths of at most 16 segments take every strategy
BIDIR_DEPTH = 16
#: bytes of stored light vertices per chunk of samples (chunks hold whole samples per pixel)
MEMORY_BUDGET = 256 << 20


@plugin("bdpt", "integrator")
class BDPT(IntegratorTemplate):
    """Bidirectional path tracing: every (s, t) strategy, balance/power MIS by ratio recurrences."""

    PARAMS = (
        MAX_DEPTH,
        Param("bidir_depth", "int", BIDIR_DEPTH, min=2, max=MAX_BDPT_DEPTH,
              doc="Paths of at most this many segments are built by every strategy (light "
                  "vertices are stored per depth up to it); longer ones, up to max_depth, by "
                  "path tracing with next-event estimation (s = 0 and s = 1) only."),
        *roulette.RR_PARAMS,
        Param("heuristic", "choice", "power", choices=("balance", "power", "none"),
              doc="MIS weighting over the (s, t) strategies (none: every strategy weighted 1, "
                  "an image of (number of strategies) x each path length: for checking the "
                  "strategies with strategy_images)."),
        Param("beta", "float", 2.0, min=0.0, min_exclusive=True,
              doc="Exponent of the power heuristic."),
        Param("light_selection", "choice", "power", choices=light_selection.MODES,
              doc="Discrete pdf for choosing the light of a light sample (next-event "
                  "estimation); the light subpath starts by the same pmf for uniform and "
                  "power, by power for adaptive, bvh and ris (it has no shading point)."),
        light_selection.CANDIDATES_PARAM,
        HIDE_EMITTERS,
        Param("strategy_images", "bool", False,
              doc="Also write the weighted contribution of every strategy (s, t) as AOV "
                  "layers s<s>_t<t>.R/G/B (their sum is the image)."),
    )

    def setup(self):
        self.mis = Mis("balance" if self.heuristic == "none" else self.heuristic, self.beta)
        #: D: paths of at most D segments take every strategy, longer ones s = 0 and 1 only
        self.bd_depth = bidirectional_depth(self.max_depth, self.bidir_depth)
        if self.strategy_images and not 0 <= self.max_depth <= self.bd_depth:
            raise ParameterError(
                f"bdpt: parameter 'strategy_images' = true needs every path built by every "
                f"strategy: 'max_depth' = {self.max_depth} is not allowed with it; allowed: 0 "
                f"to bidir_depth ({self.bidir_depth})")
        self.strategies = strategy_list(self.max_depth) if self.strategy_images else []
        self.rr = roulette.Roulette.from_params(self.params)
        self.lights = light_selection.SelectionCache.of(self)
        # the light subpath has no shading point: adaptive, bvh and ris start it by power
        self.lights_e = light_selection.SelectionCache("power") \
            if self.light_selection in ("adaptive", "bvh", "ris") else None
        self._tables = (None, None)

    # ---- checks ---------------------------------------------------------------------------
    def check_support(self, scene, sensor):
        name = self.NAME
        if not is_jit():
            raise SceneError(f"{name}: variant {mi.variant()} is not supported; use a JIT "
                             "variant (llvm_ad_rgb, llvm_ad_mono, cuda_ad_rgb)")
        if mi.is_spectral or mi.is_polarized:
            raise SceneError(f"{name}: variant {mi.variant()} is not supported (the two "
                             "subpaths would need shared wavelengths); use llvm_ad_rgb")
        kind = str(sensor).split("[", 1)[0]
        if kind not in ("PerspectiveCamera", "RadianceMeter"):
            raise SceneError(f"{name}: sensor {kind} is not supported; allowed: a "
                             "'perspective' camera or a 'radiancemeter'")
        if mi.has_flag(sensor.film().flags(), mi.FilmFlags.Special):
            raise SceneError(f"{name}: film {str(sensor.film()).split('[', 1)[0]} is not "
                             "supported; use 'hdrfilm'")
        allowed = "allowed: area, point and spot lights, constant and envmap environments"
        for e in scene.emitters():
            shape = e.get_shape()
            kind = str(e).split("[", 1)[0]
            if mi.has_flag(e.flags(), mi.EmitterFlags.Infinite):
                if mi.has_flag(e.flags(), mi.EmitterFlags.Delta):
                    raise SceneError(f"{name}: emitter {kind} (infinite, delta direction) is "
                                     f"not supported; {allowed} (use nee_path)")
                continue
            if shape is None and kind not in ("PointLight", "SpotLight"):
                raise SceneError(f"{name}: emitter {kind} is not supported; {allowed}")
            if shape is not None and not _uniform_on_shape(e, shape):
                raise SceneError(f"{name}: area emitter on shape '{shape.id()}' has a "
                                 "spatially varying radiance; allowed: constant radiance")

    def emission_selection(self, scene, sel):
        """The light pmf of the light subpath's start: ``sel`` itself for a pmf independent of
        the shading point (uniform, power), else the power pmf."""
        return sel if self.lights_e is None else self.lights_e(scene)

    def aov_names(self):
        return [f"s{s_}_t{t}.{c}" for s_, t in self.strategies for c in "RGB"]

    def weight(self, denominator):
        """The MIS weight 1 / denominator (1 with heuristic none)."""
        if self.heuristic == "none":
            return mi.Float(1.0)
        return finite_weight(denominator)

    def record(self, sbuf, lane, sid, value, active):
        """Add ``value`` to strategy ``sid``'s image of this lane (strategy_images)."""
        if sbuf is None:
            return
        rgb = _to_rgb(value)
        n = len(self.strategies)
        for c in range(3):
            dr.scatter_add(sbuf.a, rgb[c], (lane * n + sid) * 3 + c, active)

    def tables(self, scene):
        """(EmitterTables, LambertTable) of ``scene``, built once per scene; the walks and
        connections read the LambertTable as ``self._lambert``."""
        if self._tables[0] is not scene:
            self._tables = (scene, (EmitterTables(scene), LambertTable(scene)))
        self._lambert = self._tables[1][1]
        return self._tables[1]

    def sample(self, scene, sampler, ray, medium=None, active=True):
        raise SceneError("bdpt renders through render() (mi.render, the render command): its "
                         "light-tracing strategies splat onto the film")

    # ---- render ---------------------------------------------------------------------------
    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        sel = self.prepare(scene)
        if getattr(self, "_supported", None) != (scene, sensor):   # once per scene and sensor
            self.check_support(scene, sensor)
            self._supported = (scene, sensor)
        film = sensor.film()
        spp = int(spp) or int(sensor.sampler().sample_count())
        film.prepare(self.aov_names())
        block = film.create_block()
        block.set_offset(film.crop_offset())
        block_lt = film.create_block(mi.ScalarVector2u(0), False, False)
        block_lt.set_offset(film.crop_offset())
        block_lt.set_coalesce(False)
        if len(scene.emitters()) == 0 or self.max_depth == 0:
            film.put_block(block)
            return film.develop() if develop else None
        crop = film.crop_size()
        pixels = int(crop[0]) * int(crop[1])
        cap = max(self.bd_depth - 2, 0)
        per_lane = max(cap, 1) * (27 + spectrum_channels()) * 4
        spp_chunk = max(1, min(spp, MEMORY_BUDGET // max(per_lane * pixels, 1)))
        done, chunk = 0, 0
        while done < spp:
            n = min(spp_chunk, spp - done)
            chunk_seed = (int(seed) + chunk * 0x9E3779B9) & 0xFFFFFFFF
            self.render_chunk(scene, sensor, sel, block, block_lt, n, spp, chunk_seed, cap)
            done += n
            chunk += 1
        base = 5 if mi.has_flag(film.flags(), mi.FilmFlags.Alpha) else 4
        combined = _combine(block, block_lt, _filter_mass(film), base)
        film.put_block(mi.ImageBlock(combined, film.crop_offset(), film.rfilter(),
                                     False, False))
        if not develop:
            film.schedule_storage()
            return None
        img = film.develop()
        if evaluate:
            dr.eval(img)
        return img

    def render_chunk(self, scene, sensor, sel, block, block_lt, spp, spp_total, seed, cap):
        film = sensor.film()
        crop = film.crop_size()
        lanes = int(crop[0]) * int(crop[1]) * spp
        sampler = sensor.sampler().clone()
        sampler.set_sample_count(spp)
        sampler.set_samples_per_wavefront(spp)
        sampler.seed(seed, lanes)
        lane = dr.arange(mi.UInt32, lanes)
        tables, lambert = self.tables(scene)
        store = VertexStore(lanes, cap)
        n_strat = len(self.strategies)
        # per lane and strategy (strategy_images), held in a plain object so that the
        # symbolic loops do not take the scattered-to array as loop state
        sbuf = _Buffer(dr.zeros(mi.Float, lanes * n_strat * 3)) if n_strat else None

        # 1. light subpaths: stored vertices, light tracing onto the film (t = 1)
        pinhole = _is_pinhole(sensor)
        if self.bd_depth >= 2:
            walk = LightWalk(self.mis, self.rr, self.bd_depth - 1, self.bd_depth - 2, lambert)
            scale = 1.0 / spp_total
            splat = self.light_tracer(scene, sensor, sampler, block_lt, scale) if pinhole \
                else None
            sel_e = self.emission_selection(scene, sel)
            walk.walk(scene, sel_e, tables, sampler, store, lane, mi.Bool(True), splat,
                      nee_sel=None if sel_e is sel else sel)
        store.evaluate()
        sampler.schedule_state()
        dr.eval(block_lt.tensor())

        # 2. camera subpaths: s = 0, s = 1 and the connections s, t >= 2
        ray, weight, pos = _camera_rays(sensor, sampler, spp)
        L, valid = self.camera_walk(scene, sel, tables, sensor, sampler, store, lane, ray, sbuf)
        rgb = _to_rgb(L * weight)
        values = [rgb[0], rgb[1], rgb[2]]
        if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
            values.append(dr.select(valid, mi.Float(1.0), mi.Float(0.0)))
        values.append(mi.Float(1.0))
        if n_strat:
            dr.eval(sbuf.a)
            values += [dr.gather(mi.Float, sbuf.a, lane * (n_strat * 3) + j)
                       for j in range(n_strat * 3)]
        block.put(pos, values)
        dr.eval(block.tensor())

    def light_tracer(self, scene, sensor, sampler, block_lt, scale):
        """The t = 1 strategy at a light vertex (:meth:`t1_connection`), splatted onto the
        film."""
        alpha = mi.has_flag(sensor.film().flags(), mi.FilmFlags.Alpha)
        offset = mi.Vector2f(block_lt.offset())
        n_strat = len(self.strategies)

        def splat(si, bsdf, beta, dvcm, dvc, depth, active, sampler):
            uv, rgb, active = self.t1_connection(scene, sensor, si, bsdf, beta, dvcm, dvc,
                                                 depth, active, sampler, scale)
            vals = [rgb[0], rgb[1], rgb[2]] + ([mi.Float(0.0)] if alpha else []) + \
                [mi.Float(0.0)]
            if n_strat:                       # s = depth + 1, t = 1
                sid = strategy_id(depth + 1, depth + 1)
                vals += [dr.select(sid == j, rgb[c], 0.0) for j in range(n_strat)
                         for c in range(3)]
            block_lt.put(uv + offset, vals, active)
        return splat

    def t1_connection(self, scene, sensor, si, bsdf, beta, dvcm, dvc, depth, active, sampler,
                      scale=1.0):
        """Light vertex y_{depth} connected to the pinhole: (film position in pixels relative
        to the crop window, weighted RGB contribution times ``scale``, active).  Draws two
        numbers (the sensor's direction sample)."""
        mis, max_depth, lambert = self.mis, self.bd_depth, self._lambert
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        u = sampler.next_2d(active)
        active = active & (depth + 1 <= max_depth)
        ds, w_s = sensor.sample_direction(si, u, active)
        active &= ds.pdf > 0
        wo = si.to_local(ds.d)
        f = bsdf.eval(ctx, si, wo, active) * shading_correction(si, ds.d)
        p_rev = reverse_pdf(bsdf, ctx, si, wo, active & (dvc > 0), lambert)
        p_cam = mi.unpolarized_spectrum(w_s)[0] * dr.abs(dr.dot(si.n, ds.d))
        w = self.weight(1.0 + mis(p_cam) * (dvcm + dvc * mis(p_rev)))
        value = beta * f * w_s * (w * scale)
        active &= dr.any(value != 0)
        if dr.hint(self.hide_emitters, mode="scalar"):
            # the camera sees no emitter, and through them
            active &= ~_on_emitter(scene, si)
            active &= ~_occluded_by_non_emitters(scene, si.spawn_ray_to(ds.p), active)
        else:
            active &= ~scene.ray_test(si.spawn_ray_to(ds.p), active)
        return ds.uv, _to_rgb(value), active

    @record_once
    @dr.syntax
    def camera_walk(self, scene, sel, tables, sensor, sampler, store, lane, ray, sbuf=None,
                    leave_out=None):
        """The camera subpath and the strategies that end on it: (L, valid).  ``leave_out``
        (pssmlt renders these apart, :meth:`PSSMLT.seen_emission`): ``"direct"``, the
        emission the camera sees directly; ``"delta"``, also the emission it sees through
        delta scatterings only (s = 0 after an all-delta prefix: the one strategy that can
        make such paths, with weight 1)."""
        seen = leave_out is None
        delta = leave_out == "delta"
        mis, lambert = self.mis, self._lambert
        max_depth = depth_limit(self.max_depth)
        bd_depth = self.bd_depth     # longer paths: s = 0 and s = 1 only (no dvc terms)
        sel_e = self.emission_selection(scene, sel)
        pinhole = _is_pinhole(sensor)
        hide = self.hide_emitters
        w_seen = 0.0 if (hide or not seen) else 1.0   # emission seen directly
        prefix = mi.Bool(True)     # (leave_out delta) the camera subpath so far: deltas only
        has_env = scene.environment() is not None
        ctx = mi.BSDFContext()
        L = mi.Spectrum(0.0)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        dvcm = mi.Float(0.0)
        dvc = mi.Float(0.0)
        depth = mi.UInt32(1)
        prev_p = mi.Point3f(ray.o)
        prev_n = mi.Normal3f(0.0)
        ray = mi.Ray3f(ray)
        ray.time = widen(ray.time, ray.d)    # (loop-invariant state as wide as the loop:
        prefix = widen(prefix, ray.d)        # recorded once, see record_once)
        active = mi.Bool(True)
        valid = mi.Bool(False)
        while dr.hint(active, label="bdpt camera walk", exclude=[max_depth, ctx]):
            first = depth == 1
            if dr.hint(hide, mode="scalar"):     # area emitters transparent to camera rays
                si = scene.ray_intersect(ray, active & ~first)
                si = dr.select(first, skip_emitters(scene, ray, active & first), si)
                dist2 = dr.squared_norm(si.p - ray.o)
            else:
                si = scene.ray_intersect(ray, active)
                dist2 = dr.square(si.t)
            hit = active & si.is_valid()
            valid |= first & hit
            cos_in = dr.abs(dr.dot(si.n, ray.d))

            it_prev = dr.zeros(mi.Interaction3f)
            it_prev.p, it_prev.n = prev_p, prev_n
            # s = 0 on the environment: the camera subpath escapes (the ratios as after the
            # last scattering: y0 is a direction, so no d^2 and no cosine at the light end)
            if dr.hint(has_env, mode="scalar"):
                esc = active & ~si.is_valid()
                em_env = emitter_at(scene, si)
                le_env = emitted(scene, si, esc)
                esc &= dr.any(le_env != 0)
                pick_env = sel.pmf_at(it_prev, em_env, esc & ~first)   # next-event est.'s
                pick_env_e = sel_e.pmf(em_env, esc)                    # the light subpath's
                _, disk_pdf, _ = tables.lookup(em_env, esc)
                p_env = environment_direction_pdf(em_env, ray.d, esc & ~first)
                w_env = self.weight(1.0 + mis(pick_env * p_env) * dvcm
                                    + dr.select(depth <= bd_depth,
                                                mis(pick_env_e * p_env * disk_pdf) * dvc, 0.0))
                w_env = dr.select(first, w_seen, w_env)
                if dr.hint(delta, mode="scalar"):
                    w_env = dr.select(prefix, 0.0, w_env)
                L += dr.select(esc, beta * le_env * w_env, 0.0)
                self.record(sbuf, lane, strategy_id(0, depth), beta * le_env * w_env, esc)
            # the first hit: light tracing's density relative to the camera's (0 for a
            # radiancemeter, whose delta direction no light subpath can reach)
            if dr.hint(pinhole, mode="scalar"):
                ds_c, w_c = sensor.sample_direction(si, mi.Point2f(0.5), hit & first)
                p_film = mi.unpolarized_spectrum(w_c)[0] * dr.square(ds_c.dist)
                dvcm = dr.select(first, mis(safe_div(1.0, p_film)), dvcm)
            else:
                dvcm = dr.select(first, 0.0, dvcm)
            dvcm *= mis(dist2)
            inv_cos = mis(safe_div(1.0, cos_in))
            dvcm *= inv_cos
            dvc *= inv_cos

            # s = 0: the camera subpath hits an area light
            em = emitter_at(scene, si)
            le = emitted(scene, si, hit)
            hit_light = hit & dr.any(le != 0)
            _, pos_pdf, _ = tables.lookup(em, hit_light)
            pick = sel.pmf_at(it_prev, em, hit_light & ~first)     # next-event estimation's
            pick_e = sel_e.pmf(em, hit_light)                       # the light subpath's
            ds_e = direction_sample(scene, si, it_prev)
            p_nee = em.pdf_direction(it_prev, ds_e, hit_light & ~first)
            direct_a = pick * p_nee * cos_in * safe_div(1.0, dist2)
            emission_w = pick_e * pos_pdf * cos_in * dr.inv_pi
            w0 = dr.select(first, w_seen,
                           self.weight(1.0 + mis(direct_a) * dvcm
                                       + dr.select(depth <= bd_depth, mis(emission_w) * dvc,
                                                   0.0)))
            if dr.hint(delta, mode="scalar"):
                w0 = dr.select(prefix, 0.0, w0)
            L += dr.select(hit_light, beta * le * w0, 0.0)
            self.record(sbuf, lane, strategy_id(0, depth), beta * le * w0, hit_light)

            bsdf = si.bsdf(ray)
            smooth = hit & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)

            # s = 1: next-event estimation
            nee = smooth & (depth + 1 <= max_depth)
            ds_l, w_em, norm = sel.sample_direction(si, sel.sample_1d(sampler, nee),
                                                    sampler.next_2d(nee), nee, bsdf=bsdf, ctx=ctx)
            vis = nee & dr.any(w_em != 0)
            vis &= ~scene.ray_test(si.spawn_ray_to(ds_l.p), vis)
            wo_l = si.to_local(ds_l.d)
            # one BSDF call evaluates the light sample's direction and samples the continuation
            f_l, p_fwd_l, bs, w = bsdf.eval_pdf_sample(ctx, si, wo_l, sampler.next_1d(hit),
                                                       sampler.next_2d(hit), hit)
            p_rev_l = reverse_pdf(bsdf, ctx, si, wo_l, vis & (dvc > 0), lambert)
            is_area_l, pos_pdf_l, dir_pdf_l = tables.lookup(ds_l.emitter, vis)
            inf_l = tables.infinite(ds_l.emitter, vis)
            pick_l = sel.pmf_at(si, ds_l.emitter, vis, norm)
            p_nee_w = safe_div(ds_l.pdf, pick_l)
            cos_z = dr.abs(dr.dot(si.n, ds_l.d))
            # emission density over next-event estimation's, in z's area measure: an
            # environment's emission samples the same direction, then the disk (p_disk cos_z)
            ratio = dr.select(is_area_l, safe_div(pos_pdf_l * cos_z, dr.pi * p_nee_w),
                              dr.select(inf_l, pos_pdf_l * cos_z,
                                        dir_pdf_l * cos_z * safe_div(1.0, dr.square(ds_l.dist))))
            w_light = dr.select(ds_l.delta, 0.0, mis(safe_div(p_fwd_l, ds_l.pdf)))
            if dr.hint(sel_e is not sel, mode="scalar"):   # the light subpath's pmf differs
                ratio *= safe_div(sel_e.pmf(ds_l.emitter, vis), pick_l)
            w_cam = dr.select(depth + 1 <= bd_depth, mis(ratio) * (dvcm + dvc * mis(p_rev_l)),
                              0.0)
            w1 = self.weight(w_light + 1.0 + w_cam)
            L += dr.select(vis, beta * f_l * w_em * w1, 0.0)
            self.record(sbuf, lane, strategy_id(1, depth + 1), beta * f_l * w_em * w1, vis)

            # s >= 2, t >= 2: connections to the stored light vertices
            conn = smooth & (depth + 2 <= bd_depth)
            L += self.connect(scene, store, lane, si, bsdf, beta, dvcm, dvc, depth, conn, sbuf)

            # continue with the BSDF sample drawn above (radiance mode)
            spec = is_delta_sample(bs)
            wo = si.to_world(bs.wo)
            p_rev = reverse_pdf(bsdf, ctx, si, bs.wo, hit & ~spec & (dvc > 0), lambert)
            cos_out = dr.abs(dr.dot(si.n, wo))
            dvc = dr.select(spec, dvc * mis(cos_out),
                            mis(safe_div(cos_out, bs.pdf)) * (dvc * mis(p_rev) + dvcm))
            dvcm = dr.select(spec, 0.0, mis(safe_div(1.0, bs.pdf)))
            beta *= w
            eta *= bs.eta
            active = hit & ((bs.pdf > 0) | spec)
            if dr.hint(delta, mode="scalar"):
                prefix &= spec
            beta, active = self.rr(beta, eta, depth, sampler.next_1d(active), active)
            prev_p, prev_n = mi.Point3f(si.p), mi.Normal3f(si.n)
            ray = si.spawn_ray(wo)
            depth += 1
            active &= depth <= max_depth
        return L, valid

    @record_once
    @dr.syntax
    def connect(self, scene, store, lane, si, bsdf, beta, dvcm, dvc, depth, active, sbuf=None):
        """Sum over the stored light vertices y_k of the weighted connection z -- y_k."""
        mis, max_depth, lambert = self.mis, self.bd_depth, self._lambert
        ctx = mi.BSDFContext()
        ctx_l = mi.BSDFContext(mi.TransportMode.Importance)
        L = mi.Spectrum(0.0)
        n = dr.gather(mi.UInt32, store.count, lane, active)
        # stored vertex k lies at depth >= k + 1: only k <= max_depth - depth - 2 can connect
        n = dr.minimum(n, dr.select(depth + 1 < max_depth, max_depth - 1 - depth, 0))
        k = mi.UInt32(0)
        while dr.hint(active & (k < n), label="bdpt connections",
                      exclude=[active, n, si, bsdf, beta, dvcm, dvc, depth, lane, ctx, ctx_l]):
            act = active & (k < n)
            sy, bsdf_y, beta_y, dvcm_y, dvc_y, depth_y = store.get(lane * store.cap + k, act)
            ok = act & (depth_y + depth + 1 <= max_depth)
            d = sy.p - si.p
            dist2 = dr.squared_norm(d)
            dirn = d * dr.rsqrt(dr.select(dist2 > 0, dist2, 1.0))
            ok &= dist2 > 0
            wo_c = si.to_local(dirn)
            f_c, p_c = bsdf.eval_pdf(ctx, si, wo_c, ok)
            p_c_rev = reverse_pdf(bsdf, ctx, si, wo_c, ok & (dvc > 0), lambert)
            wo_y = sy.to_local(-dirn)
            f_y, p_y = bsdf_y.eval_pdf(ctx_l, sy, wo_y, ok)
            p_y_rev = reverse_pdf(bsdf_y, ctx_l, sy, wo_y, ok & (dvc_y > 0), lambert)
            inv_d2 = safe_div(1.0, dist2)
            cos_c = dr.abs(dr.dot(si.n, dirn))
            cos_y = dr.abs(dr.dot(sy.n, dirn))
            w_light = mis(p_c * cos_y * inv_d2) * (dvcm_y + dvc_y * mis(p_y_rev))
            w_cam = mis(p_y * cos_c * inv_d2) * (dvcm + dvc * mis(p_c_rev))
            w = self.weight(w_light + 1.0 + w_cam)
            contrib = beta * f_c * f_y * shading_correction(sy, -dirn) * beta_y * (w * inv_d2)
            ok &= dr.any(contrib != 0)
            ok &= ~scene.ray_test(si.spawn_ray_to(sy.p), ok)
            L += dr.select(ok, contrib, 0.0)
            self.record(sbuf, lane, strategy_id(depth_y + 1, depth_y + depth + 1), contrib, ok)
            k += 1
        return L


@record_once
@dr.syntax
def _occluded_by_non_emitters(scene, ray, active):
    """Whether a surface other than an emitting shape lies on ``ray`` (up to ``ray.maxt``):
    the visibility of the camera under ``hide_emitters``, for which area emitters are
    transparent."""
    target = ray.o + ray.d * ray.maxt
    si = scene.ray_intersect(ray, active)
    skip = mi.Bool(active) & _on_emitter(scene, si)
    while dr.hint(skip, label="bdpt skip emitters"):
        si = scene.ray_intersect(si.spawn_ray_to(target), skip)
        skip &= _on_emitter(scene, si)
    return active & si.is_valid() & ~_on_emitter(scene, si)


class _Buffer:
    """An array the symbolic loops scatter to, kept out of their loop state."""

    def __init__(self, a):
        self.a = a


def bidirectional_depth(max_depth: int, bidir_depth: int) -> int:
    """D: the longest path (segments) that every strategy builds: ``bidir_depth``, or
    ``max_depth`` where that is finite and shorter."""
    return bidir_depth if max_depth < 0 else min(max_depth, bidir_depth)


def strategy_list(max_depth: int) -> list:
    """The strategies (s, t) in image order: by path length k = s + t - 1 (segments), then s:
    k = 1: (0, 2) only (s = 1, t = 1 is not used); k >= 2: s = 0 .. k."""
    out = [(0, 2)] if max_depth >= 1 else []
    for k in range(2, max_depth + 1):
        out += [(s, k + 1 - s) for s in range(k + 1)]
    return out


def strategy_id(s, k):
    """Index of strategy (s, t = k + 1 - s) in :func:`strategy_list` (k = path length)."""
    k = mi.UInt32(k)
    return dr.select(k <= 1, 0, (k * (k + 1)) // 2 - 2 + mi.UInt32(s))


def _is_pinhole(sensor) -> bool:
    name = getattr(sensor, "class_name", None)     # (no read of the sensor's values)
    return (name() if callable(name) else str(sensor).split("[", 1)[0]) == "PerspectiveCamera"


def _uniform_on_shape(emitter, shape) -> bool:
    """Whether the area emitter samples positions uniformly on its shape (constant radiance)."""
    import numpy as np
    n = 16
    u = mi.Point2f(dr.linspace(mi.Float, 0.1, 0.9, n), dr.linspace(mi.Float, 0.8, 0.2, n))
    ps, _ = emitter.sample_position(0.0, u, True)
    pdf = np.array(ps.pdf, dtype=np.float64).ravel()
    area = float(shape.surface_area()[0])
    return bool(np.allclose(pdf * area, 1.0, rtol=1e-3))


def _to_rgb(value):
    value = mi.unpolarized_spectrum(value)
    if mi.is_monochromatic:
        return mi.Color3f(value[0])
    return value


def _camera_rays(sensor, sampler, spp):
    """Camera rays of a chunk: ``spp`` per pixel, in pixel order (as Mitsuba's render)."""
    film = sensor.film()
    size = film.crop_size()
    idx = dr.arange(mi.UInt32, int(size[0]) * int(size[1]) * spp)
    idx //= dr.opaque(mi.UInt32, spp)
    pos = mi.Vector2i()
    pos.y = mi.Int32(idx // int(size[0]))
    pos.x = mi.Int32(idx - mi.UInt32(pos.y) * int(size[0]))
    pos += mi.Vector2i(film.crop_offset())
    pos_f = mi.Vector2f(pos) + sampler.next_2d()
    scale = dr.rcp(mi.ScalarVector2f(size))
    offset = -mi.ScalarVector2f(film.crop_offset()) * scale
    ray, weight = sensor.sample_ray_differential(0.0, 0.5, dr.fma(pos_f, scale, offset),
                                                 mi.Point2f(0.5))
    splat = mi.Vector2f(pos) if film.rfilter().is_box_filter() else pos_f
    return mi.Ray3f(ray), weight, splat


def _filter_mass(film, n: int = 8):
    """F_j = the integral over the film of pixel j's reconstruction filter, by an n x n grid
    of splats per pixel (exact for the box filter; smooth filters converge fast): the expected
    filter weight one camera sample per pixel gives pixel j."""
    size = film.crop_size()
    w, h = int(size[0]), int(size[1])
    idx = dr.arange(mi.UInt32, w * h * n * n)
    sub = idx % (n * n)
    pix = idx // (n * n)
    pos = mi.Vector2f(mi.Float(pix % w) + (mi.Float(sub % n) + 0.5) / n,
                      mi.Float(pix // w) + (mi.Float(sub // n) + 0.5) / n)
    blk = mi.ImageBlock(size, film.crop_offset(), 1, film.rfilter(), False, False)
    blk.set_coalesce(False)
    blk.put(pos + mi.Vector2f(film.crop_offset()), [mi.Float(1.0 / (n * n))])
    return blk.tensor()


def _combine(block, block_lt, mass, base):
    """The camera block with the light-tracing sums added to its colour channels: each pixel's
    splat sum divided by its filter mass F_j (so that it estimates the same filtered pixel
    value as the camera samples' weighted mean), times the pixel's camera weight (which the
    film's weight division then removes)."""
    t = block.tensor()
    lt = block_lt.tensor()
    shape = t.shape
    ch = shape[2]
    w_idx = base - 1                     # R G B [A] W, then the AOVs
    data = t.array
    idx = dr.arange(mi.UInt32, dr.width(data))
    c = idx % ch
    pix = idx // ch
    w = dr.gather(mi.Float, data, pix * ch + w_idx)
    colour = (c < 3) | (c >= base)
    add = dr.gather(mi.Float, lt.array, pix * lt.shape[2] + c, colour)
    f = dr.gather(mi.Float, mass.array, pix, colour)
    out = data + dr.select(colour & (f > 0), add * w / dr.select(f > 0, f, 1.0), 0.0)
    return mi.TensorXf(out, shape)
