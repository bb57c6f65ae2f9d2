"""Planted bugs in pssmlt (issue 18) that tests/test_pssmlt.py must catch (tests/mutation.py
format: name, file, original text, mutated text, target test files)."""

_P = "integrators/plugins/pssmlt.py"
_S = "integrators/sampling/primary_sample.py"
_T = ["test_pssmlt.py"]

MUTANTS = [
    # acceptance min(1, sqrt(I'/I)): the chains' stationary density becomes sqrt(I)
    ("pssmlt-acceptance-sqrt", _P,
     "a = dr.select(pos_c, dr.minimum(1.0, lum / dr.select(pos_c, lum_c, 1.0)), 1.0)",
     "a = dr.select(pos_c, dr.minimum(1.0, dr.sqrt(lum / dr.select(pos_c, lum_c, 1.0))), 1.0)",
     _T),
    # Kelemen's perturbation with a biased sign: the small step is no longer symmetric
    ("pssmlt-kelemen-asymmetric", _S, "neg = r < 0.5", "neg = r < 0.47", _T),
    # the current state splatted with a instead of 1 - a
    ("pssmlt-splat-weights-swapped", _P,
     "w_c = dr.select(pos_c, (1.0 - a) * scale",
     "w_c = dr.select(pos_c, a * scale", _T),
    # the accept step stores another vector than the proposal that was evaluated
    ("pssmlt-stored-vector-not-the-proposal", _P,
     "prop = ps.propose(u[d], index, k, large, sigma)",
     "prop = ps.propose(u[d], index + 1, k, large, sigma)", _T),
    # b's count takes every mutation, not only the large steps whose I it sums
    ("pssmlt-b-counts-every-mutation", _P,
     "st.lum_count += int(_scalar(n_large))",
     "st.lum_count += m", _T),
    # film position x and y swapped when choosing the pixel
    ("pssmlt-pixel-transposed", _P,
     "    return py * w + px\n",
     "    return px * w + py\n", _T),
    # emission seen directly counted by the chains and again by seen_emission
    ("pssmlt-emission-twice", _P,
     "if self.separate_emission:   # rendered apart (seen_emission)",
     "if False:   # rendered apart (seen_emission)", _T),
    # the chains start from the bootstrap paths in order, not resampled by I
    ("pssmlt-no-resampling", _P,
     "if resample and lum_sum > 0:", "if False and lum_sum > 0:", _T),
    # Kelemen's weights without the large step's second count (its independent-sample part)
    ("pssmlt-large-step-not-counted", _P,
     "(a + dr.select(large, 1.0, 0.0))", "(a + dr.select(large, 0.0, 0.0))", _T),
    # Kelemen's weights with a density of large steps that does not match large_step
    ("pssmlt-large-step-density-doubled", _P,
     "return dr.opaque(mi.Float, large_step * self.b)",
     "return dr.opaque(mi.Float, 2.0 * large_step * self.b)", _T),
    # the fused loop over steps: an accepted chain keeps its old pixel in the loop state
    ("pssmlt-loop-keeps-old-pixel", _P,
     "dr.select(accept, pix, pix_c), acc + a",
     "dr.select(accept, pix_c, pix_c), acc + a", _T),
    # the fused loop over steps: every step of a kernel reuses the same random numbers
    ("pssmlt-loop-same-key-every-step", _P,
     "k = ps.hash32(key0 + t)", "k = ps.hash32(key0 + t * 0)", _T),
    # the splat scale miscounts the mutations of a pass
    ("pssmlt-scale-miscount", _P,
     "dr.opaque(mi.Float, w * h / total)",
     "dr.opaque(mi.Float, w * h / (total + st.chains))", _T),
    # estimator bdpt: the light vertices' splats (light tracing, t = 1) left out of the path
    ("pssmlt-bdpt-light-splats-dropped", _P,
     "        for k in range(slots):\n            p_k, rgb_k = buf.get(lane * slots + k)",
     "        for k in range(0):\n            p_k, rgb_k = buf.get(lane * slots + k)", _T),
    # estimator bdpt: the current state's splats weighted as the proposal's
    ("pssmlt-bdpt-current-splats-as-proposal", _P,
     "        splat(image, dr.gather(mi.UInt32, st.pix[j], ids), rgb_c * w_c,",
     "        splat(image, dr.gather(mi.UInt32, st.pix[j], ids), rgb_c * w_p,", _T),
    # estimator bdpt: the chains keep the emission seen through delta scatterings, which
    # seen_emission renders too (counted twice)
    ("pssmlt-bdpt-delta-chain-twice", _P,
     "                              leave_out=self.left_out)",
     "                              leave_out=\"direct\")", _T),
    # estimator bdpt: the emission seen through delta scatterings rendered by nobody
    ("pssmlt-bdpt-delta-chain-missing", _P,
     "        if self.left_out == \"delta\":        # and through delta scatterings (bdpt's s = 0)",
     "        if False:", _T),
    # estimator bdpt: the light subpath reads the camera subpath's coordinates
    ("pssmlt-bdpt-shared-stream", _P,
     "                sampler.substream(self.dims_cam, self.dims_light))",
     "                sampler.substream(0, self.dims_light))", _T),
    # importance=relative: the chains' I relative, but b the bootstrap's mean luminance (the
    # pilot built, the bootstrap's own I not recomputed): the image off by the ratio of the two
    ("pssmlt-relative-b-of-luminance", _P,
     "        lum_b = retarget(pix_b, rgb_b, bootstrap, lum_b)",
     "        retarget(pix_b, rgb_b, bootstrap, lum_b)", _T),
    # importance=relative: a splat's I divides by g at pixel 0, not at its own pixel (still a
    # valid importance, but bdpt's splats then share one g: the relative weighting is lost;
    # consistent, so only the pilot's test sees it)
    ("pssmlt-relative-g-at-pixel-0", _P,
     "            return importance(rgb) / dr.gather(mi.Float, self.pilot, pix)",
     "            return importance(rgb) / dr.gather(mi.Float, self.pilot, pix * 0)", _T),
    # a pass's partial step starts at a literal chain offset: the step is compiled again for
    # every offset (a new kernel each pass; the image is the same)
    ("pssmlt-offset-literal", _P,
     "dr.opaque(mi.UInt32, st.offset)", "st.offset", _T),
    # importance_cap: the bootstrap's I capped (b their mean) but the chains' I not: the
    # image too dark where a path's I passes the cap
    ("pssmlt-cap-only-in-bootstrap", _P,
     "            lum = dr.minimum(lum, self.cap)\n        return pix, rgb, lum",
     "            lum = lum\n        return pix, rgb, lum", _T),
    # estimator=auto takes bdpt without asking bdpt whether it renders the scene
    ("pssmlt-auto-skips-scene-check", _P,
     "            self.bdpt_estimator(scene, sensor)\n            choice, why = \"bdpt\"",
     "            choice, why = \"bdpt\"", _T),
]
