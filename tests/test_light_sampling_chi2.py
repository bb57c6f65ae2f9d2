"""Chi-square tests of the whole light-sampling routine: from a fixed shading point, directions
drawn by ``LightSelection.sample_direction`` (selection, a point on the light, area to solid
angle) must follow the density ``pdf_direction`` reports for them, for uniform, power and
adaptive selection (``mi.chi2.ChiSquareTest`` over the sphere of directions).

H0: the sampled directions have density pdf_direction.  Each test at the Sidak-corrected level
1 - (1 - 0.001)^(1/3) over the three tests (family-wise 0.1 %).  Negative control: the same test
with the selection probability left out of the pdf must fail.  The pdf is integrated per bin
with ires = 64: light silhouettes make it discontinuous, and at Mitsuba's default resolution the
integration error alone rejects a correct sampler."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import pytest

import integrators  # noqa: F401
from integrators.sampling.light_selection import make
from integrators.testing import assert_sampling, chi2_test
from integrators.testing.scenes import light_rect

ALPHA = 1 - (1 - 1e-3) ** (1 / 3)
# mi.chi2.ChiSquareTest over the sphere of directions, run quietly (no chi2_data.py written)
CHI2 = {"domain": "sphere", "sample_dim": 3, "res": 51, "ires": 64, "sample_count": 2_000_000,
        "alpha": ALPHA}
ORIGIN = mi.ScalarPoint3f(0.1, 0.2, 0.0)


def scene():
    return mi.load_dict({
        "type": "scene",
        "a": {"type": "rectangle", "to_world": light_rect((0.5, 0.3, 1.0), (0.4, 0.3)),
              "emitter": {"type": "area", "radiance": 3.0}},
        "b": {"type": "sphere", "center": [-1.0, 0.5, 1.5], "radius": 0.4,
              "emitter": {"type": "area", "radiance": 1.0}},
        "c": {"type": "rectangle", "to_world": light_rect((0.0, -1.2, 0.8), (0.2, 0.6)),
              "emitter": {"type": "area", "radiance": 10.0}},
    })


def adapters(sc, mode, drop_selection=False):
    sel = make(sc, mode)

    def origin_si(n):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.p = mi.Point3f(ORIGIN)
        si.n = mi.Vector3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(si.n)
        return si

    def sample(s):
        n = dr.width(s)
        ds, w, _ = sel.sample_direction(origin_si(n), s[0], mi.Point2f(s[1], s[2]))
        return ds.d

    def pdf(wo):
        n = dr.width(wo)
        si = origin_si(n)
        hit = sc.ray_intersect(si.spawn_ray(mi.Vector3f(wo)))
        p = sel.pdf_direction(si, hit, hit.is_valid())
        if drop_selection:
            p = p / dr.select(p > 0, sel.pmf(hit.emitter(sc), hit.is_valid()), 1.0)
        return p
    return sample, pdf


@pytest.mark.parametrize("mode", ["uniform", "power", "adaptive"])
def test_light_direction_sampling(mode):
    sample, pdf = adapters(scene(), mode)
    assert_sampling(sample, pdf, **CHI2)


def test_negative_control_pdf_without_selection():
    sample, pdf = adapters(scene(), "power", drop_selection=True)
    r = chi2_test(sample, pdf, **CHI2)
    assert not r.passed, r
