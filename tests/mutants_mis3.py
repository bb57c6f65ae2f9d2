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
     "np.maximum(second - spread * (mean_l ** 2 / c + (mean - mean_l) ** 2), 0.0)",
     "np.maximum(second - spread * mean ** 2, 0.0)", ["test_mis3_learned.py"]),
    # the learning statistics of a BSDF-sampled emission hit with the vertex's weight applied
    # twice (the pre-update throughput aliased by the in-place update: the bug before stop 30)
    ("learned-hit-weight-twice", "integrators/sampling/vertex.py",
     "learner.record_hit(cell, beta, L_e, pdf_e, d.bs.pdf, p_l,",
     "learner.record_hit(cell, beta * d.weight, L_e, pdf_e, d.bs.pdf, p_l,",
     ["test_mis3_learned.py"]),
    # the recorded paths ignored: the rest of the pixel sample back to the stand-in
    ("learned-rest-of-path-ignored", "integrators/plugins/mis3.py",
     "have = n_p >= LEARN_MIN_PATHS", "have = n_p < 0", ["test_mis3_learned.py"]),
    # the pooled variance taken as the vertex's noise (the spread between points ignored)
    ("learned-spread-ignored", "integrators/plugins/mis3.py",
     "var = allocation_variance(second, mean, mean_l, spread=spread)",
     "var = allocation_variance(second, mean, mean_l, spread=1.0)", ["test_mis3_learned.py"]),
    # one light estimate squared instead of the product of two independent ones
    ("learned-pair-not-independent", "integrators/plugins/mis3.py",
     "self.grid.add(idx, {PATH_STATS + 4: z[0] * z[1]}, act)",
     "self.grid.add(idx, {PATH_STATS + 4: z[0] * z[0]}, act)", ["test_mis3_learned.py"]),
]
