r"""Statistical and deterministic tests of the ``phong`` BSDF (``integrators/phong.py``).

Model under test (local shading frame, n = +z, r = mirror direction of wi = (-wi.x, -wi.y, wi.z),
cos(alpha) = <r, wo>, e = exponent):

    f(wi, wo) = rho_d / pi + rho_g (e + 2) / (2 pi) max(cos(alpha), 0)^e        (one-sided)
    pdf_d(wo) = cos(theta_o) / pi,  pdf_g(wo) = (e + 1) / (2 pi) max(cos(alpha), 0)^e  (wo.z > 0)
    pdf       = (1 - P) pdf_d + P pdf_g,  P = mean(rho_g) / (mean(rho_d) + mean(rho_g))

What is tested
--------------
1. Pearson chi^2 goodness of fit of ``sample()`` against ``pdf()`` (``mi.chi2.ChiSquareTest`` on
   the sphere), for the diffuse lobe (ctx.component = 0), the glossy lobe (component = 1), the
   mixture, lobe selection by ``type_mask`` and an RGB (channel-mean) mixture; exponents 1, 20,
   300 and incident angles 0, 30, 60, 80 degrees.
   Null hypothesis H0 of each chi^2 test: the directions returned by ``sample()`` (those with a
   non-zero weight) are distributed with the density ``pdf()`` (integrated over the histogram
   cells).  Each test runs at the Sidak-corrected level 1 - (1 - 0.01)^(1/N_CHI2), N_CHI2 = the
   number of chi^2 tests in this file (positive tests + negative controls), and every test uses
   its own random seed, so the tests are independent: if the implementation is correct, the
   probability that *any* chi^2 test fails is <= 1 % (up to the chi^2 approximation of Mitsuba's
   pooled test and the trapezoid integration error of the tabulated pdf).
2. Negative controls: the same sampler checked against deliberately wrong pdfs (exponent e + 1,
   pdf scaled by (e+1)/(e+2), wrong lobe-selection probability, a 5 % exponent error on the
   sharpest lobe) must be *rejected* at the same corrected level -- proof that the chi^2 tests
   above have power and are not vacuous.
3. eval/pdf/sample equal the closed-form formulas (float64 reference, relative tolerance 1e-4).
4. Albedo (mean sample weight, 2^20 samples per incident angle, angles 0..89 degrees) for
   rho_d + rho_g = 1 never exceeds 1, agrees with a quadrature reference, and at normal incidence
   the glossy albedo equals rho_g exactly (see the individual tests for H0 and levels; each of
   these families has a false-failure rate <= 1 %).
5. Lobe selection via BSDFContext.component / type_mask and ``flags(i)``.
6. Parameter validation errors (reflectance sum > 1, negative exponent, unknown name, negative
   reflectance in every variant).
7. scalar_rgb and llvm_ad_rgb agree.

All random numbers come from fixed seeds, so a run is deterministic: the false-failure rates above
are probabilities over the choice of seeds (the whole file: <= ~4 % by a union bound over the four
statistical families), not a flakiness rate between runs.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy import integrate, stats

import integrators
from integrators.testing import bsdf_adapter, bsdf_context, chi2_test

ALPHA = 0.001                         # family-wise level of each of the 4 statistical families (suite budget: README)
SEED_BASE = 0x5EED

# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def _phong(rd=0.5, rg=0.4, e=20.0):
    return {"type": "phong", "diffuse_reflectance": _tex(rd),
            "specular_reflectance": _tex(rg), "exponent": float(e)}


def _tex(v):
    if isinstance(v, (list, tuple)):
        return {"type": "rgb", "value": [float(x) for x in v]}
    return float(v)


# the test kit: bsdf_context(component, type_mask) restricts a BSDFContext to lobes,
# bsdf_adapter(params, deg, ctx) is mi.chi2.BSDFAdapter at incident angle deg, and chi2_test
# runs mi.chi2.ChiSquareTest quietly (no printing, no chi2_data.py)
_ctx = bsdf_context


def _res(e):
    """(res, ires) of the chi^2 histogram for exponent e.

    ires = points per cell axis of the trapezoid rule that tabulates the pdf.  Mitsuba's default
    (res 101, ires 4) is too coarse already at e = 20: its cell integrals are biased enough that
    the *correct* sampler gets p-values far from uniform (seen: p < 1e-3 in 12 of 20 seeds at
    e = 20, 30 deg, and a failure at the corrected level), so every case uses ires 16 (p-values
    then uniform over seeds, checked by hand: 30 seeds per case, none below 0.005).  At e = 300
    the lobe is ~3 degrees wide and res 101 misestimates it even with ires 16, so those cases use
    res 201.  Even then, at normal incidence the e = 300 lobe (1 - cos(theta) ~ 1/e = 0.003) lies
    almost entirely in the top row (height 2/201 = 0.01 in cos(theta)), so that case mainly checks
    the azimuthal distribution and the lobe's mass; the sharp negative control below shows that a
    5 % exponent error is still detected there.  Exponents >> 300 (e.g. 10000) are not chi^2
    tested: no affordable histogram resolves them; the albedo/weight tests cover them instead.
    """
    return (101, 16) if e <= 20 else (201, 16)


def _uniforms(n, seed, dim=3):
    idx = dr.arange(mi.UInt32, n)
    v0, v1 = mi.sample_tea_32(idx, seed)
    rng = mi.PCG32(initstate=v0, initseq=v1)
    out = [rng.next_float32() for _ in range(dim)]
    dr.eval(*out)
    return out


# ---------------------------------------------------------------------------------------------
# 1. chi^2 goodness of fit (positive tests) and 2. negative controls
# ---------------------------------------------------------------------------------------------

ANGLES = (0, 30, 60, 80)
EXPONENTS = (1, 20, 300)

# (id, bsdf params, ctx kwargs, incident angle in degrees)
CHI2_CASES = []
for _deg in ANGLES:
    # the diffuse lobe does not depend on e; e = 300 makes sure the glossy lobe does not leak in
    CHI2_CASES.append((f"diffuse-e300-{_deg}deg", _phong(0.5, 0.4, 300), {"component": 0}, _deg))
for _e in EXPONENTS:
    for _deg in ANGLES:
        CHI2_CASES.append((f"glossy-e{_e}-{_deg}deg", _phong(0.5, 0.4, _e), {"component": 1}, _deg))
        CHI2_CASES.append((f"mixture-e{_e}-{_deg}deg", _phong(0.5, 0.4, _e), {}, _deg))
CHI2_CASES += [
    ("typemask-glossy-e20-30deg", _phong(0.5, 0.4, 20),
     {"type_mask": mi.BSDFFlags.GlossyReflection}, 30),
    ("typemask-diffuse-e20-30deg", _phong(0.5, 0.4, 20),
     {"type_mask": mi.BSDFFlags.DiffuseReflection}, 30),
    # per-channel albedos: selection probability is the ratio of channel means (0.25 / 0.55)
    ("mixture-rgb-e20-30deg", _phong([0.6, 0.2, 0.1], [0.1, 0.3, 0.35], 20), {}, 30),
    # rho_d = 0: only the glossy lobe is ever picked (selection probability 1)
    ("mixture-glossyonly-e20-60deg", _phong(0.0, 1.0, 20), {}, 60),
]


def _neg_exponent_plus_one():
    """Sampler of e = 20 (glossy lobe, 30 deg) checked against the pdf of e = 21."""
    p = _phong(0.5, 0.4, 20)
    sample, _ = bsdf_adapter(p, 30, _ctx(component=1))
    _, pdf_wrong = bsdf_adapter(_phong(0.5, 0.4, 21), 30, _ctx(component=1))
    return sample, pdf_wrong, _res(20)


def _neg_scaled_pdf():
    """pdf off by the factor (e+1)/(e+2) (the BRDF's normalisation used in the pdf), e = 20."""
    e = 20
    sample, pdf = bsdf_adapter(_phong(0.5, 0.4, e), 30, _ctx(component=1))
    return sample, (lambda wo: pdf(wo) * ((e + 1.0) / (e + 2.0))), _res(e)


def _neg_selection_probability():
    """Mixture (rho_d = 0.5, rho_g = 0.4: P = 4/9) checked against a 50/50 mixture pdf."""
    p = _phong(0.5, 0.4, 20)
    sample, _ = bsdf_adapter(p, 30, _ctx())
    _, pdf_d = bsdf_adapter(p, 30, _ctx(component=0))
    _, pdf_g = bsdf_adapter(p, 30, _ctx(component=1))
    return sample, (lambda wo: 0.5 * pdf_d(wo) + 0.5 * pdf_g(wo)), _res(20)


def _neg_sharp_exponent():
    """Sharpest tested lobe (e = 300, normal incidence, the least resolved case) against e = 315."""
    sample, _ = bsdf_adapter(_phong(0.5, 0.4, 300), 0, _ctx(component=1))
    _, pdf_wrong = bsdf_adapter(_phong(0.5, 0.4, 315), 0, _ctx(component=1))
    return sample, pdf_wrong, _res(300)


NEGATIVE_CONTROLS = {
    "exponent+1": _neg_exponent_plus_one,
    "pdf*(e+1)/(e+2)": _neg_scaled_pdf,
    "selection-probability-0.5": _neg_selection_probability,
    "e300-vs-e315": _neg_sharp_exponent,
}

N_CHI2 = len(CHI2_CASES) + len(NEGATIVE_CONTROLS)


def _chi2(sample, pdf, res_ires, seed):
    res, ires = res_ires
    test = chi2_test(sample, pdf, domain="sphere", sample_dim=3, sample_count=1_000_000,
                     res=res, ires=ires, seed=seed, alpha=ALPHA, test_count=N_CHI2)
    return test.passed, test


@pytest.mark.parametrize("name,params,ctx_kw,deg", CHI2_CASES, ids=[c[0] for c in CHI2_CASES])
def test_chi2_sampling_matches_pdf(name, params, ctx_kw, deg):
    # H0: sample() draws directions with density pdf() (same ctx).  Rejected at the Sidak level
    # 1 - 0.99^(1/N_CHI2) (~3e-4), so all chi^2 tests together fail falsely with prob. <= 1 %.
    sample, pdf = bsdf_adapter(params, deg, _ctx(**ctx_kw))
    seed = SEED_BASE + [c[0] for c in CHI2_CASES].index(name)
    ok, test = _chi2(sample, pdf, _res(params["exponent"]), seed)
    assert ok, f"chi^2 test rejected H0 for {name} (p = {test.p_value}):\n{test.messages}"


@pytest.mark.parametrize("name", list(NEGATIVE_CONTROLS))
def test_chi2_negative_control_is_rejected(name):
    # H0 (false by construction): the sampler's density equals the deliberately wrong pdf.  The
    # test must reject it at the same corrected level as the positive tests; a pass here would
    # mean the chi^2 tests above cannot tell a right pdf from a wrong one.
    sample, wrong_pdf, res_ires = NEGATIVE_CONTROLS[name]()
    seed = SEED_BASE + 1000 + list(NEGATIVE_CONTROLS).index(name)
    ok, test = _chi2(sample, wrong_pdf, res_ires, seed)
    assert not ok, f"negative control {name!r} was NOT rejected (p = {test.p_value}):\n" \
                   f"{test.messages}"


# ---------------------------------------------------------------------------------------------
# 3. eval / pdf / sample against the closed-form formulas
# ---------------------------------------------------------------------------------------------

def _random_dirs(rng, n, upper_only=True):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if upper_only:
        v[:, 2] = np.abs(v[:, 2])
    return v.astype(np.float32)


def _vec(a):
    return mi.Vector3f(a[:, 0], a[:, 1], a[:, 2])


def _np(x):
    return np.array(x, dtype=np.float64)


def _reference(wi, wo, rd, rg, e, lobes=("d", "g")):
    """float64 reference: (eval = f cos(theta_o) per channel [n, 3], mixture/lobe pdf [n])."""
    wi = wi.astype(np.float64)
    wo = wo.astype(np.float64)
    rd = np.broadcast_to(np.asarray(rd, dtype=np.float64), (3,))
    rg = np.broadcast_to(np.asarray(rg, dtype=np.float64), (3,))
    r = wi * np.array([-1.0, -1.0, 1.0])
    cos_a = np.sum(r * wo, axis=1)
    lobe = np.where(cos_a > 0, np.maximum(cos_a, 0.0) ** e, 0.0)
    cos_o = wo[:, 2]
    valid = (wi[:, 2] > 0) & (cos_o > 0)
    f = np.zeros((len(wo), 3))
    if "d" in lobes:
        f += rd[None, :] / np.pi
    if "g" in lobes:
        f += rg[None, :] * ((e + 2.0) / (2.0 * np.pi)) * lobe[:, None]
    value = np.where(valid[:, None], f * cos_o[:, None], 0.0)
    pdf_d = np.maximum(cos_o, 0.0) / np.pi
    pdf_g = (e + 1.0) / (2.0 * np.pi) * lobe
    if lobes == ("d", "g"):
        total = rd.mean() + rg.mean()
        pg = rg.mean() / total if total > 0 else 0.0
        pdf = (1.0 - pg) * pdf_d + pg * pdf_g
    else:
        pdf = pdf_d if "d" in lobes else pdf_g
    return value, np.where(valid, pdf, 0.0)


def _close(actual, expected, rtol=1e-4):
    # float32 evaluation vs float64 reference: relative 1e-4, plus an absolute floor of 1e-6 of
    # the largest value for entries that are tiny (float32 underflow of cos^e)
    atol = 1e-6 * max(float(np.max(np.abs(expected))), 1e-30)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol)


RHO_CASES = [(0.3, 0.7), (0.5, 0.2), (0.0, 1.0), (0.4, 0.0),
             ([0.6, 0.2, 0.1], [0.1, 0.3, 0.35])]


@pytest.mark.parametrize("e", [0, 1, 20, 300])
@pytest.mark.parametrize("rho", RHO_CASES, ids=lambda r: f"rd={r[0]}-rg={r[1]}")
def test_eval_pdf_sample_match_formula(rho, e):
    rd, rg = rho
    bsdf = mi.load_dict(_phong(rd, rg, e))
    rng = np.random.default_rng(1234 + e)
    n = 20000
    wi = _random_dirs(rng, n)
    wo = _random_dirs(rng, n)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _vec(wi)
    ctx = mi.BSDFContext()
    ref_val, ref_pdf = _reference(wi, wo, rd, rg, e)
    val = _np(bsdf.eval(ctx, si, _vec(wo))).T
    pdf = _np(bsdf.pdf(ctx, si, _vec(wo)))
    _close(val, ref_val)
    _close(pdf, ref_pdf)
    v2, p2 = bsdf.eval_pdf(ctx, si, _vec(wo))
    np.testing.assert_array_equal(_np(v2).T, val)
    np.testing.assert_array_equal(_np(p2), pdf)

    # below the horizon (either direction) everything is zero (one-sided BSDF)
    wo_low = wo * np.array([1, 1, -1], dtype=np.float32)
    assert np.all(_np(bsdf.eval(ctx, si, _vec(wo_low))) == 0)
    assert np.all(_np(bsdf.pdf(ctx, si, _vec(wo_low))) == 0)
    si_low = dr.zeros(mi.SurfaceInteraction3f, n)
    si_low.wi = _vec(wi * np.array([1, 1, -1], dtype=np.float32))
    assert np.all(_np(bsdf.eval(ctx, si_low, _vec(wo))) == 0)
    assert np.all(_np(bsdf.pdf(ctx, si_low, _vec(wo))) == 0)

    # sample(): weight == eval/pdf and bs.pdf == pdf(bs.wo) for valid samples, zero otherwise
    u = _uniforms(n, seed=77 + e)
    bs, weight = bsdf.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
    wo_s = np.stack([_np(bs.wo.x), _np(bs.wo.y), _np(bs.wo.z)], axis=1).astype(np.float32)
    w = _np(weight).T
    bs_pdf = _np(bs.pdf)
    ref_val, ref_pdf = _reference(wi, wo_s, rd, rg, e)
    valid = ref_pdf > 0
    assert valid.mean() > 0.5
    np.testing.assert_allclose(bs_pdf[valid], ref_pdf[valid], rtol=1e-4)
    np.testing.assert_allclose(w[valid], ref_val[valid] / ref_pdf[valid][:, None],
                               rtol=1e-4, atol=1e-7)
    assert np.all(w[~valid] == 0) and np.all(bs_pdf[~valid] == 0)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    # sampled directions are unit vectors and glossy samples lie in the lobe's hemisphere
    np.testing.assert_allclose(np.linalg.norm(wo_s.astype(np.float64), axis=1), 1.0, atol=1e-5)
    comp = _np(bs.sampled_component).astype(int)
    r = wi.astype(np.float64) * np.array([-1.0, -1.0, 1.0])
    assert np.all(np.sum(r * wo_s, axis=1)[comp == 1] > -1e-6)
    if rg == 0.0:
        assert np.all(comp == 0)
    if rd == 0.0:
        assert np.all(comp == 1)


# ---------------------------------------------------------------------------------------------
# 4. albedo
# ---------------------------------------------------------------------------------------------

ALBEDO_EXPONENTS = (0, 1, 10, 100, 10000)
ALBEDO_RHOS = ((0.3, 0.7), (0.0, 1.0))
ALBEDO_ANGLES = tuple(range(90))
ALBEDO_N = 1 << 20
N_ALBEDO = len(ALBEDO_EXPONENTS) * len(ALBEDO_RHOS) * len(ALBEDO_ANGLES)
# Bonferroni over all (rho, e, angle) cases, family-wise level ALPHA: one-sided for the upper
# bound (~4.39 sigma, i.e. stricter than a plain 4 sigma), two-sided for the equality tests.
Z_BOUND = max(4.0, float(stats.norm.isf(ALPHA / N_ALBEDO)))
Z_EQUAL = max(4.0, float(stats.norm.isf(ALPHA / (2 * N_ALBEDO))))
# float32 rounding of the weights (relative ~1e-7) can bias the mean when sigma is ~1e-7
FLOAT_TOL = 2e-6


def _glossy_albedo(theta, e):
    """Quadrature reference of int_{H+} (e+2)/(2pi) max(cos alpha, 0)^e cos(theta_o) d omega.

    Lobe coordinates around the mirror direction: cos(alpha) = u^(1/(e+1)) turns the measure
    (e+1)/(2pi) cos^e(alpha) d omega into du d(phi)/(2pi), so the albedo is
    (e+2)/(e+1) int_0^1 <max(cos theta_o, 0)>_phi du, with the azimuthal mean in closed form."""
    ci, s_i = math.cos(theta), math.sin(theta)

    def phi_mean(a, b):        # mean over phi of max(0, a + b cos phi), b >= 0
        if a >= b:
            return a
        if a <= -b:
            return 0.0
        p0 = math.acos(-a / b)
        return (a * p0 + b * math.sin(p0)) / math.pi

    def g(u):
        t = u ** (1.0 / (e + 1.0))
        return phi_mean(t * ci, math.sqrt(max(0.0, 1.0 - t * t)) * s_i)

    uk = s_i ** (e + 1.0)     # where the lobe starts to cross the horizon
    pts = [uk] if 0.0 < uk < 1.0 else None
    v, _ = integrate.quad(g, 0.0, 1.0, points=pts, epsabs=1e-12, epsrel=1e-10, limit=500)
    return (e + 2.0) / (e + 1.0) * v


def test_glossy_albedo_quadrature_reference():
    # Deterministic check of the reference used below (and of the claims in phong.py's docstring):
    # the glossy lobe's albedo is exactly 1 at normal incidence for every e (the lobe around the
    # normal is exactly the upper hemisphere, no clipping), (1 + cos theta)/2 for e = 0
    # (closed form), and never above 1 at any angle.
    for e in ALBEDO_EXPONENTS:
        assert _glossy_albedo(0.0, e) == pytest.approx(1.0, abs=1e-9)
        vals = [_glossy_albedo(math.radians(d), e) for d in ALBEDO_ANGLES]
        assert max(vals) <= 1.0 + 1e-9
        assert all(a >= b - 1e-9 for a, b in zip(vals, vals[1:]))   # decreasing with theta_i
    for d in (10, 45, 80, 89):
        t = math.radians(d)
        assert _glossy_albedo(t, 0) == pytest.approx((1 + math.cos(t)) / 2, abs=1e-9)
    # e = 1 at normal incidence analytically: 3/(2pi) * 2pi * int_0^1 c^2 dc = 1
    assert _glossy_albedo(0.0, 1) == pytest.approx(1.0, abs=1e-12)


def _albedo_stats(bsdf, ctx, deg, u):
    """(mean, standard error) of the channel-0 sample weight for one incident angle."""
    si = dr.zeros(mi.SurfaceInteraction3f)
    t = math.radians(deg)
    # opaque: one compiled kernel for all angles of a BSDF
    si.wi = mi.Vector3f(dr.opaque(mi.Float, math.sin(t)), 0.0, dr.opaque(mi.Float, math.cos(t)))
    _, w = bsdf.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
    w0 = mi.Float64(w[0])
    s1, s2 = dr.sum(w0), dr.sum(w0 * w0)
    dr.eval(s1, s2)
    n = dr.width(u[0])
    mean = s1[0] / n
    var = max(s2[0] / n - mean * mean, 0.0) * n / (n - 1)
    return mean, math.sqrt(var / n)


@pytest.mark.parametrize("e", ALBEDO_EXPONENTS)
@pytest.mark.parametrize("rho", ALBEDO_RHOS, ids=lambda r: f"rd={r[0]}-rg={r[1]}")
def test_albedo_at_most_one(rho, e):
    rd, rg = rho
    bsdf = mi.load_dict(_phong(rd, rg, e))
    u = _uniforms(ALBEDO_N, seed=SEED_BASE + 2000 + 10 * int(rd * 10) + ALBEDO_EXPONENTS.index(e))
    ctx = mi.BSDFContext()
    for deg in ALBEDO_ANGLES:
        mean, se = _albedo_stats(bsdf, ctx, deg, u)
        expected = rd + rg * _glossy_albedo(math.radians(deg), e)
        # H0: albedo(theta) <= 1 (energy conservation).  One-sided z-test on the mean of 2^20
        # bounded i.i.d. weights; reject if mean > 1 + Z_BOUND * se (+ float32 slack).
        # Z_BOUND is the Bonferroni quantile for all N_ALBEDO cases at family level 1 %.
        assert mean <= 1.0 + Z_BOUND * se + FLOAT_TOL, \
            f"albedo {mean} > 1 (se {se}) at {deg} deg, e = {e}, rho = {rho}"
        # H0: E[weight] = rho_d + rho_g * A_g(theta, e) (the weights are unbiased); two-sided
        # z-test, Bonferroni over all N_ALBEDO cases at family level 1 %.
        assert abs(mean - expected) <= Z_EQUAL * se + FLOAT_TOL, \
            f"albedo {mean} != reference {expected} (se {se}) at {deg} deg, e = {e}, rho = {rho}"


@pytest.mark.parametrize("e", ALBEDO_EXPONENTS)
def test_glossy_albedo_is_rho_g_at_normal_incidence(e):
    # Exact analytically for every e (verified by test_glossy_albedo_quadrature_reference):
    # int (e+2)/(2pi) cos^e(theta) cos(theta) d omega = 1 over the upper hemisphere.
    # H0: E[weight] = rho_g for the glossy lobe alone (ctx.component = 1, rho_g = 0.7) and for
    # the mixture with rho_d = 0 (rho_g = 1).  Two-sided z-test on 2^20 samples, 2 x 5 tests,
    # Bonferroni at family level 1 % (|z| <= ~3.9); tolerance 1e-3 relative -- far tighter than
    # "1 % + 4 sigma" -- only covers float32 rounding.
    z = float(stats.norm.isf(ALPHA / (2 * 2 * len(ALBEDO_EXPONENTS))))
    u = _uniforms(ALBEDO_N, seed=SEED_BASE + 3000 + e)
    for params, ctx, rho_g in ((_phong(0.3, 0.7, e), _ctx(component=1), 0.7),
                               (_phong(0.0, 1.0, e), _ctx(), 1.0)):
        mean, se = _albedo_stats(mi.load_dict(params), ctx, 0, u)
        assert abs(mean - rho_g) <= z * se + 1e-6, (e, mean, se, rho_g)
        assert abs(mean - rho_g) <= 1e-3 * rho_g


# ---------------------------------------------------------------------------------------------
# 5. lobe selection by BSDFContext and flags
# ---------------------------------------------------------------------------------------------

def test_lobe_selection_and_flags():
    rd, rg, e = 0.3, 0.6, 15.0
    bsdf = mi.load_dict(_phong(rd, rg, e))
    F = mi.BSDFFlags
    assert bsdf.component_count() == 2
    assert mi.has_flag(bsdf.flags(0), F.DiffuseReflection)
    assert not mi.has_flag(bsdf.flags(0), F.GlossyReflection)
    assert mi.has_flag(bsdf.flags(1), F.GlossyReflection)
    assert not mi.has_flag(bsdf.flags(1), F.DiffuseReflection)
    for i in (0, 1):
        assert mi.has_flag(bsdf.flags(i), F.FrontSide)
        assert not mi.has_flag(bsdf.flags(i), F.BackSide)
    assert int(bsdf.flags()) == int(bsdf.flags(0)) | int(bsdf.flags(1))

    rng = np.random.default_rng(7)
    n = 4096
    wi, wo = _random_dirs(rng, n), _random_dirs(rng, n)
    # put half of the wo near the mirror direction so that the glossy lobe is not ~0
    near = wi[: n // 2] * np.array([-1, -1, 1], dtype=np.float32) + 0.1 * wo[: n // 2]
    wo[: n // 2] = near / np.linalg.norm(near, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _vec(wi)
    cases = {
        "component0": (_ctx(component=0), ("d",)),
        "component1": (_ctx(component=1), ("g",)),
        "type_mask_glossy": (_ctx(type_mask=F.GlossyReflection), ("g",)),
        "type_mask_diffuse": (_ctx(type_mask=F.DiffuseReflection), ("d",)),
        "all": (_ctx(), ("d", "g")),
    }
    u = _uniforms(n, seed=99)
    for name, (ctx, lobes) in cases.items():
        ref_val, ref_pdf = _reference(wi, wo, rd, rg, e, lobes)
        _close(_np(bsdf.eval(ctx, si, _vec(wo))).T, ref_val)
        _close(_np(bsdf.pdf(ctx, si, _vec(wo))), ref_pdf)
        bs, w = bsdf.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
        # (with one lobe enabled, phong returns width-1 sampled_component/sampled_type: broadcast)
        comp = np.broadcast_to(_np(bs.sampled_component).astype(int), (n,))
        stype = np.broadcast_to(_np(bs.sampled_type).astype(int), (n,))
        ok = _np(w)[0] > 0
        assert ok.mean() > 0.5, name
        if lobes == ("d",):
            assert np.all(comp[ok] == 0), name
            assert np.all(stype[ok] == int(F.DiffuseReflection)), name
        elif lobes == ("g",):
            assert np.all(comp[ok] == 1), name
            assert np.all(stype[ok] == int(F.GlossyReflection)), name
        else:
            assert set(np.unique(comp[ok])) == {0, 1}, name
    # component 1 and type_mask GlossyReflection are the same thing
    a = _np(bsdf.eval(cases["component1"][0], si, _vec(wo)))
    b = _np(bsdf.eval(cases["type_mask_glossy"][0], si, _vec(wo)))
    np.testing.assert_array_equal(a, b)
    # the sum of the single-lobe evals is the full eval
    d = _np(bsdf.eval(cases["component0"][0], si, _vec(wo)))
    full = _np(bsdf.eval(cases["all"][0], si, _vec(wo)))
    np.testing.assert_allclose(a + d, full, rtol=1e-5, atol=1e-9)
    # no lobe enabled: nothing is evaluated or sampled
    none = _ctx(type_mask=F.DeltaReflection)
    assert np.all(_np(bsdf.eval(none, si, _vec(wo))) == 0)
    assert np.all(_np(bsdf.pdf(none, si, _vec(wo))) == 0)
    _, w = bsdf.sample(none, si, u[0], mi.Point2f(u[1], u[2]))
    assert np.all(_np(w) == 0)


# ---------------------------------------------------------------------------------------------
# 6. bad input
# ---------------------------------------------------------------------------------------------

def test_reflectance_sum_above_one_is_rejected():
    with pytest.raises(Exception, match=r"(?s)phong.*exceeds 1"):
        mi.load_dict({"type": "phong", "diffuse_reflectance": 0.7, "specular_reflectance": 0.5})
    # per-channel maxima are added: 0.8 (red) + 0.3 (green) > 1 although no channel sums above 1
    with pytest.raises(Exception, match=r"(?s)phong.*exceeds 1"):
        mi.load_dict(_phong([0.8, 0.1, 0.1], [0.1, 0.3, 0.1], 10))
    # the boundary itself is fine
    mi.load_dict({"type": "phong", "diffuse_reflectance": 0.3, "specular_reflectance": 0.7})


def test_negative_exponent_is_rejected():
    with pytest.raises(Exception, match="exponent"):
        mi.load_dict({"type": "phong", "exponent": -1.0})


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_negative_reflectance_is_rejected(variant):
    try:
        integrators.set_variant(variant)
        for key in ("diffuse_reflectance", "specular_reflectance"):
            params = {"type": "phong", "diffuse_reflectance": 0.1, "specular_reflectance": 0.1}
            params[key] = -0.1
            with pytest.raises(Exception, match=rf"(?s)phong.*{key}.*negative"):
                mi.load_dict(params)
    finally:
        integrators.set_variant("llvm_ad_rgb")


def test_unknown_parameter_is_rejected():
    with pytest.raises(Exception, match=r"(?s)phong.*shininess_typo"):
        mi.load_dict({"type": "phong", "shininess_typo": 3.0})


# ---------------------------------------------------------------------------------------------
# 7. scalar_rgb agrees with llvm_ad_rgb
# ---------------------------------------------------------------------------------------------

def test_scalar_variant_matches_llvm():
    params = _phong([0.5, 0.2, 0.1], [0.3, 0.4, 0.2], 25)
    rng = np.random.default_rng(31)
    n = 8
    wi = _random_dirs(rng, n)
    wo = _random_dirs(rng, n)
    wo[:4] = wi[:4] * np.array([-1, -1, 1], dtype=np.float32) + 0.05 * wo[:4]   # near the lobe
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    u = rng.random((n, 3)).astype(np.float32)
    ctxs = {"all": {}, "c0": {"component": 0}, "c1": {"component": 1}}

    assert mi.variant() == "llvm_ad_rgb"
    bsdf = mi.load_dict(params)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _vec(wi)
    llvm = {}
    for k, kw in ctxs.items():
        ctx = _ctx(**kw)
        bs, w = bsdf.sample(ctx, si, mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]))
        llvm[k] = (_np(bsdf.eval(ctx, si, _vec(wo))).T, _np(bsdf.pdf(ctx, si, _vec(wo))),
                   _np(w).T, _np(bs.pdf), np.array([_np(bs.wo.x), _np(bs.wo.y), _np(bs.wo.z)]).T)
    try:
        integrators.set_variant("scalar_rgb")
        bsdf_s = mi.load_dict(params)
        for k, kw in ctxs.items():
            ctx = _ctx(**kw)
            ev, pd, ws, bpdf, bwo = [], [], [], [], []
            for j in range(n):
                si_s = mi.SurfaceInteraction3f()
                si_s.wi = mi.Vector3f(*map(float, wi[j]))
                w_o = mi.Vector3f(*map(float, wo[j]))
                ev.append(list(bsdf_s.eval(ctx, si_s, w_o)))
                pd.append(float(bsdf_s.pdf(ctx, si_s, w_o)))
                bs, w = bsdf_s.sample(ctx, si_s, float(u[j, 0]),
                                      mi.Point2f(float(u[j, 1]), float(u[j, 2])))
                ws.append(list(w))
                bpdf.append(float(bs.pdf))
                bwo.append(list(bs.wo))
            for got, want in zip((ev, pd, ws, bpdf, bwo), llvm[k]):
                np.testing.assert_allclose(np.array(got, dtype=np.float64), want,
                                           rtol=1e-4, atol=1e-6, err_msg=k)
    finally:
        integrators.set_variant("llvm_ad_rgb")
    assert mi.variant() == "llvm_ad_rgb"
