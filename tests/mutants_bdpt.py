"""Mutants of bidirectional path tracing (``bdpt``; see tests/mutation.py for the format).

Each plants one plausible bug in the estimator or its MIS recurrences; tests/test_bdpt.py must
fail for every one (``python tests/mutation.py --only NAME``)."""

_SUB = "integrators/sampling/subpath.py"
_BDPT = "integrators/plugins/bdpt.py"
_T = ["test_bdpt.py"]

MUTANTS = [
    # the first light vertex's ratio without the emitted cosine: MIS weights no longer sum to 1
    ("bdpt-first-hit-dvcm-without-cos0", _SUB,
     "dvcm_first = dr.select(area, mis(safe_div(p_nee * cos0, pdf_e)),",
     "dvcm_first = dr.select(area, mis(safe_div(p_nee, pdf_e)),", _T),
    # the recurrence forgets the reverse density at a smooth scattering
    ("bdpt-recurrence-without-reverse-pdf", _SUB,
     "mis(safe_div(cos_out, bs.pdf)) * (dvc * mis(p_rev) + dvcm))\n            dvcm = dr.select(spec, 0.0, mis(safe_div(1.0, bs.pdf)))\n            beta *= w * shading_correction(si, wo)",
     "mis(safe_div(cos_out, bs.pdf)) * (dvc + dvcm))\n            dvcm = dr.select(spec, 0.0, mis(safe_div(1.0, bs.pdf)))\n            beta *= w * shading_correction(si, wo)",
     _T),
    # light tracing without its shadow ray
    ("bdpt-light-tracing-no-visibility", _BDPT,
     "            active &= ~scene.ray_test(si.spawn_ray_to(ds.p), active)\n",
     "", _T),
    # a path longer than bidir_depth keeps the terms of the strategies s >= 2 in its s = 0
    # weight (no light subpath can build it): its weights sum to less than one
    ("bdpt-long-path-keeps-light-subpath-terms", _BDPT,
     "dr.select(depth <= bd_depth, mis(emission_w) * dvc,\n                                                   0.0)",
     "mis(emission_w) * dvc", _T),
    # the same for next-event estimation's weight
    ("bdpt-long-path-nee-keeps-light-subpath-terms", _BDPT,
     "dr.select(depth + 1 <= bd_depth, mis(ratio) * (dvcm + dvc * mis(p_rev_l)),\n                              0.0)",
     "mis(ratio) * (dvcm + dvc * mis(p_rev_l))", _T),
    # a connection without the 1/d^2 of the geometry term
    ("bdpt-connection-without-inverse-square", _BDPT,
     "beta_y * (w * inv_d2)", "beta_y * w", _T),
    # next-event estimation weighted against the BSDF hit only (the light-subpath strategies
    # that also produce the path are forgotten): weights sum to more than one
    ("bdpt-nee-weight-without-light-subpaths", _BDPT,
     "w1 = self.weight(w_light + 1.0 + w_cam)", "w1 = self.weight(w_light + 1.0)", _T),
    # a delta scattering on the camera subpath keeps its ratio (strategies that cannot connect
    # through a delta lobe get weight)
    ("bdpt-camera-delta-vertex-keeps-dvcm", _BDPT,
     "            dvcm = dr.select(spec, 0.0, mis(safe_div(1.0, bs.pdf)))\n            beta *= w\n",
     "            dvcm = mis(safe_div(1.0, bs.pdf))\n            beta *= w\n", _T),
    # the light subpath scattered in radiance mode (glass then divides by eta^2 twice)
    ("bdpt-light-walk-radiance-mode", _SUB,
     "        ctx = mi.BSDFContext(mi.TransportMode.Importance)\n        emitter, ray, beta",
     "        ctx = mi.BSDFContext()\n        emitter, ray, beta", _T),
    # light-tracing splats not divided by the pixel's filter mass (wrong with a gaussian filter)
    ("bdpt-splats-without-filter-mass", _BDPT,
     "out = data + dr.select(colour & (f > 0), add * w / dr.select(f > 0, f, 1.0), 0.0)",
     "out = data + dr.select(colour & (f > 0), add * w, 0.0)", _T),
    # a delta light's direction density left out of next-event estimation's ratio
    ("bdpt-delta-light-direction-pdf", _BDPT,
     "dir_pdf_l * cos_z * safe_div(1.0, dr.square(ds_l.dist))",
     "cos_z * safe_div(1.0, dr.square(ds_l.dist))", _T),
    # connections one segment short of max_depth are skipped
    ("bdpt-connection-depth-off-by-one", _BDPT,
     "ok = act & (depth_y + depth + 1 <= max_depth)",
     "ok = act & (depth_y + depth + 2 <= max_depth)", _T),
    # the closed-form reverse density of Mitsuba's diffuse BSDF off by a factor 2
    ("bdpt-lambert-reverse-pdf", _SUB,
     "(cos_i > 0), cos_i * dr.inv_pi, 0.0)", "(cos_i > 0), cos_i * dr.inv_two_pi, 0.0)", _T),
    # the camera's density for the light-tracing ratio taken per pixel instead of film-wide
    ("bdpt-camera-pdf-per-pixel", _BDPT,
     "dvcm = dr.select(first, mis(safe_div(1.0, p_film)), dvcm)",
     "dvcm = dr.select(first, mis(safe_div(1.0, 256.0 * p_film)), dvcm)", _T),
    # ---- environment lights, several lights, light selection, hide_emitters ----
    # the light subpath's dvc without the selection probability (the bug with several lights)
    ("bdpt-light-start-dvc-without-selection", _SUB,
     "self.mis(safe_div(cos0, pick * pdf_e))", "self.mis(safe_div(cos0, pdf_e))", _T),
    # an environment's first light vertex with a distance factor (as a finite light)
    ("bdpt-env-first-hit-with-distance", _SUB,
     "dr.select(inf, mis(safe_div(p_dir, pdf_e)),",
     "dr.select(inf, mis(safe_div(p_dir * dist2, pdf_e)),", _T),
    # an environment's emission density without the disk's area density
    ("bdpt-env-emission-without-disk", _SUB,
     "pdf_e = dr.select(area, pdf_area, dr.select(inf, p_dir * pos_pdf, dir_pdf))",
     "pdf_e = dr.select(area, pdf_area, dr.select(inf, p_dir, dir_pdf))", _T),
    # the camera's escape weighted without the light subpaths that reach the environment
    ("bdpt-env-escape-without-emission-term", _BDPT,
     "mis(pick_env_e * p_env * disk_pdf) * dvc, 0.0))", "0.0, 0.0))", _T),
    # next-event estimation to the environment: the emission ratio without the disk pdf
    ("bdpt-env-nee-ratio-without-disk", _BDPT,
     "dr.select(inf_l, pos_pdf_l * cos_z,", "dr.select(inf_l, cos_z,", _T),
    # adaptive/bvh: the light subpath's pmf ratio left out of next-event estimation's weight
    ("bdpt-nee-selection-ratio", _BDPT,
     "ratio *= safe_div(sel_e.pmf(ds_l.emitter, vis), pick_l)", "ratio *= 1.0", _T),
    # adaptive/bvh: next-event estimation's pmf at y1 left out of the light subpath's dvcm
    ("bdpt-light-walk-nee-pmf", _SUB,
     "dvcm_first *= mis(safe_div(nee_sel.pmf_at(si, emitter, active & first),",
     "dvcm_first *= mis(safe_div(sel.pmf(emitter, active & first),", _T),
    # hide_emitters: light tracing blocked by the (camera-transparent) area lights
    ("bdpt-hide-light-tracing-blocked-by-emitters", _BDPT,
     "active &= ~_occluded_by_non_emitters(scene, si.spawn_ray_to(ds.p), active)",
     "active &= ~scene.ray_test(si.spawn_ray_to(ds.p), active)", _T),
    # hide_emitters: light vertices on an emitter's surface splatted (the camera cannot see it)
    ("bdpt-hide-light-tracing-onto-emitters", _BDPT,
     "            active &= ~_on_emitter(scene, si)\n", "", _T),
    # hide_emitters ignored for the environment seen directly
    ("bdpt-hide-env-visible", _BDPT,
     "w_env = dr.select(first, w_seen, w_env)",
     "w_env = dr.select(first, 1.0, w_env)", _T),
]
