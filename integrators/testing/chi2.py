"""Chi-square goodness of fit of a sampling routine against its pdf (``mi.chi2.ChiSquareTest``).

H0 of each test: the directions (or points) drawn by ``sample`` have the density ``pdf``
(integrated over the histogram cells).  Mitsuba's pooled Pearson chi-square; rejected at the
Sidak-corrected level 1 - (1 - alpha)^(1 / test_count), so ``test_count`` tests at ``alpha``
fail falsely with probability <= alpha together.  Always run quietly: nothing is printed and no
``chi2_data.py`` is written into the working directory.

* :func:`chi2_test` - any (sample, pdf) pair; returns a :class:`Chi2Test` verdict;
* :func:`bsdf_adapter` - the (sample, pdf) pair of a BSDF at one incident direction
  (``mi.chi2.BSDFAdapter``; ``ctx`` restricts it to one lobe);
* :func:`assert_sampling`, :func:`assert_bsdf_sampling` - the same, raising AssertionError with
  the verdict.

Resolution: Mitsuba's default (res 101, ires 4) tabulates the pdf too coarsely for glossy lobes
(a correct sampler gets p < 1e-3 at Phong e = 20): the default here is ires = 16; lobes a few
degrees wide need res 201 or more.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from .stats import count_check

#: default family-wise level of chi-square tests (with test_count tests in the family)
CHI2_ALPHA = 1e-3


@dataclass
class Chi2Test:
    ok: bool
    p_value: float
    alpha: float              # the per-test (Sidak-corrected) level
    messages: str

    h0 = "the samples have the density pdf (Pearson chi-square over histogram cells)"

    @property
    def passed(self) -> bool:
        return bool(self.ok)

    def __str__(self):
        p = "nan" if self.p_value is None else f"{self.p_value:.3g}"
        lines = [ln.strip() for ln in self.messages.splitlines() if ln.strip()]
        why = [ln for ln in lines if ln.startswith(("Failure", "*****", "Accepted"))]
        return f"p = {p} (alpha {self.alpha:.3g}): " + "; ".join(why or lines[-1:])


def _domain(domain):
    import mitsuba as mi
    if domain is None or domain == "sphere":
        return mi.chi2.SphericalDomain()
    if domain == "plane":
        return mi.chi2.PlanarDomain()
    if domain == "line":
        return mi.chi2.LineDomain()
    return domain


def chi2_test(sample, pdf, *, domain="sphere", sample_dim: int = 3,
              sample_count: int = 1_000_000, res: int = 101, ires: int = 16, seed: int = 0,
              alpha: float = CHI2_ALPHA, test_count: int = 1) -> Chi2Test:
    """Run ``mi.chi2.ChiSquareTest(domain, sample, pdf, ...)`` quietly; return the verdict.

    ``sample(u)`` maps ``sample_dim`` uniform arrays to points of the domain (a direction on
    the sphere by default; it may also return (points, weights), weight 0 = no sample);
    ``pdf(points)`` is the density the sampler claims.  The test is rejected at the
    Sidak-corrected level 1 - (1 - alpha)^(1 / test_count)."""
    import mitsuba as mi
    test = mi.chi2.ChiSquareTest(domain=_domain(domain), sample_func=sample, pdf_func=pdf,
                                 sample_dim=sample_dim, sample_count=sample_count, res=res,
                                 ires=ires, seed=seed)
    ok = test.run(significance_level=alpha, test_count=test_count, quiet=True)
    level = 1.0 - (1.0 - alpha) ** (1.0 / test_count)
    count_check(level, "chi2")
    p = None if test.p_value is None else float(test.p_value)
    # quiet=True writes no chi2_data.py, whatever Mitsuba's messages say
    messages = re.sub(r'\s*Target density and histogram (were )?written to "chi2_data\.py"?\.?',
                      "", test.messages)
    return Chi2Test(bool(ok), p, level, messages)


def incident(wi):
    """An incident direction: an angle from the normal in degrees (in the xz plane), or a
    3-vector in the local shading frame."""
    import mitsuba as mi
    if isinstance(wi, (int, float)):
        t = math.radians(wi)
        return mi.Vector3f(math.sin(t), 0.0, math.cos(t))
    return mi.Vector3f(*[float(v) for v in wi]) if not isinstance(wi, mi.Vector3f) else wi


def bsdf_context(component=None, type_mask=None):
    """A ``mi.BSDFContext`` restricted to one lobe (``component``: an index, see
    ``bsdf.flags(i)``) or to the lobes of ``type_mask`` (``mi.BSDFFlags``)."""
    import mitsuba as mi
    ctx = mi.BSDFContext()
    if component is not None:
        ctx.component = component
    if type_mask is not None:
        ctx.type_mask = +type_mask
    return ctx


def bsdf_adapter(bsdf: dict, wi=0.0, ctx=None):
    """(sample, pdf) of the BSDF ``bsdf`` (a dict for ``mi.load_dict``) at the incident
    direction ``wi`` (degrees from the normal, or a local 3-vector), with context ``ctx``
    (None: all lobes), for :func:`chi2_test` (``mi.chi2.BSDFAdapter``)."""
    import mitsuba as mi
    return mi.chi2.BSDFAdapter(bsdf["type"], bsdf, wi=incident(wi), ctx=ctx)


def _raise(what, r):
    if not r.passed:
        raise AssertionError(f"{what}: H0 {r.h0} rejected at alpha {r.alpha:.3g}: {r}\n"
                             f"{r.messages}")
    return r


def assert_sampling(sample, pdf, **kw) -> Chi2Test:
    """:func:`chi2_test`, raising AssertionError (verdict and Mitsuba's messages) on
    rejection; returns the verdict."""
    return _raise("sampling routine", chi2_test(sample, pdf, **kw))


def assert_bsdf_sampling(bsdf: dict, wi=0.0, ctx=None, *, component=None, type_mask=None,
                         **kw) -> Chi2Test:
    """Chi-square test of a BSDF's ``sample()`` against its ``pdf()`` at incident direction
    ``wi`` (degrees from the normal, or a local 3-vector), for all lobes or the lobe picked by
    ``ctx`` / ``component`` / ``type_mask``.  Keyword arguments go to :func:`chi2_test`
    (``res``, ``ires``, ``sample_count``, ``seed``, ``alpha``, ``test_count``).  Raises
    AssertionError with the verdict on rejection; returns the verdict."""
    if ctx is None and (component is not None or type_mask is not None):
        ctx = bsdf_context(component, type_mask)
    sample, pdf = bsdf_adapter(bsdf, wi, ctx)
    return _raise(f"{bsdf.get('type')} at wi = {wi}", chi2_test(sample, pdf, **kw))
