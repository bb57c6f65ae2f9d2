"""Mutants of mis3's learned light-sample allocation (see tests/mutation.py for the format)."""

MUTANTS = [
    # one light sample too many where a vertex takes more than one: biased high
    ("allocation-one-extra-sample", "integrators/sampling/vertex.py",
     "count = dr.select(more, mi.UInt32(m), 1)",
     "count = dr.select(more, mi.UInt32(m) + 1, 1)", ["test_mis3_learned.py"]),
    # the emission found by the BSDF sample weighted as if one light sample was taken
    ("allocation-emission-weight-count-1", "integrators/sampling/vertex.py",
     "scale = d.light_scale if learn else None",
     "scale = dr.minimum(d.light_scale, 1.0) if learn else None", ["test_mis3_learned.py"]),
    # the lobe densities unclamped: roughplastic's diffuse-only pdf is negative below the horizon
    ("lobe-density-unclamped", "integrators/plugins/mis3.py",
     "q_d = pi1 * dr.maximum(bsdf.pdf(ctx_d, si, wo, active), 0.0) if has_d else zero",
     "q_d = pi1 * bsdf.pdf(ctx_d, si, wo, active) if has_d else zero",
     ["test_mis3_continuation.py"]),
    # the learned allocation's variance model back to M - mu^2 (negative wherever both
    # techniques share the mean: every allocation then looked free of variance)
    ("allocation-variance-minus-mean-squared", "integrators/plugins/mis3.py",
     "np.maximum(second - (light / c + (mean - mean_l) ** 2), 0.0)",
     "np.maximum(second - mean ** 2, 0.0)", ["test_mis3_learned.py"]),
    # the learning statistics of a BSDF-sampled emission hit with the vertex's weight applied
    # twice (the pre-update throughput aliased by the in-place update: the bug before stop 30)
    ("learned-hit-weight-twice", "integrators/sampling/vertex.py",
     "learner.record_hit(cell, beta, L_e, pdf_e, d.bs.pdf, p_l,",
     "learner.record_hit(cell, beta * d.weight, L_e, pdf_e, d.bs.pdf, p_l,",
     ["test_mis3_learned.py"]),
    # the recorded paths ignored: the rest of the pixel sample back to the stand-in
    ("learned-rest-of-path-ignored", "integrators/plugins/mis3.py",
     "have = n_p >= LEARN_MIN_PATHS", "have = n_p < 0", ["test_mis3_learned.py"]),
    # the light share's squared mean between points ignored: the pooled variance read as noise
    ("learned-pairs-ignored", "integrators/plugins/mis3.py",
     "sq_l = st[:, PAIRS:PAIRS + k] / nn if LEARN_PAIRS else None", "sq_l = None",
     ["test_mis3_learned.py"]),
    # one light estimate squared instead of the product of two independent ones
    ("learned-pair-not-independent", "integrators/plugins/mis3.py",
     "self.grid.add(idx, {PAIRS + j: z[0][j] * z[1][j] for j in range(len(LEARNED_P))}, act)",
     "self.grid.add(idx, {PAIRS + j: z[0][j] * z[0][j] for j in range(len(LEARNED_P))}, act)",
     ["test_mis3_learned.py"]),
    # the margin that protects one light sample also against candidates above one (whose
    # estimates are not heavy-tailed): allocations that pay up to 20 % are refused
    ("learned-margin-above-one", "integrators/plugins/mis3.py",
     "below = cand[arg] < 1.0   # (the margin", "below = cand[arg] > 0.0   # (the margin",
     ["test_mis3_learned.py"]),
    # the image's objective: every region's pixel weight read as one
    ("learned-image-weight-ignored", "integrators/plugins/mis3.py",
     "w_r = np.where(weighed > 0, st[:, WEIGHT] / np.maximum(weighed, 1.0),",
     "w_r = np.where(weighed > 0, 1.0,", ["test_mis3_learned.py"]),
    # the image's rate V / C as measured, not as the new decisions will make it
    ("learned-image-rate-not-iterated", "integrators/plugins/mis3.py",
     "lam = max(v_img + dv, 0.1 * v_img) / max(c_img + dc, 0.1 * c_img)",
     "lam = v_img / c_img", ["test_mis3_learned.py"]),
    # a recording visit adds weight one instead of its pixel's
    ("learned-image-visit-unweighted", "integrators/plugins/mis3.py",
     "visit[WEIGHT] = dr.gather(mi.Float, self.pixels.weights(), self._pixel, record)",
     "visit[WEIGHT] = mi.Float(1.0)", ["test_mis3_learned.py"]),
    # the pixels' statistics kept for another view of the same film size (as before
    # 2026-12-06: keyed on the pixel count): a moved sensor's visits weighed by the old image
    ("learned-pixels-other-view", "integrators/sampling/learning.py",
     "if stats is not None and stats.view == view:",
     "if stats is not None and stats.n == cls.layout(sensor):", ["test_mis3_learned.py"]),
]
