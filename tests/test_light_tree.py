"""light_selection=bvh (integrators/sampling/light_tree.py): the light BVH.

* the tree: every node's power is the sum of its leaves', its box holds its children's, its cone
  holds its children's axes; every light is one leaf, reached by its bit trail;
* pmf: sum over all emitters of p(j | x) is 1 at random points and normals where every light
  can contribute (mixed scenes: rectangles, spheres, a mesh, point and spot lights, a constant
  environment, a zero-power light), at most 1 elsewhere, the rest being the measured chance
  that no light is chosen; the light traversal draws has p(j | x) = pmf_at(x, j) exactly;
* chi-square (integrators/testing/chi2.py, H0: the drawn light index has the pmf pmf_at;
  Pearson over unit cells of the index line, alpha = 1e-3 family-wise over the points);
* a light of zero power is never chosen and has pmf 0; a light that can contribute to x always
  has p(j | x) > 0 (and a one-sided light seen from behind has 0);
* unbiased (H0: unbiased; Student t on batch means against the closed form, Sidak over RGB,
  alpha = 1e-4 (the kit's default), relative s.e. < 0.5 %) on the many-light plane (64
  rectangles with radiance over four decades, two point lights, a zero-power rectangle: the
  sum of Lambert terms) for direct_mis, nee_path and mis3 with bvh;
* the scalar and spectral variants run it.

light_selection=ris (ResampledTreeSelection: 4 tree candidates, one kept by resampled
importance sampling):

* its weight is unbiased for any per-light values g: H0 E[factor(Y) g_Y] = sum of g over the
  lights the tree can pick, Student t on 64 batch means of 2^18 draws (kit default alpha,
  Sidak over nothing: one value), 3 points x 2 scenes x 2 kinds of g; the negative control,
  the tree's own weight 1 / p(Y) on the resampled choice, is rejected by the same test;
* the pmf it reports (for MIS) is the tree's pmf_at of the light it kept;
* unbiased against the many-light closed form (direct_mis, nee_path, mis3) and against power
  selection with every kind of emitter, as bvh above, also over a glossy floor;
* lower per-pixel variance than bvh on the 64-light field (one-sided Wilcoxon, as above);
* with the BSDF given (every integrator gives it), resampling by each candidate's unshadowed
  contribution: the light-sample estimate at floor points has bvh's mean (Welch
  z, kit default alpha; a 2 % bias is rejected by the same test).
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import integrators
from integrators.sampling import light_tree as lt
from integrators.sampling.light_selection import make
from integrators.testing import assert_unbiased
from integrators.testing.chi2 import chi2_test
from integrators.testing.scenes import light_rect, plane_scene

ROOT = Path(__file__).resolve().parents[1]


def _tool(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scenes" / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


many = _tool("make_many_lights")
field = _tool("make_light_field")

RHO = 0.5
POINTS = [(0.1, 0.2, 0.0), (1.9, -1.3, 0.0), (-2.6, 2.4, 0.0)]
LAMPS = [((0.5, -0.4, 0.8), 0.6), ((-1.7, 1.1, 1.2), 2.5)]


def plane_with_lights(spp=4096):
    """The 64 rectangles of scenes/many_lights.xml, two point lights and a rectangle of zero
    radiance over the diffuse floor: (scene dict, expected radiance per point)."""
    rects = [(light_rect(c, (hx, hy)), le) for c, (hx, hy), le in many.lights()]
    # the dark rectangle still occludes: it sits outside the grid just below the lights, where
    # no ray from a light or lamp to a sensor point passes
    rects.append((light_rect((3.0, 3.0, 1.45), (0.2, 0.2)), 0.0))
    return plane_scene(rects, points=LAMPS, sensors_at=POINTS, spp=spp, rho=RHO,
                       view=(0.2, -0.3, 0.4))


def mixed_scene(dark=True):
    """Every kind of emitter the tree handles, plus a dark one (not in spectral variants,
    where a zero spectrum cannot be sampled)."""
    T = mi.ScalarTransform4f
    d = {"type": "scene",
            "floor": {"type": "rectangle", "to_world": T().scale(10)},
            "rect": {"type": "rectangle", "to_world": light_rect((1, 0, 2), (0.3, 0.2)),
                     "emitter": {"type": "area", "radiance": 5.0}},
            "disk": {"type": "disk", "to_world": T().translate([-2, 1, 1]).scale(0.3),
                     "emitter": {"type": "area", "radiance": 2.0}},
            "ball": {"type": "sphere", "center": [0, 3, 1], "radius": 0.2,
                     "emitter": {"type": "area", "radiance": 10.0}},
            "cube": {"type": "cube", "to_world": T().translate([3, -2, 0.5]).scale(0.2),
                     "emitter": {"type": "area", "radiance": 1.0}},
            "dark": {"type": "rectangle", "to_world": light_rect((0, 0, 1), (0.2, 0.2)),
                     "emitter": {"type": "area", "radiance": 0.0}},
            "point": {"type": "point", "position": [-1, -1, 1.5], "intensity": 3.0},
            "spot": {"type": "spot", "intensity": 20.0, "cutoff_angle": 30,
                     "to_world": T().look_at([2, 2, 3], [2, 2, 0], [0, 1, 0])},
            "env": {"type": "constant", "radiance": 0.1}}
    if not dark:
        del d["dark"]
    return d


def _points(n, rng, z=(0.0, 1.0), half=4.0):
    p = np.stack([rng.uniform(-half, half, n), rng.uniform(-half, half, n),
                  rng.uniform(*z, n)], 1)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    return p, nrm


def _si(p, n):
    si = dr.zeros(mi.SurfaceInteraction3f, len(p))
    si.p = mi.Point3f(*[mi.Float(p[:, k].astype(np.float32)) for k in range(3)])
    si.n = mi.Vector3f(*[mi.Float(n[:, k].astype(np.float32)) for k in range(3)])
    si.sh_frame = mi.Frame3f(si.n)
    return si


def pmf_matrix(sel, p, n):
    """p(j | x_i) for every point i and emitter j: (points, emitters)."""
    m = len(p)
    k = sel.count
    pp, nn = np.repeat(p, k, 0), np.repeat(n, k, 0)
    em = dr.gather(mi.EmitterPtr, sel.emitters_dr, mi.UInt32(np.tile(np.arange(k), m)))
    return np.array(sel.pmf_at(_si(pp, nn), em), dtype=np.float64).reshape(m, k)


def _index_of(sel, emitter):
    ids = np.array(dr.reinterpret_array(mi.UInt32, emitter), dtype=np.int64)
    all_ids = np.array(dr.reinterpret_array(mi.UInt32, sel.emitters_dr), dtype=np.int64)
    table = np.full(max(all_ids.max(), ids.max()) + 1, -1)
    table[all_ids] = np.arange(len(all_ids))
    return table[ids]


@pytest.fixture(scope="module")
def plane():
    d, expected = plane_with_lights()
    return mi.load_dict(d), expected


@pytest.fixture(scope="module")
def plane_sel(plane):
    return make(plane[0], "bvh")


@pytest.fixture(scope="module")
def mixed_sel():
    return make(mi.load_dict(mixed_scene()), "bvh")


@pytest.fixture(scope="module")
def plane_ris(plane):
    return make(plane[0], "ris")


@pytest.fixture(scope="module")
def mixed_ris():
    return make(mi.load_dict(mixed_scene()), "ris")


def _sample1(sel, rng, m):
    """A light choice's random numbers for m lanes (2-D for ris)."""
    u = [mi.Float(rng.random(m).astype(np.float32)) for _ in range(sel.SAMPLE_DIMS)]
    return u[0] if sel.SAMPLE_DIMS == 1 else mi.Point2f(*u)


# ---------------------------------------------------------------------------------------------
def _check_tree(tree: lt.Tree, n_lights: int):
    info = tree.info
    leaf = (info & lt.LEAF) != 0
    assert leaf.sum() == n_lights and tree.size == 2 * n_lights - 1
    assert sorted((info[leaf] & ~lt.LEAF).tolist()) == list(range(n_lights))
    inner = np.nonzero(~leaf)[0]
    a = info[inner].astype(np.int64)
    for c in (a, a + 1):
        assert np.all(tree.lo[inner] <= tree.lo[c]) and np.all(tree.hi[inner] >= tree.hi[c])
        # the parent's cone holds the child's: angle(w_p, w_c) + theta_c <= theta_p
        ang = lt._angle_between(tree.w[inner], tree.w[c]) + np.arccos(np.clip(tree.cos_o[c], -1, 1))
        full = tree.cos_o[inner] <= -1 + 1e-9
        assert np.all(full | (ang <= np.arccos(np.clip(tree.cos_o[inner], -1, 1)) + 1e-6))
        assert np.all(tree.cos_e[inner] <= tree.cos_e[c])
    assert np.allclose(tree.phi[inner], tree.phi[a] + tree.phi[a + 1])
    # every light's bit trail leads from the root to its leaf
    for j in range(n_lights):
        node = 0
        for k in range(int(tree.depth[j])):
            node = int(info[node]) + int((int(tree.trail[j]) >> k) & 1)
        assert info[node] == (lt.LEAF | j)
    assert tree.depth.max() <= lt.MAX_DEPTH


@pytest.mark.parametrize("n", [1, 2, 3, 17, 300])
def test_tree_invariants(n):
    rng = np.random.default_rng(n)
    c = rng.uniform(-5, 5, (n, 3))
    half = rng.uniform(0, 0.3, (n, 3))
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    cos_o = np.where(rng.random(n) < 0.3, -1.0, rng.uniform(0.5, 1.0, n))
    tree = lt.build(c - half, c + half, w, cos_o, np.zeros(n), rng.random(n) < 0.2,
                    10 ** rng.uniform(0, 3, n))
    _check_tree(tree, n)


def test_device_record_bounds_the_node():
    """The device record a level reads (:class:`DeviceTree`, 12 words per node): its sphere
    (the float32 weighted centre c, radius r) holds every corner of the node's box, so the
    bound made from it is a bound; its ``info`` is the node's; its cone and power are the
    tree's."""
    n = 300
    rng = np.random.default_rng(7)
    c = rng.uniform(-50, 50, (n, 3))
    half = rng.uniform(0, 2, (n, 3))
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    tree = lt.build(c - half, c + half, w, rng.uniform(-1, 1, n), np.zeros(n),
                    rng.random(n) < 0.2, 10 ** rng.uniform(0, 3, n))
    dev = lt.DeviceTree(tree)
    rec = np.array(dev.packed, np.float32).reshape(tree.size, len(dev.FIELDS))
    centre, r = rec[:, :3].astype(np.float64), rec[:, 3].astype(np.float64)
    for k in range(8):
        corner = np.where(np.array([(k >> a) & 1 for a in range(3)], bool), tree.hi, tree.lo)
        assert np.all(np.linalg.norm(corner - centre, axis=1) <= r)
    assert np.array_equal(rec[:, 10].view(np.uint32), tree.info)
    assert np.allclose(rec[:, 4:7], tree.w, atol=1e-6)
    assert np.allclose(np.abs(rec[:, 9]), tree.phi, rtol=1e-6)
    assert np.array_equal(rec[:, 9] < 0, tree.two)


def test_tree_invariants_same_place():
    """All lights at one point (no valid SAOH split): median splits, still a full tree."""
    n = 40
    tree = lt.build(np.zeros((n, 3)), np.zeros((n, 3)), np.tile([0, 0, 1.0], (n, 1)),
                    -np.ones(n), np.zeros(n), np.zeros(n, bool), np.ones(n))
    _check_tree(tree, n)


def test_cone_union_bounds_both():
    rng = np.random.default_rng(3)
    n = 1000
    wa, wb = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    wa /= np.linalg.norm(wa, axis=1)[:, None]
    wb /= np.linalg.norm(wb, axis=1)[:, None]
    ca, cb = rng.uniform(-0.5, 1, n), rng.uniform(-0.5, 1, n)
    w, c = lt.cone_union(wa, ca, wb, cb)
    t = np.arccos(np.clip(c, -1, 1))
    for wx, cx in ((wa, ca), (wb, cb)):
        need = lt._angle_between(w, wx) + np.arccos(cx)
        assert np.all((c <= -1 + 1e-12) | (need <= t + 1e-6))


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["plane", "mixed"])
def test_pmf_sums_to_one(which, plane_sel, mixed_sel):
    """Where every light can contribute (below the downward-facing rectangles) the pmf over
    all emitters sums to 1."""
    sel = plane_sel if which == "plane" else mixed_sel
    rng = np.random.default_rng(11)
    p, n = _points(200, rng, z=(0.0, 0.9))
    pm = pmf_matrix(sel, p, n)
    assert np.all(pm >= 0)
    assert np.allclose(pm.sum(1), 1.0, atol=2e-5), pm.sum(1)


@pytest.mark.parametrize("which", ["plane", "mixed"])
def test_pmf_sum_is_the_chance_of_a_light(which, plane_sel, mixed_sel):
    """Anywhere, the pmf sums to at most 1; the rest is the chance that traversal meets a node
    whose two children are both bounded by 0 (then no light is chosen, as in pbrt-v4: the
    lights below can send nothing to x, so the estimator loses nothing).  H0: the fraction of
    1,000 draws that return a light at x is sum_j p(j | x); binomial z-test over 40 points,
    |z| < 5 (two-sided 5.7e-7 each)."""
    sel = plane_sel if which == "plane" else mixed_sel
    rng = np.random.default_rng(12)
    p, n = _points(40, rng, z=(0.0, 3.0))
    total = pmf_matrix(sel, p, n).sum(1)
    assert np.all(total <= 1 + 2e-5)
    m = 1000
    _, pmf, _ = sel.choose(_si(np.repeat(p, m, 0), np.repeat(n, m, 0)),
                           mi.Float(rng.random(40 * m).astype(np.float32)))
    hit = (np.array(pmf) > 0).reshape(40, m).mean(1)
    se = np.sqrt(np.maximum(total * (1 - total), 1e-12) / m)
    assert np.all(np.abs(hit - total) <= 5 * se + 1e-6), (hit, total)


@pytest.mark.parametrize("mode", ["bvh", "ris"])
@pytest.mark.parametrize("which", ["plane", "mixed"])
def test_choose_returns_its_pmf(which, mode, plane_sel, mixed_sel, plane_ris, mixed_ris):
    """The probability traversal reports equals pmf_at of the light it chose, bit for bit
    (for ris: the tree's pmf of the light it kept, the density its MIS weights use)."""
    sel = {("plane", "bvh"): plane_sel, ("mixed", "bvh"): mixed_sel,
           ("plane", "ris"): plane_ris, ("mixed", "ris"): mixed_ris}[which, mode]
    rng = np.random.default_rng(5)
    p, n = _points(1 << 14, rng, z=(0.0, 2.5))
    si = _si(p, n)
    em, pmf, _ = sel.choose(si, _sample1(sel, rng, len(p)))
    again = np.array(sel.pmf_at(si, em))
    pmf = np.array(pmf)
    assert np.mean(pmf > 0) > 0.5
    assert np.array_equal(pmf, again)
    assert np.all(np.array(dr.reinterpret_array(mi.UInt32, em))[pmf == 0] == 0)


def test_zero_power_never_chosen(plane_sel, mixed_sel):
    for sel in (plane_sel, mixed_sel):
        dark = [j for j, e in enumerate(sel.emitters) if sel.power[j] == 0]
        assert len(dark) == 1
        rng = np.random.default_rng(2)
        p, n = _points(1 << 16, rng, z=(0.0, 2.5))
        em, _, _ = sel.choose(_si(p, n), mi.Float(rng.random(len(p)).astype(np.float32)))
        assert dark[0] not in set(_index_of(sel, em).tolist())
        assert np.all(pmf_matrix(sel, p[:100], n[:100])[:, dark[0]] == 0)


def test_contributing_light_can_be_chosen(plane_sel):
    """Below the downward-facing rectangles (z < 1.5) every light of nonzero power has
    p > 0, at any normal; well above them (z > 2.5: the bounding spheres of the rectangles
    subtend less than the angle to their plane) the rectangles have p = 0 and only the point
    lights (which shine everywhere) are left."""
    sel = plane_sel
    rng = np.random.default_rng(9)
    lit = sel.power > 0
    p, n = _points(400, rng, z=(0.0, 1.45), half=6.0)
    pm = pmf_matrix(sel, p, n)
    assert np.all(pm[:, lit] > 0)
    p, n = _points(100, rng, z=(2.5, 3.0), half=4.0)
    pm = pmf_matrix(sel, p, n)
    point = np.array([not e.get_shape() for e in sel.emitters])
    assert np.all(pm[:, ~point] == 0) and np.all(pm[:, point & lit] > 0)


@pytest.mark.parametrize("which", ["plane", "mixed"])
def test_traversal_chi2(which, plane_sel, mixed_sel):
    """H0: the index of the light choose() draws at a fixed point has the pmf pmf_at (Pearson
    chi-square over unit cells of the index line, 3 points per scene, family-wise alpha 1e-3
    over the 6)."""
    sel = plane_sel if which == "plane" else mixed_sel
    k = sel.count
    for i, (pt, nrm) in enumerate([((0.4, -0.7, 0.0), (0, 0, 1)), ((2.5, 2.0, 0.3), (1, 0, 0)),
                                   ((-1.0, 0.5, 1.2), (0.6, 0.0, -0.8))]):
        def sample(u, pt=pt, nrm=nrm):
            m = dr.width(u[0])
            si = _si(np.tile(pt, (m, 1)), np.tile(nrm, (m, 1)))
            em, pmf, _ = sel.choose(si, u[0])
            idx = _index_of(sel, em)
            return mi.Point2f(mi.Float((idx + 0.5).astype(np.float32)), 0.0)

        def pdf(x, pt=pt, nrm=nrm):
            j = np.clip(np.floor(np.array(x)).astype(np.int64), 0, k - 1)
            si = _si(np.tile(pt, (len(j), 1)), np.tile(nrm, (len(j), 1)))
            em = dr.gather(mi.EmitterPtr, sel.emitters_dr, mi.UInt32(j))
            return sel.pmf_at(si, em)

        r = chi2_test(sample, pdf, domain=mi.chi2.LineDomain(bounds=[0.0, float(k)]),
                      sample_dim=1, sample_count=1 << 20, res=k, ires=4, seed=i,
                      test_count=6)
        assert r.passed, (which, i, str(r))


# ---------------------------------------------------------------------------------------------
RIS_POINTS = [((0.4, -0.7, 0.0), (0, 0, 1)), ((2.5, 2.0, 0.3), (1, 0, 0)),
              ((-1.0, 0.5, 1.2), (0.6, 0.0, -0.8))]


def _ris_estimates(sel, pt, nrm, g, tree_weight=False, m=1 << 18, seed=0):
    """64 batch means of factor(Y) g_Y over m resampled choices at one point (with
    ``tree_weight`` the negative control: 1 / p(Y) in place of the resampled weight)."""
    rng = np.random.default_rng(seed)
    si = _si(np.tile(pt, (m, 1)), np.tile(nrm, (m, 1)))
    em, pmf, _, divisor = sel.weighted_choice(si, _sample1(sel, rng, m))
    idx = _index_of(sel, em)
    pmf, divisor = np.array(pmf, np.float64), np.array(divisor, np.float64)
    w = np.where(pmf > 0, 1.0 / np.where(pmf > 0, pmf if tree_weight else divisor, 1.0), 0.0)
    x = np.where(pmf > 0, w * g[np.maximum(idx, 0)], 0.0)
    return x.reshape(64, -1).mean(1)[:, None]


@pytest.mark.parametrize("which", ["plane", "mixed"])
def test_ris_weight_unbiased_for_any_values(which, plane_ris, mixed_ris):
    """H0: E[factor(Y) g_Y] = sum of g_j over the lights with p(j | x) > 0, for g = each
    light's power and for random values (the power times an independent uniform factor in
    [0.5, 2] per light, so not proportional to the importance the resampling targets): the
    resampled choice and its weight estimate any sum over the lights without bias.  Negative
    control: with the tree's weight 1 / p(Y) on the resampled choice the same test rejects H0
    at some point (the control must fail; it reaches 40-220 s.e.).

    The random values were lognormal (sigma 1.5) before: that puts a value 90x the median on a
    light the target almost never selects at x, the 2^18 choices then mostly miss it, and the
    sample mean reads low while its s.e. looks small, so the t-test's false-failure rate is not
    its alpha (1 of 36 value assignments failed at alpha 1.5e-5 in a scratch run; a CI run
    failed at -18 %, p 7e-8, with the assignment of values to lights set by the process's
    emitter order).  Bounded factors keep the estimate's tail that of the power test's."""
    from integrators.testing.stats import mean_test
    sel = plane_ris if which == "plane" else mixed_ris
    rng = np.random.default_rng(21)
    values = {"power": np.asarray(sel.power, np.float64),
              "random": np.asarray(sel.power, np.float64) * rng.uniform(0.5, 2.0, sel.count)}
    control = []
    for i, (pt, nrm) in enumerate(RIS_POINTS):
        pm = pmf_matrix(sel, np.array([pt], float), np.array([nrm], float))[0]
        for name, g in values.items():
            truth = float(g[pm > 0].sum())
            r = mean_test(_ris_estimates(sel, pt, nrm, g, seed=i), truth)
            assert r.passed, (which, i, name, str(r))
            c = _ris_estimates(sel, pt, nrm, g, tree_weight=True, seed=i)
            control.append(abs(c.mean() - truth) / (c.std(ddof=1) / 8.0))
    assert max(control) > 10.0, control


def _floor_estimates(scene, sel, pt, m=1 << 19, seed=0, scale=1.0):
    """64 batch means of luminance(f weight) (the unshadowed light-sample estimate of the
    reflected direct light) of ``sel.sample_direction`` at the floor point under ``pt``."""
    from integrators.common import luminance
    rng = np.random.default_rng(seed)
    o = np.tile([pt[0], pt[1], 1.0], (m, 1))
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, k].astype(np.float32)) for k in range(3)]),
                   mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    bsdf, ctx = si.bsdf(ray), mi.BSDFContext()
    s2 = mi.Point2f(*[mi.Float(rng.random(m).astype(np.float32)) for _ in range(2)])
    ds, w, _ = sel.sample_direction(si, _sample1(sel, rng, m), s2, si.is_valid(), bsdf=bsdf,
                                    ctx=ctx)
    f = bsdf.eval(ctx, si, si.to_local(ds.d), si.is_valid())
    x = np.array(luminance(f * w), np.float64) * scale
    return x.reshape(64, -1).mean(1)


def _welch_p(a, b):
    from scipy import stats
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    return 2 * stats.norm.sf(abs(a.mean() - b.mean()) / se)


def test_ris_contribution_target_unbiased(plane):
    """With the BSDF given, ris resamples by each candidate's unshadowed contribution f L_e.
    H0: its light-sample estimate of the unshadowed reflected light at a floor point has the
    mean of bvh's (Welch z on 64 batch means of 2^19 samples each, kit default alpha per point,
    3 points), with a smaller spread.  Sensitivity control: the same test rejects bvh against
    itself scaled by 1.02 (a 2 % bias) at every point."""
    from integrators.testing.stats import DEFAULT_ALPHA, count_check
    scene = plane[0]
    ris, tree = make(scene, "ris"), make(scene, "bvh")
    for i, (pt, _) in enumerate(RIS_POINTS):
        a = _floor_estimates(scene, ris, pt, seed=i)
        b = _floor_estimates(scene, tree, pt, seed=100 + i)
        count_check(DEFAULT_ALPHA)
        assert _welch_p(a, b) > DEFAULT_ALPHA, (i, a.mean(), b.mean())
        assert a.std() < b.std(), (i, a.std(), b.std())      # and it does reduce the noise
        c = _floor_estimates(scene, tree, pt, seed=200 + i, scale=1.02)
        assert _welch_p(c, b) < DEFAULT_ALPHA, (i, c.mean(), b.mean())


@pytest.mark.parametrize("mode", ["bvh", "ris"])
@pytest.mark.parametrize("nee", ["direct_mis", "nee_path", "mis3"])
def test_unbiased_many_lights(plane, nee, mode):
    scene, expected = plane
    d = {"type": nee, "light_selection": mode}
    if nee != "direct_mis":
        d["max_depth"] = 2
    assert_unbiased(scene, expected[1], d, batches=32, spp=8192, sensor=1, max_spp=32768)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["bvh", "ris"])
@pytest.mark.parametrize("nee", ["direct_mis", "nee_path", "mis3"])
def test_unbiased_many_lights_every_point(plane, nee, mode):
    scene, expected = plane
    d = {"type": nee, "light_selection": mode}
    if nee != "direct_mis":
        d["max_depth"] = 2
    assert_unbiased(scene, expected, d, batches=32, spp=16384, sensor=range(len(expected)),
                    max_spp=65536)


@pytest.mark.parametrize("mode,floor", [("bvh", "diffuse"), ("ris", "diffuse"),
                                        ("ris", "glossy")])
def test_unbiased_mixed_against_power(mode, floor):
    """Every kind of emitter (and the environment, chosen outside the tree): bvh (ris) and
    power selection render the same expected image (block-wise Welch t, kit default alpha);
    for ris also over a glossy floor (rough aluminium, alpha 0.15), where its resampling
    target, the unshadowed contribution, depends on the BSDF."""
    d = mixed_scene()
    if floor == "glossy":
        d["floor"]["bsdf"] = {"type": "roughconductor", "material": "Al", "alpha": 0.15}
    d["sensor"] = {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0, -6, 4], [0, 0, 0], [0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}}
    assert_unbiased(d, {"type": "nee_path", "max_depth": 3, "light_selection": "power"},
                    {"type": "nee_path", "max_depth": 3, "light_selection": mode},
                    batches=16, spp=1024, block=8, max_rel_se=0.02)


def test_light_field_scene_renders():
    """The benchmark's generated scene (64 lights, 16x16 pixels): bvh has lower per-pixel
    variance than power, and ris than bvh (H0: median over lit pixels of log(var_a / var_b)
    <= 0, one-sided Wilcoxon signed-rank over them, 8 renders each, rejected at alpha = 1e-4:
    the test asserts both rejections), and the image means agree to 10 % (a smoke check:
    unbiasedness is tested against closed forms above)."""
    from scipy import stats
    scene = mi.load_dict(field.scene_dict(64, res=16, spp=64))
    imgs = {}
    for s in ("power", "bvh", "ris"):
        integ = mi.load_dict({"type": "nee_path", "max_depth": 2, "light_selection": s,
                              "hide_emitters": True})
        imgs[s] = np.stack([np.array(mi.render(scene, integrator=integ, seed=k))[..., 0]
                            for k in range(8)])
    var = {s: v.var(axis=0, ddof=1).ravel().astype(np.float64) for s, v in imgs.items()}
    lit = (var["power"] > 0) & (var["bvh"] > 0) & (var["ris"] > 0)   # the sky is black
    assert lit.sum() > 100
    for a, b in (("power", "bvh"), ("bvh", "ris")):
        ratio = np.log(var[a][lit] / var[b][lit])
        assert stats.wilcoxon(ratio, alternative="greater").pvalue < 1e-4, (a, b, np.median(ratio))
    m = {s: v.mean() for s, v in imgs.items()}
    assert m["bvh"] == pytest.approx(m["power"], rel=0.1)
    assert m["ris"] == pytest.approx(m["power"], rel=0.1)


def test_bad_mode_rejected():
    with pytest.raises(Exception, match="light_selection"):
        mi.load_dict({"type": "nee_path", "light_selection": "bvhh"})
    # light_candidates changes nothing outside ris: refused, not ignored
    for nee in ("direct_mis", "nee_path", "mis3", "bdpt"):
        with pytest.raises(Exception, match="'light_candidates' = 8 is invalid with "
                                            "light_selection='bvh'"):
            mi.load_dict({"type": nee, "light_selection": "bvh", "light_candidates": 8})
    with pytest.raises(Exception, match="'light_candidates' = 0 is invalid; allowed"):
        mi.load_dict({"type": "nee_path", "light_selection": "ris", "light_candidates": 0})
    integ = mi.load_dict({"type": "nee_path", "light_selection": "ris", "light_candidates": 8})
    assert integ.lights.candidates == 8


def test_ris_one_candidate_is_the_tree(plane):
    """light_candidates = 1: the light the tree picks for the same u, weighted 1 / p."""
    scene = plane[0]
    tree, one = make(scene, "bvh"), make(scene, "ris", 1)
    rng = np.random.default_rng(8)
    p, n = _points(1 << 12, rng, z=(0.0, 1.4))
    si = _si(p, n)
    u = rng.random(len(p)).astype(np.float32)
    em_t, pmf_t, _ = tree.choose(si, mi.Float(u))
    em_r, pmf_r, _, div = one.weighted_choice(si, mi.Point2f(mi.Float(u), 0.5))
    assert np.array_equal(_index_of(tree, em_t), _index_of(one, em_r))
    assert np.array_equal(np.array(pmf_t), np.array(pmf_r))
    assert np.allclose(np.array(div), np.array(pmf_t), rtol=1e-5, atol=0)


# ---------------------------------------------------------------------------------------------
def test_scalar_variant():
    integrators.set_variant("scalar_rgb")
    try:
        scene = mi.load_dict(mixed_scene())
        sel = make(scene, "bvh")
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p, si.n = mi.Point3f(0.3, 0.2, 0.5), mi.Vector3f(0, 0, 1)
        total = sum(float(sel.pmf_at(si, e)) for e in sel.emitters)
        assert total == pytest.approx(1.0, abs=1e-5)
        e, p, _ = sel.choose(si, 0.77)
        assert p > 0 and p == sel.pmf_at(si, e)
        d, expected = plane_scene(points=[((0.3, -0.2, 1.0), 2.0)], sensors_at=[(0.7, 0.3, 0.0)])
        for mode in ("bvh", "ris"):
            assert_unbiased(d, expected, {"type": "direct_mis", "light_selection": mode},
                            sensor=range(1), batches=8, spp=256, max_rel_se=0.05)
    finally:
        integrators.set_variant("llvm_ad_rgb")


def test_spectral_variant():
    if "llvm_ad_spectral" not in mi.variants():
        pytest.skip("llvm_ad_spectral not built")
    integrators.set_variant("llvm_ad_spectral")
    try:
        scene = mi.load_dict(mixed_scene(dark=False))
        sel = make(scene, "bvh")
        rng = np.random.default_rng(1)
        p, n = _points(20, rng, z=(0.0, 2.0))
        assert np.allclose(pmf_matrix(sel, p, n).sum(1), 1.0, atol=2e-5)
        d = mixed_scene(dark=False)
        d["sensor"] = {"type": "perspective", "film": {"type": "hdrfilm", "width": 8,
                                                       "height": 8}}
        for mode in ("bvh", "ris"):
            img = mi.render(mi.load_dict(d), integrator=mi.load_dict(
                {"type": "nee_path", "light_selection": mode}), spp=4)
            assert np.all(np.isfinite(np.array(img))) and np.array(img).mean() > 0, mode
    finally:
        integrators.set_variant("llvm_ad_rgb")


def test_split_cost_keeps_tree_shallow():
    """The SAOH split cost (buckets swept from both sides) keeps a tree over lights spread
    evenly through a cube near balanced: mean leaf depth at most log2(N) + 1.5 for 4,096
    lights, with random orientations and with one shared cone.  Deterministic; measured
    12.26 and 12.13 against the bound 13.5 (a cost that leaves out the right side: 25)."""
    n = 4096
    rng = np.random.default_rng(1)
    c = rng.uniform(-10, 10, (n, 3))
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    phi = 10 ** rng.uniform(0, 3, n)
    for axes in (w, np.tile([0.0, 0.0, 1.0], (n, 1))):
        tree = lt.build(c - 0.05, c + 0.05, axes, np.ones(n), np.zeros(n), np.zeros(n, bool), phi)
        assert tree.depth.mean() <= np.log2(n) + 1.5, tree.depth.mean()


def test_selection_quality_light_field():
    """On 1,024 sphere lights (scenes/tools/make_light_field.py) the tree's choice is close to
    the ideal one (p proportional to each light's unshadowed irradiance, exact for a sphere
    above the horizon: pi L (r/d)^2 cos): the second moment sum_j f_j^2 / p_j / (sum_j f_j)^2
    (1 for the ideal, the variance factor of the light choice) at 100 fixed floor points.
    Deterministic (fixed points, no sampling): measured median 1.48 for bvh (1.46 with the
    16-word device record's box-centred sphere), 27.9 for power."""
    n = 1024
    scene = mi.load_dict(field.scene_dict(n, res=4, spp=1))
    sel = make(scene, "bvh")
    centre = np.array([np.array(e.get_shape().bbox().center(), float).ravel()
                       for e in sel.emitters])
    radius = np.array([0.5 * float(np.array(e.get_shape().bbox().extents(), float).ravel()[0])
                       for e in sel.emitters])
    le = np.pi * sel.power / (4 * np.pi * np.pi * radius ** 2)   # power = pi L 4 pi r^2
    rng = np.random.default_rng(0)
    p = np.stack([rng.uniform(-15, 15, 100), rng.uniform(-14, 18, 100), np.zeros(100)], 1)
    nrm = np.tile([0.0, 0.0, 1.0], (100, 1))
    d = centre[None] - p[:, None]
    d2 = (d ** 2).sum(-1)
    f = np.pi * le[None] * radius[None] ** 2 / d2 * d[..., 2] / np.sqrt(d2)
    second = lambda pm: (f ** 2 / np.maximum(pm, 1e-30)).sum(1) / f.sum(1) ** 2   # noqa: E731
    tree = np.median(second(pmf_matrix(sel, p, nrm)))
    power = np.median(second(np.broadcast_to(sel.pmf_np, f.shape)))
    assert tree < 2.0 and power > 10 * tree, (tree, power)
