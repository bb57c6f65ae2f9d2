"""pssmlt (issue 18): Metropolis sampling in primary sample space.

Statistical tests, each with its null hypothesis and level (the kit's ``count_check`` counts
them into the end-of-run false-failure bound):

* detailed balance on a toy integrand with a known answer: chains started uniformly and run
  with large steps, and with small steps alone, are distributed as the target (chi-square on
  the chains' bins, H0: the chain states follow the target, alpha 1e-4 each);
* the bootstrap estimate b is unbiased (H0: E[b] = the image's mean luminance by Mitsuba's
  ``path``; Welch t, alpha DEFAULT_ALPHA);
* the image mean and block means equal Mitsuba's ``path`` (Cornell box and a lamp in a glass
  shade): independent renders (fresh seeds, ``continue_chains`` off) against independent
  ``path`` renders, block-wise Welch t with Sidak (the kit's ``image_test``), and a power guard
  (the relative standard error small enough to see the bias named in the test).  The default
  suite sees a 5 % bias (guard 0.75 %); the slow tests see 1 % (guard 0.25 %: a 1 % bias gives
  |t| >= 4) and compare 4x4 blocks at high mutation counts.  A test of blocks also catches
  start-up bias: chains that start away from the target (too few mutations to forget it)
  give dim regions too much weight and bright ones too little.

Deterministic checks: a chain's stored state is what its stored primary vector evaluates to;
passes with consecutive seeds continue the chains (and other seeds start afresh); parameters,
defaults, and the bdpt estimator's refusals (what bdpt refuses).
"""
from __future__ import annotations

import gc
from pathlib import Path

import numpy as np
import pytest

import integrators  # noqa: F401  (variant + plugins)
import drjit as dr
import mitsuba as mi
from scipy import stats

from integrators.plugins import pssmlt as P
from integrators.plugins.base import SceneError
from integrators.sampling import primary_sample as ps
from integrators.testing.stats import DEFAULT_ALPHA, count_check, image_test

CHI2_ALPHA = 1e-4
SCENES = Path(__file__).resolve().parents[1] / "scenes"


# ---- scenes -------------------------------------------------------------------------------
def cornell(res=16, max_depth=5):
    d = mi.cornell_box()
    film = d["sensor"]["film"]
    film.update(width=res, height=res, pixel_format="rgb", rfilter={"type": "box"})
    d["integrator"] = {"type": "path", "max_depth": max_depth}
    return mi.load_dict(d)


def glass_shade(res=16):
    return mi.load_file(str(SCENES / "pssmlt_glass_shade.xml"), res=res, max_depth=5,
                        integrator="path")


def pssmlt(**kw):
    return mi.load_dict({"type": "pssmlt", "max_depth": 5, "chains": 4096, "bootstrap": 16384,
                         "continue_chains": False, "estimator": "path", **kw})


def renders(scene, integ, n, spp, seed0):
    """n independent renders (seeds far apart, so no render continues another's chains)."""
    return np.array([np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed0 + 97 * k))
                     for k in range(n)], dtype=np.float64)


# ---- the toy integrand: a 4 x 4 table of weights on [0, 1)^2 ------------------------------
TOY = np.array([[1.0, 2.0, 0.5, 4.0],
                [8.0, 1.0, 3.0, 0.7],
                [2.5, 6.0, 1.0, 1.5],
                [0.6, 1.2, 5.0, 2.0]])


def toy_evaluate(sampler):
    """(bin, rgb, I) of the toy: I = TOY[bin(y), bin(x)] (luminance weights sum to 1)."""
    x, y = sampler.next_1d(), sampler.next_1d()
    n = TOY.shape[0]
    bx = dr.minimum(mi.UInt32(x * n), n - 1)
    by = dr.minimum(mi.UInt32(y * n), n - 1)
    b = by * n + bx
    f = dr.gather(mi.Float, mi.Float(TOY.ravel()), b)
    return b, mi.Color3f(f, f, f), f


@pytest.mark.parametrize("large_step,sigma", [(0.3, 1 / 64), (0.0, 0.25)],
                         ids=["large+small", "small-only"])
def test_chains_reach_the_target(large_step, sigma):
    """H0: after burn-in, the states of independent chains started *uniformly* (not from the
    bootstrap) are distributed as the target I / int I (chi-square over the 16 bins, alpha
    1e-4).  Detailed balance of the proposal (symmetric small steps, independence large steps)
    and the acceptance min(1, I'/I) make the target stationary; a wrong acceptance or an
    asymmetric perturbation moves the chains elsewhere."""
    chains, steps = 20000, 250
    st = P.start(toy_evaluate, 2, chains, chains, seed=7 + int(large_step * 10),
                 resample=False, extra=False)
    image = dr.zeros(mi.Float, TOY.size * 3)
    P.run(toy_evaluate, st, chains * steps, image, dr.opaque(mi.Float, 1.0), large_step, sigma)
    counts = np.bincount(np.array(st.pix), minlength=TOY.size)
    expected = chains * TOY.ravel() / TOY.sum()
    count_check(CHI2_ALPHA, "chi2")
    chi2, p = stats.chisquare(counts, expected)
    assert p >= CHI2_ALPHA, (f"H0 (chain states follow the target) rejected: chi2 {chi2:.1f}, "
                             f"p {p:.3g} < {CHI2_ALPHA}; counts {counts.tolist()} expected "
                             f"{np.round(expected).astype(int).tolist()}")
    # the expected-value splats estimate the integral of each bin (b = the toy's mean)
    h = np.array(image).reshape(-1, 3)[:, 0] / (chains * steps) * TOY.mean() * TOY.size
    assert np.allclose(h, TOY.ravel(), rtol=0.1), (h.round(2), TOY.ravel())


def test_kelemen_offset_is_symmetric():
    """The small step's offset density is even (the proposal is symmetric): the offsets of a
    fine grid of uniforms come in +- pairs, between sigma/16 and sigma."""
    r = mi.Float((np.arange(4096) + 0.5) / 4096)
    off = np.array(ps.kelemen_offset(r, 0.25))
    assert np.allclose(np.sort(off[off > 0]), np.sort(-off[off < 0]), rtol=1e-5)
    assert np.all(np.abs(off) <= 0.25 + 1e-7) and np.all(np.abs(off) >= 0.25 / 16 - 1e-7)


def _stored_and_reevaluated(integ, spp):
    """Render a 16x16 Cornell box, then evaluate every chain's stored primary vector again:
    (chain state, (pixel, rgb, I) of the re-evaluation)."""
    scene = cornell(16)
    mi.render(scene, integrator=integ, spp=spp, seed=3)
    st = integ.state
    assert st.mutations == spp * 16 * 16
    smp = ps.primary_sampler(st.u, st.dims, dr.arange(mi.UInt32, st.chains), mi.UInt32(1),
                             None, 0.0, st.extra)
    return st, integ.estimate(scene, scene.sensors()[0], integ.prepare(scene), smp)


def test_chain_state_is_what_its_vector_evaluates_to():
    """Each chain's stored contribution, importance and pixel are those its stored primary
    vector gives when evaluated again (so the accept step stored the very proposal that was
    evaluated, coordinate for coordinate)."""
    st, (pix, rgb, lum) = _stored_and_reevaluated(pssmlt(), 32)
    np.testing.assert_array_equal(np.array(pix), np.array(st.pix))
    np.testing.assert_allclose(np.array(lum), np.array(st.lum), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.array(rgb), np.array(st.rgb), rtol=1e-5, atol=1e-7)


def test_chain_state_is_what_its_vector_evaluates_to_bdpt():
    """As above for estimator bdpt, whose paths are several splats (the camera sample and
    each light vertex's connection to the camera) read from two streams of the vector."""
    st, (pix, rgb, lum) = _stored_and_reevaluated(pssmlt(estimator="bdpt", chains=2048), 16)
    assert isinstance(st.pix, list) and len(st.pix) == 1 + (5 - 1)
    np.testing.assert_allclose(np.array(lum), np.array(st.lum), rtol=1e-4, atol=1e-6)
    some = 0
    for j in range(len(pix)):
        ok = np.array(dr.any(rgb[j] != 0))
        some += ok.sum()
        np.testing.assert_array_equal(np.array(pix[j])[ok], np.array(st.pix[j])[ok])
        np.testing.assert_allclose(np.array(rgb[j]), np.array(st.rgb[j]), rtol=1e-4,
                                   atol=1e-6)
    assert some > st.chains          # light tracing splats too, not the camera sample alone


def test_bdpt_subpaths_read_disjoint_coordinates():
    """The camera and the light subpath of the bdpt estimator read disjoint coordinates of a
    primary vector, together all of them (correlated subpaths would bias bdpt's weights,
    which assume independent subpaths; too little for the image tests to see)."""
    integ = pssmlt(estimator="bdpt")
    dims = integ.dims
    u = mi.Float(np.arange(2 * dims, dtype=np.float32) % dims / dims)
    cam, light = integ.streams(ps.primary_sampler(u, dims, dr.arange(mi.UInt32, 2), 1,
                                                  extra=True))
    read_c = [round(float(cam.next_1d()[0]) * dims) for _ in range(integ.dims_cam)]
    read_l = [round(float(light.next_1d()[0]) * dims) for _ in range(integ.dims_light)]
    assert not set(read_c) & set(read_l)
    assert sorted(read_c + read_l) == list(range(dims))


@pytest.mark.parametrize("estimator,batches,seed,relative",
                         [("path", 40, 1000, False), ("bdpt", 24, 2000, False),
                          ("path", 40, 3000, True)])
def test_bootstrap_b_is_unbiased(estimator, batches, seed, relative):
    """H0: E[b] = the mean luminance of Mitsuba's path image (Welch t on ``batches``
    bootstrap estimates of 65,536 paths each against 10 path renders, alpha DEFAULT_ALPHA);
    power guard: relative standard error below 1 % (a 5 % bias gives |t| >= 5).  With the
    bdpt estimator, I is the sum of every splat's luminance over a path.  ``relative``: I is
    the luminance over a fixed random per-pixel g (importance=relative with a given pilot),
    so E[b] = the mean over pixels of path's luminance / g."""
    scene = cornell(16)
    integ = pssmlt(estimator=estimator, separate_emission=False)
    sensor = scene.sensors()[0]
    sel = integ.prepare(scene)
    g = np.random.default_rng(seed).uniform(0.5, 2.0, 16 * 16).astype(np.float32)
    if relative:
        integ.pilot = mi.Float(g)

    def ev(s):
        return integ.estimate(scene, sensor, sel, s)
    b = np.array([P.start(ev, integ.dims, 256, 65536, seed=seed + k, extra=integ.extra).b
                  for k in range(batches)])
    ref = renders(scene, mi.load_dict({"type": "path", "max_depth": 5}), 10, 1024, seed // 20)
    lum = ref @ np.array([0.212671, 0.715160, 0.072169])
    if relative:
        lum = lum / g.reshape(16, 16)
    y = lum.mean(axis=(1, 2))
    count_check(DEFAULT_ALPHA)
    t, p = stats.ttest_ind(b, y, equal_var=False)
    se = np.sqrt(b.var(ddof=1) / b.size + y.var(ddof=1) / y.size) / y.mean()
    assert se < 0.01, f"too noisy to test: relative s.e. {se:.4f}"
    assert p >= DEFAULT_ALPHA, (f"H0 (E[b] = path's mean luminance) rejected: b {b.mean():.5f} "
                                f"vs {y.mean():.5f}, t {t:.2f}, p {p:.3g}")


def _compare(scene, n, spp, ref_n, ref_spp, block, guard, max_depth=5, **kw):
    ours = renders(scene, pssmlt(max_depth=max_depth, **kw), n, spp, 11)
    ref = renders(scene, mi.load_dict({"type": "path", "max_depth": max_depth}), ref_n,
                  ref_spp, 100003)
    r = image_test(ours, ref, block=block)
    assert r.passed, f"H0 ({r.h0}) rejected: {r}"
    assert r.rel_se < guard, f"too noisy to see the bias: {r}"
    return r


@pytest.mark.parametrize("estimator", ["path", "bdpt"])
@pytest.mark.parametrize("which", ["cornell", "glass_shade"])
def test_image_mean_matches_path(which, estimator):
    """H0: pssmlt's expected image mean (per channel) is path's: one block over the whole
    16x16 image, Welch t, Sidak over channels, alpha DEFAULT_ALPHA; power guard 0.75 % (a 5 %
    bias gives |t| >= 6.7, the critical value is about 4.9).  The noise of the mean is the
    noise of b, heavy-tailed in the glass shade (the lamp is found through glass only)."""
    if which == "cornell":
        _compare(cornell(16), 32, 64, 24, 2048, 16, 0.0075, bootstrap=65536,
                 estimator=estimator)
    else:   # (bdpt: the lamp seen through the shade is rendered apart, by camera rays whose
        # noise adds to the mean's: more renders for the same power)
        _compare(glass_shade(16), 32 if estimator == "path" else 48, 64, 24, 2048, 16, 0.0075,
                 bootstrap=131072, estimator=estimator)


@pytest.mark.parametrize("estimator", ["path", "bdpt"])
@pytest.mark.parametrize("selection", ["bvh", "ris"])
def test_light_selection_of_many_lights_matches_path(selection, estimator):
    """The lights chosen by the light tree (``bvh``) or by resampling its candidates (``ris``,
    two numbers per choice, so the primary vector's layout grows by one per vertex) on 64
    sphere lights of powers over three decades, the lights hidden from the camera (their
    directly seen emission is rendered apart, by camera rays, and its noise would hide the
    chains').  H0 as test_image_mean_matches_path (one block over the 16x16 image, Welch t,
    Sidak over channels, alpha DEFAULT_ALPHA; power guard 0.75 %: a 5 % bias gives
    |t| >= 6.7, the critical value is about 4.9)."""
    scene = mi.load_file(str(SCENES / "light_field_64.xml"), res=16)
    ours = renders(scene, pssmlt(max_depth=3, bootstrap=65536, estimator=estimator,
                                 light_selection=selection, hide_emitters=True), 16, 64, 11)
    ref = renders(scene, mi.load_dict({"type": "path", "max_depth": 3, "hide_emitters": True}),
                  32, 1024, 100003)
    r = image_test(ours, ref, block=16)
    assert r.passed, f"H0 ({r.h0}) rejected: {r}"
    assert r.rel_se < 0.0075, f"too noisy to see the bias: {r}"


@pytest.mark.parametrize("which", ["cornell", "glass_shade"])
def test_default_estimator_at_unbounded_depth_matches_path(which):
    """max_depth -1 and estimator auto (the defaults): the chains drive bdpt, whose paths past
    its bidir_depth are path-traced without a bound.  H0 as test_image_mean_matches_path,
    against path at max_depth -1 (the same power guard)."""
    if which == "cornell":
        _compare(cornell(16), 32, 64, 24, 2048, 16, 0.0075, max_depth=-1, bootstrap=65536,
                 estimator="auto")
    else:
        _compare(glass_shade(16), 48, 64, 24, 2048, 16, 0.0075, max_depth=-1,
                 bootstrap=131072, estimator="auto")


@pytest.mark.parametrize("estimator,importance,cap",
                         [("path", "relative", None), ("bdpt", "relative", None),
                          ("path", "luminance", None), ("path", "luminance", 2.0),
                          ("bdpt", "luminance", None)])
def test_blocks_match_path_small_image(estimator, importance, cap):
    """H0: the same expected image as path per 2x2 block of an 8x8 image (Welch t per block
    and channel, Sidak, alpha DEFAULT_ALPHA): the film position of a path is its own pixel,
    and (bdpt) a light vertex's splat the pixel it projects to; with either importance
    (relative and Kelemen's luminance) and with a cap on I (bdpt's default 8, and 2 with
    the path estimator: most directly lit paths are then capped).  Power guard: median
    relative s.e. of a block below 3 %."""
    kw = {} if cap is None else {"importance_cap": cap}
    _compare(cornell(8), 24, 512, 12, 2048, 2, 0.03, estimator=estimator,
             importance=importance, **kw)


def test_pilot_scale():
    """importance=relative's pilot (P.pilot_scale): block means of the bootstrap's
    luminance per pixel, floored at PILOT_FLOOR x the image mean; ones for a black image."""
    w, h, n = 8, 4, 64 * 32
    pix = mi.UInt32(np.arange(n, dtype=np.uint32) % (w * h))
    lum_px = np.where(np.arange(w * h) < w * h // 2, 1.0, 0.0)     # top half lit
    rgb = mi.Color3f(*[mi.Float(np.tile(lum_px, n // (w * h)).astype(np.float32))] * 3)
    g = P.pilot_scale(pix, rgb, w, h, n)
    side = int(np.ceil(np.sqrt(P.PILOT_SAMPLES * w * h / n)))
    assert side == 4
    # the image (w h / n per splat: mean 1 on the lit half), in 4x4 blocks, floored at 0.1 x 0.5
    img = lum_px * (w * h / n) * (n // (w * h))
    blocks = img.reshape(h, w).reshape(1, 4, 2, 4).mean(axis=(1, 3))
    expected = np.sqrt(np.repeat(np.repeat(blocks, 4, 0), 4, 1).ravel() ** 2
                       + (P.PILOT_FLOOR * img.mean()) ** 2)
    np.testing.assert_allclose(g, expected, rtol=1e-6)
    assert np.all(g > 0)
    np.testing.assert_array_equal(P.pilot_scale(pix, dr.zeros(mi.Color3f, n), w, h, n),
                                  np.ones(w * h))


@pytest.mark.slow
@pytest.mark.parametrize("which", ["cornell", "glass_shade"])
def test_image_mean_matches_path_within_1_percent(which):
    """As test_image_mean_matches_path with the power to see a 1 % bias (guard 0.25 %).  The
    glass shade's mean is as noisy as its b (heavy-tailed: the lamp is found through glass
    only), hence its larger bootstrap."""
    if which == "cornell":
        _compare(cornell(16), 200, 128, 64, 4096, 16, 0.0025, bootstrap=65536)
    else:
        _compare(glass_shade(16), 160, 64, 64, 4096, 16, 0.0025, bootstrap=524288)


@pytest.mark.slow
def test_blocks_match_path_high_mutation_counts():
    """H0: the same expected image as path per 4x4 block of a 32x32 Cornell box at 1024
    mutations per pixel (Welch t per block and channel, Sidak, alpha DEFAULT_ALPHA); guard:
    median relative s.e. of a block below 2 %."""
    _compare(cornell(32), 24, 1024, 12, 4096, 4, 0.02)


# ---- passes, parameters, formats --------------------------------------------------------------
def test_passes_continue_the_chains():
    """render's passes (seeds s, s+1, ...) continue one run's chains: one bootstrap, the
    mutations of every pass counted; a render with an unrelated seed starts afresh; the run
    record lists continue_chains."""
    from integrators.app.record import RunRecord, integrator_description
    scene = cornell(8)
    integ = pssmlt(continue_chains=True)
    imgs = [np.array(mi.render(scene, integrator=integ, spp=8, seed=s)) for s in (5, 6, 7)]
    s = integ.stats()
    assert s["seed_first"] == 5 and s["seed_last"] == 7
    assert s["mutations"] == 3 * 8 * 64
    assert all(np.all(np.isfinite(i)) for i in imgs)
    mi.render(scene, integrator=integ, spp=8, seed=100)
    assert integ.stats()["seed_first"] == 100 and integ.stats()["mutations"] == 8 * 64
    name, params = integrator_description(integ)
    assert name == "pssmlt" and params["continue_chains"] is True
    assert isinstance(RunRecord(integrator=name, params=params).to_json(), str)


def test_progressive_render_uses_one_run():
    """integrators.app.progressive.render (the render CLI's loop) with spp: its passes are
    one run of the chains, spp x W x H mutations in all."""
    from integrators.app import progressive
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=8, height=8, pixel_format="rgb", rfilter={"type": "box"})
    d["integrator"] = {"type": "pssmlt", "max_depth": 5, "chains": 1024, "bootstrap": 4096,
                       "estimator": "path"}
    scene = mi.load_dict(d)
    acc = progressive.render(scene, spp=64, seed=3)
    s = scene.integrator().stats()
    assert acc.passes > 1 and s["seed_first"] == 3 and s["seed_last"] == 3 + acc.passes - 1
    assert s["mutations"] == 64 * 64
    assert np.all(np.isfinite(acc.mean())) and acc.mean().mean() > 0


def test_defaults_render():
    """<integrator type="pssmlt"/> renders with every default (a luminance film too)."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=8, height=8, pixel_format="luminance")
    d["integrator"] = {"type": "pssmlt"}
    scene = mi.load_dict(d)
    img = np.array(mi.render(scene, spp=4))
    assert img.shape == (8, 8, 1) and np.all(np.isfinite(img)) and img.mean() > 0


def test_auto_estimator_is_bdpt_where_depth_and_scene_allow_it():
    """estimator=auto (the default): bdpt, with its chains and cap, on a scene bdpt renders
    (max_depth finite or -1); path for a scene bdpt refuses (a directional light), with the
    reason in the run notes; the chosen estimator's defaults follow it."""
    def scene_with(integ, sun=False):
        d = mi.cornell_box()
        d["sensor"]["film"].update(width=8, height=8, pixel_format="rgb")
        if sun:
            d["sun"] = {"type": "directional", "direction": [0, -1, 0]}
        d["integrator"] = integ
        return mi.load_dict(d)
    cases = [({"max_depth": 5}, False, "bdpt", "allows bdpt"),
             ({}, False, "bdpt", "allows bdpt"),
             ({"max_depth": 5}, True, "path", "infinite, delta direction")]
    for params, sun, expected, why in cases:
        scene = scene_with({"type": "pssmlt", "bootstrap": 4096, **params}, sun)
        img = np.array(mi.render(scene, spp=2))
        integ = scene.integrator()
        notes = integ.run_notes()
        assert notes["estimator"] == expected and why in notes["estimator_auto"], notes
        assert np.all(np.isfinite(img)) and img.mean() > 0
        stats = integ.stats()
        assert stats["chains"] == (P.BDPT_CHAINS if expected == "bdpt" else P.PATH_CHAINS)
        assert notes["chains"] == stats["chains"]            # what the run record shows
        assert notes["importance_cap"] == integ.importance_cap
        assert integ.params["chains"] == P.PATH_CHAINS        # params: what was asked for
        assert integ.importance_cap == (P.BDPT_IMPORTANCE_CAP if expected == "bdpt" else 0)
        assert notes["large_step"] == integ.large_step == (
            P.BDPT_LARGE_STEP if expected == "bdpt" else P.PATH_LARGE_STEP)
        del scene, integ
    gc.collect()
    # an explicit estimator is kept as given (no notes on a choice)
    integ = pssmlt()
    assert integ.run_notes() == {"estimator": "path", "chains": 4096, "importance_cap": 0.0,
                                 "large_step": P.PATH_LARGE_STEP}


def test_bdpt_estimator_refuses_what_bdpt_refuses_in_one_line():
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=8, height=8)
    d["sun"] = {"type": "directional", "direction": [0, -1, 0]}
    d["integrator"] = {"type": "pssmlt", "estimator": "bdpt", "max_depth": 5}
    scene = mi.load_dict(d)
    with pytest.raises(Exception) as e:
        mi.render(scene, spp=1)
    err = e.value
    while err is not None and not isinstance(err, SceneError):   # mi.render wraps it
        err = err.__cause__ or err.__context__
    msg, ok = str(e.value), err is not None and "\n" not in str(err) and "infinite" in str(err)
    # the traceback's frames hold the scene in a reference cycle: free it now (a scene freed
    # by the cyclic collector while a later test records its kernels aborts)
    del e, err, scene
    gc.collect()
    assert ok, msg


def test_bdpt_estimator_renders_with_its_defaults():
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=8, height=8, pixel_format="rgb")
    d["integrator"] = {"type": "pssmlt", "estimator": "bdpt", "max_depth": 6}
    scene = mi.load_dict(d)
    img = np.array(mi.render(scene, spp=4))
    assert img.shape == (8, 8, 3) and np.all(np.isfinite(img)) and img.mean() > 0
    assert scene.integrator().stats()["chains"] == P.BDPT_CHAINS


@pytest.mark.parametrize("estimator", ["path", "bdpt"])
def test_relative_importance_is_luminance_over_g(estimator):
    """importance=relative: a path's I is the sum over its splats of luminance / g at the
    splat's own pixel (g a given pilot), so that the mutations spread for a relative error."""
    scene = cornell(8)
    integ = pssmlt(estimator=estimator)
    sel = integ.prepare(scene)
    g = np.random.default_rng(5).uniform(0.5, 2.0, 64).astype(np.float32)
    integ.pilot = mi.Float(g)
    smp = ps.primary_sampler(None, integ.dims, dr.arange(mi.UInt32, 4096), mi.UInt32(3),
                             extra=integ.extra)
    pix, rgb, lum = integ.estimate(scene, scene.sensors()[0], sel, smp)
    pix, rgb = (pix, rgb) if isinstance(pix, list) else ([pix], [rgb])
    expected = sum(np.array(P.importance(r_k)) / g[np.array(p_k)] for p_k, r_k in zip(pix, rgb))
    assert np.count_nonzero(expected) > 100
    np.testing.assert_allclose(np.array(lum), expected, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("estimator", ["path", "bdpt"])
def test_passes_reuse_the_compiled_kernels(estimator):
    """Passes that continue the chains compile nothing new: each pass's partial step starts at
    another chain (192 mutations per pass over 1024 chains: offsets 0, 192, 384, ...) and b
    changes with every pass's large steps, and neither may be a literal in a kernel (a
    literal offset recompiled the whole step, about 1.3 s a pass with the bdpt estimator on
    a 64 x 64 glass shade: most of a short render's budget)."""
    scene = cornell(8)
    integ = mi.load_dict({"type": "pssmlt", "max_depth": 5, "chains": 1024, "bootstrap": 4096,
                          "estimator": estimator})
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        seen, new = set(), []
        for s in range(5):
            mi.render(scene, integrator=integ, spp=3, seed=s)
            hashes = {e["hash"] for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT}
            new.append(len(hashes - seen))
            seen |= hashes
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert integ.stats()["mutations"] == 5 * 3 * 64
    assert new[0] > 0 and new[2:] == [0, 0, 0], new


def test_importance_cap():
    """importance_cap: 8 by default with the bdpt estimator, none with path, a given value
    kept; the bootstrap sets the cap to that multiple of its mean I and caps its own I (so b
    is the mean of the capped I), and every chain's I stays at most the cap."""
    assert pssmlt(estimator="bdpt").importance_cap == P.BDPT_IMPORTANCE_CAP
    assert pssmlt().importance_cap == 0.0
    assert pssmlt(estimator="bdpt", importance_cap=3.0).importance_cap == 3.0
    integ = pssmlt(importance_cap=2.0)
    lum = np.random.default_rng(2).exponential(1.0, 4096).astype(np.float32) ** 3
    out = np.array(integ.retarget(8, 8)(None, None, lum.size, mi.Float(lum)))
    cap = 2.0 * lum.astype(np.float64).mean()
    assert float(integ.cap[0]) == pytest.approx(cap, rel=1e-5)
    assert (lum > cap).sum() > 100
    np.testing.assert_allclose(out, np.minimum(lum, cap), rtol=1e-6)
    scene = cornell(8)
    mi.render(scene, integrator=integ, spp=16, seed=1)
    chains = np.array(integ.state.lum)
    assert integ.stats()["importance_cap"] == 2.0
    assert chains.max() <= float(integ.cap[0]) * (1 + 1e-6)
    assert (chains == chains.max()).sum() > 10     # the cap bites on the Cornell box
