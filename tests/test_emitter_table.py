"""The shape-to-emitter table (``integrators.common.emitter_table`` / ``emitter_at`` /
``direction_sample``), which our integrators read instead of the virtual calls
``si.emitter(scene)`` and ``mi.DirectionSample3f(scene, si, ref)`` (each trace of those traces
every shape: seconds per render call at thousands of emitting shapes).

Exact checks, no statistics: on random rays through a scene with rectangle and sphere lights, a
shape without an emitter, an environment and rays that miss, the table must name the same
emitter as Mitsuba's call for every lane, and the direction sample must agree field by field.
Negative control: a table of the same scene with two entries swapped is caught by the same
comparison.  The binding must never outlive the integrator that made it, nor serve another
scene (it falls back to Mitsuba's call)."""
from __future__ import annotations

import gc

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators import common


def _scene(env=True):
    d = {"type": "scene",
         "rect": {"type": "rectangle", "emitter": {"type": "area", "radiance": 2.0},
                  "to_world": mi.ScalarTransform4f().translate([0, 0, 2])},
         "ball": {"type": "sphere", "center": [1.5, 0, 0], "radius": 0.5,
                  "emitter": {"type": "area", "radiance": 3.0}},
         "box": {"type": "cube", "to_world": mi.ScalarTransform4f().translate([-1.5, 0, 0])
                 .scale(0.5)},
         "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f()
                   .translate([0, 0, -1]).scale(3)}}
    if env:
        d["env"] = {"type": "constant", "radiance": 0.5}
    return mi.load_dict(d)


def _rays(n=4096, seed=3):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    o = mi.Point3f(*[mi.Float(np.full(n, v, np.float32)) for v in (0.1, 0.2, 0.3)])
    return mi.Ray3f(o, mi.Vector3f(*[mi.Float(c.astype(np.float32)) for c in d]))


def _ids(ptr):
    return np.array(dr.reinterpret_array(mi.UInt32, ptr))


class _Holder:
    """Stands in for an integrator: the binding needs a weakly referable owner holding the
    scene it was prepared for (``_prepared``)."""
    def __init__(self, scene):
        self._prepared = scene


pytestmark = pytest.mark.skipif(not common.is_jit(), reason="the table serves JIT variants")


@pytest.mark.parametrize("env", [True, False])
def test_emitter_at_names_mitsubas_emitter_on_every_lane(env):
    scene = _scene(env)
    si = scene.ray_intersect(_rays())
    holder = _Holder(scene)
    common.bind_emitters(holder, scene, common.emitter_table(scene))
    ours, theirs = _ids(common.emitter_at(scene, si)), _ids(si.emitter(scene))
    hits = np.array(si.is_valid())
    # the rays reach every kind of lane: both lights, the plain box and floor, and misses
    assert 0 < hits.sum() < len(hits)
    assert len(set(theirs[hits])) == 3          # rect, ball and 0 (box, floor)
    assert (theirs[~hits] != 0).all() == env
    np.testing.assert_array_equal(ours, theirs)


def test_negative_control_a_wrong_table_is_caught():
    scene = _scene()
    si = scene.ray_intersect(_rays())
    table = np.array(common.emitter_table(scene))
    lit = np.flatnonzero(table[1:]) + 1         # the two area lights' shapes
    table[lit[0]], table[lit[1]] = table[lit[1]], table[lit[0]]
    holder = _Holder(scene)
    common.bind_emitters(holder, scene, mi.UInt32(table))
    ours, theirs = _ids(common.emitter_at(scene, si)), _ids(si.emitter(scene))
    assert (ours != theirs).sum() > 100


def test_direction_sample_matches_mitsubas_record():
    scene = _scene()
    si = scene.ray_intersect(_rays(seed=5))
    ref = dr.zeros(mi.Interaction3f, dr.width(si.p))
    ref.p = mi.Point3f(0.1, 0.2, 0.3)
    holder = _Holder(scene)
    common.bind_emitters(holder, scene, common.emitter_table(scene))
    ours, theirs = common.direction_sample(scene, si, ref), mi.DirectionSample3f(scene, si, ref)
    for field in ("p", "n", "uv", "d", "dist", "time", "pdf"):
        a, b = np.array(getattr(ours, field)), np.array(getattr(theirs, field))
        np.testing.assert_allclose(*np.broadcast_arrays(a, b), rtol=1e-6, atol=1e-6,
                                   err_msg=field)
    np.testing.assert_array_equal(*np.broadcast_arrays(np.array(ours.delta),
                                                       np.array(theirs.delta)))
    np.testing.assert_array_equal(_ids(ours.emitter), _ids(theirs.emitter))


def test_binding_serves_only_its_scene_and_only_while_its_integrator_lives():
    scene, other = _scene(), _scene(env=False)
    table = common.emitter_table(scene)
    holder = _Holder(scene)
    common.bind_emitters(holder, scene, table)
    assert common._bound_table(scene) is table
    assert common._bound_table(other) is None
    holder._prepared = other                    # the integrator moved on to another scene
    assert common._bound_table(scene) is None
    holder._prepared = scene
    del holder
    gc.collect()
    assert common._bound_table(scene) is None
    # unbound, emitter_at is Mitsuba's own call
    si = other.ray_intersect(_rays())
    np.testing.assert_array_equal(_ids(common.emitter_at(other, si)),
                                  _ids(si.emitter(other)))
