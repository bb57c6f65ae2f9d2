"""The public test kit: statistics, closed forms, test scenes, one-call checks, a pytest plugin.

Test your own integrator (registered with ``mi.register_integrator``)::

    from integrators.testing import assert_unbiased, closed_box
    scene, expected = closed_box(rho=0.5, le=1.0)          # L = le / (1 - rho) = 2
    assert_unbiased(scene, expected, {"type": "my_integrator"})

* :func:`assert_unbiased` / :func:`check_unbiased` - H0 "unbiased" against a closed-form value,
  an exact image, a batch of reference renders or a reference integrator (``"path"``); fails on
  rejection and when too noisy to see a 5 % bias (:mod:`integrators.testing.unbiased`);
* :func:`assert_bsdf_sampling`, :func:`assert_sampling`, :func:`chi2_test`,
  :func:`bsdf_adapter` - chi-square test of a sampling routine against its pdf
  (:mod:`integrators.testing.chi2`);
* :func:`closed_box`, :func:`closed_sphere`, :func:`polygon_light_plane`, :func:`furnace` -
  (scene dict, expected) cases, and their building blocks (:mod:`integrators.testing.scenes`);
* closed forms (:mod:`integrators.testing.closed_forms`) and the statistics underneath
  (:func:`mean_test`, :func:`image_test`, :func:`batch_means`, ... in
  :mod:`integrators.testing.stats`), :data:`CHECKS` / :data:`DEFAULT_ALPHA` (false-failure
  accounting);
* the pytest plugin :mod:`integrators_pytest` (a top-level module) (loaded automatically when this
  package is installed): fixtures ``assert_unbiased``, ``closed_box``, ``closed_sphere``,
  ``polygon_light_plane``, ``furnace`` and the end-of-run line counting statistical checks.

Names are imported on first use, so ``import integrators.testing`` does not load scipy.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "stats": ["DEFAULT_ALPHA", "CHECKS", "FLOAT32_RTOL", "MeanTest", "ImageTest", "mean_test",
              "image_test", "batch_means", "batch_images", "radiancemeter", "sample_values",
              "variance_upper_test", "count_check", "checks_summary"],
    "closed_forms": ["lambert_polygon_irradiance", "rectangle_vertices",
                     "point_light_irradiance", "closed_sphere_radiance", "closed_box_radiance",
                     "furnace_radiance", "fresnel_dielectric", "thin_dielectric_reflectance",
                     "sphere_interface_radiance"],
    "scenes": ["ClosedForm", "closed_box", "closed_sphere", "polygon_light_plane", "furnace",
               "dielectric_furnace", "mirror_furnace", "back_face_furnace",
               "closed_box_scene", "closed_sphere_scene", "furnace_scene", "plane_scene",
               "plane_radiance", "light_rect", "view_cosine"],
    "unbiased": ["assert_unbiased", "check_unbiased", "UnbiasedFailure", "MAX_REL_SE"],
    "chi2": ["Chi2Test", "chi2_test", "assert_sampling", "assert_bsdf_sampling",
             "bsdf_adapter", "bsdf_context", "incident", "CHI2_ALPHA"],
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name):
    if name in _EXPORTS:       # a submodule
        return importlib.import_module(f"{__name__}.{name}")
    mod = _WHERE.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
