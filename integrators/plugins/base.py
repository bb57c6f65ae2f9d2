"""What every integrator template shares: reading its parameters, ``to_string``, ``max_depth``."""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi

from ..common import (bind_emitters, emitted, emitter_at, emitter_table, is_jit,
                      record_once, widen)
from ..params import MAX_DEPTH_VALUE, Param, read

MAX_DEPTH = Param("max_depth", "int", -1, min=0, max=MAX_DEPTH_VALUE, allow=(-1,),
                  doc="Longest path depth (-1: unlimited; 1: emitters seen directly; "
                      "2: direct light), Mitsuba's meaning.")


class IntegratorTemplate:
    """Base of our integrator templates (made into ``mi.SamplingIntegrator`` subclasses)."""

    PARAMS: tuple = ()
    NAME = "integrator"

    def __init__(self, props):
        self._base.__init__(self, props)
        self.params = read(self.NAME, self.PARAMS, props)
        #: the parameters the scene (or dict) set explicitly
        self.given = frozenset(props.keys())
        for k, v in self.params.items():
            setattr(self, k, v)
        self.setup()

    def setup(self):
        """Derived state from ``self.params`` (override)."""

    #: our integrators have no volumetric estimator: scenes with media are refused
    HANDLES_MEDIA = False

    def prepare(self, scene):
        """Per-scene set-up, once per scene (sample() calls it; cheap after the first call):
        :func:`check_scene`, :meth:`scene_warnings` and the scene's shape-to-emitter table
        (:func:`~integrators.common.emitter_table`, bound for this render), then the light
        selection (the integrator's ``lights`` cache, when it has one)."""
        if getattr(self, "_prepared", None) is not scene:
            check_scene(scene, self.NAME, self.HANDLES_MEDIA)
            self.scene_flags = scene_bsdf_flags(scene)
            for msg in self.scene_warnings(scene):
                warnings.warn(msg, RuntimeWarning, stacklevel=2)
            if is_jit():
                bind_emitters(self, scene, emitter_table(scene))
            self._prepared = scene
        elif is_jit():
            bind_emitters(self, scene)
        lights = getattr(self, "lights", None)
        return lights(scene) if lights is not None else None

    def scene_warnings(self, scene) -> list:
        """One-line warnings about what this integrator will not find in ``scene``."""
        return []

    def camera_hit(self, scene, ray, active):
        """The first surface a camera ray sees and the emission it shows: (si, L_e).

        With ``hide_emitters`` (as Mitsuba's integrators), area emitters are transparent to
        camera rays (the ray goes on to what is behind them) and the environment is black."""
        ray = mi.Ray3f(ray)
        ray.time = widen(ray.time, ray.d)    # (the paths' loops record once: record_once)
        if self.params.get("max_depth", -1) == 0:   # Mitsuba's meaning: nothing at all
            return scene.ray_intersect(ray, active), mi.Spectrum(0.0)
        if not self.params.get("hide_emitters", False):
            si = scene.ray_intersect(ray, active)
            return si, emitted(scene, si, active)
        return skip_emitters(scene, ray, active), mi.Spectrum(0.0)

    def aov_names(self):
        return []

    def base_render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        """Mitsuba's own ``render`` from a ``render`` override, with SIGINT still reaching
        Python.

        ``mi.render`` enters Mitsuba's ``render`` binding, which installs a SIGINT handler that
        cancels the render and passes the signal on to the handler it replaced; an override
        that calls the binding again nests a second handler whose "replaced" one is Mitsuba's
        own, so the signal never reaches Python (Ctrl-C ignored for the rest of the process).
        Re-installing Python's handler right before and after the inner call keeps the chain
        ending in Python (main thread only: elsewhere signals are the main thread's)."""
        with _python_sigint():
            return self._base.render(self, scene, sensor, seed, spp, develop, evaluate)

    def to_string(self):
        body = ",\n".join(f"  {k} = {v!r}" for k, v in self.params.items())
        return f"{self.NAME}[\n{body}\n]"


class _python_sigint:
    """Re-install Python's SIGINT handler at the C level on entry and exit (main thread)."""

    def __enter__(self):
        self._reinstall()

    def __exit__(self, *exc):
        self._reinstall()
        return False

    @staticmethod
    def _reinstall():
        import signal
        import threading
        if threading.current_thread() is threading.main_thread():
            h = signal.getsignal(signal.SIGINT)
            if h is not None:
                signal.signal(signal.SIGINT, h)


# ---- what a scene may hold ---------------------------------------------------------------
HIDE_EMITTERS = Param("hide_emitters", "bool", False,
                      doc="Hide emitters seen directly by camera rays (area lights become "
                          "transparent to them, the environment black), as Mitsuba's integrators.")


class SceneError(ValueError):
    """A scene our integrators cannot render as it is; the message is one line for the user."""


def _name(obj) -> str:
    ident = obj.id() if hasattr(obj, "id") else ""
    shape = obj.get_shape() if hasattr(obj, "get_shape") else None
    if shape is not None and shape.id():
        ident = shape.id()
    kind = str(obj).split("[", 1)[0].strip()
    return f"'{ident}' ({kind})" if ident else f"({kind})"


def _bad_values(obj, keys_ok=lambda k: True, negative_ok: bool = False):
    """(parameter, value) of the first non-finite (or negative) parameter of ``obj``."""
    import numpy as np
    params = mi.traverse(obj)
    for key in params.keys():
        if "to_world" in key or "to_uv" in key or "position" in key or "direction" in key \
                or not keys_ok(key):
            continue
        try:
            v = np.asarray(params[key], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            continue
        if v.size == 0:
            continue
        bad = ~np.isfinite(v) if negative_ok else ~(np.isfinite(v) & (v >= 0))
        if bad.any():
            return key, float(v[np.argmax(bad)])
    return None


def check_scene(scene, integrator_name: str, handles_media: bool = False) -> list:
    """Refuse, in one line, a scene feature the integrator cannot handle or a bad value in an
    emitter or BSDF; return the one-line warnings the scene deserves (delta lights for an
    integrator that cannot reach them is the caller's to add)."""
    if not handles_media:
        where = []
        for shape in scene.shapes():
            for side, med in (("interior", shape.interior_medium()),
                              ("exterior", shape.exterior_medium())):
                if med is not None:
                    where.append(f"the {side} of shape {_name(shape)}")
        for sensor in scene.sensors():
            if sensor.get_medium() is not None:
                where.append(f"sensor {_name(sensor)}")
        if where:
            raise SceneError(
                f"{integrator_name}: the scene has a participating medium ({where[0]}"
                f"{f' and {len(where) - 1} more' if len(where) > 1 else ''}) and "
                f"{integrator_name} has no volumetric estimator; render media with Mitsuba's "
                "'volpath' (or remove the medium)")
    for e in scene.emitters():
        # spectral variants store an RGB emitter as spectral-upsampling coefficients, which may
        # be negative: only RGB and monochrome values can be checked for sign
        bad = _bad_values(e, keys_ok=lambda k: k != "sampling_weight",
                          negative_ok=bool(mi.is_spectral))
        if bad:
            raise SceneError(f"emitter {_name(e)}: parameter '{bad[0]}' = {bad[1]:g} is invalid; "
                             "allowed: finite values >= 0")
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is None:
            continue
        bad = _bad_values(bsdf, negative_ok=True)
        if bad:
            raise SceneError(f"bsdf {_name(bsdf)} of shape {_name(shape)}: parameter '{bad[0]}' "
                             f"= {bad[1]:g} is invalid; allowed: finite values")
    return []


def scene_bsdf_flags(scene) -> int:
    """The union of the flags of every BSDF in ``scene`` (what its surfaces can do), so that an
    estimator compiles no sampling call for a lobe no surface has."""
    flags = 0
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None:
            flags |= int(bsdf.flags())
    return flags


def has_delta_lights(scene) -> bool:
    return any(mi.has_flag(e.flags(), mi.EmitterFlags.Delta) for e in scene.emitters())


@record_once
@dr.syntax
def skip_emitters(scene, ray, active):
    """First intersection of ``ray`` that is not on an emitting shape."""
    ray = mi.Ray3f(ray)
    ray.time = widen(ray.time, ray.d)
    si = scene.ray_intersect(ray, active)
    skip = mi.Bool(active) & _on_emitter(scene, si)
    while dr.hint(skip, label="skip emitters"):
        ray = si.spawn_ray(ray.d)
        si = scene.ray_intersect(ray, skip)
        skip &= _on_emitter(scene, si)
    return si


def _on_emitter(scene, si):
    if is_jit():
        return si.is_valid() & (emitter_at(scene, si) != None)  # noqa: E711 (a pointer array)
    return bool(si.is_valid()) and si.shape is not None and si.shape.emitter() is not None
