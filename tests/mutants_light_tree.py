"""Mutants of the light tree (light_selection=bvh; see tests/mutation.py for the format)."""

T = "integrators/sampling/light_tree.py"
TESTS = ["test_light_tree.py"]

MUTANTS = [
    # the pmf walk follows the trail but takes the sibling's share: pmf_at no longer what
    # traversal did
    ("tree-pmf-sibling-share", T,
     "chosen = dr.select(right, i1, i0)",
     "chosen = dr.select(right, i0, i1)", TESTS),
    # traversal goes left half the time whatever the importances, reporting the ratio: biased
    ("tree-traverse-ignores-importance", T,
     "left = u < p0",
     "left = u < 0.5", TESTS),
    # the uniform number is not rescaled after a decision: later choices correlated with it
    ("tree-u-not-rescaled", T,
     "u = dr.select(left, u / dr.select(left, p0, 1.0),\n"
     "                          (u - p0) / dr.select(left, 1.0, 1.0 - p0))",
     "u = dr.select(left, u, u)", TESTS),
    # the emission-cone test rules out lights that can still shine on x: biased low
    ("tree-cone-test-too-tight", T,
     'imp = dr.select(cos_p > g["cos_e"] - COS_E_SLACK, imp, 0.0)',
     'imp = dr.select(cos_p > g["cos_e"] + 0.3, imp, 0.0)', TESTS),
    # a parent's cone is its first child's only (not conservative)
    ("tree-cone-union-dropped", T,
     "tree.w[nd], tree.cos_o[nd] = cone_union(tree.w[a], tree.cos_o[a], w2, c2)",
     "tree.w[nd], tree.cos_o[nd] = tree.w[a], tree.cos_o[a]", TESTS),
    # a parent's box is its first child's only (not conservative)
    ("tree-box-union-dropped", T,
     "tree.lo[nd] = np.minimum(tree.lo[a], tree.lo[b2])",
     "tree.lo[nd] = tree.lo[a]", TESTS),
    # the split cost without the right side's term: every split cuts off the first bucket,
    # the tree twice as deep and its choices worse
    ("tree-split-cost-left-side-only", T,
     "    cost = (left + right) * kr[:, :, None]",
     "    cost = left * kr[:, :, None]", TESTS),
    # the device record's sphere: pbrt's half diagonal, but about the weighted centre (not
    # the box's): it no longer holds the box, the bound is no bound
    ("tree-record-radius-half-diagonal", T,
     "r = np.sqrt((far ** 2).sum(-1))",
     "r = 0.5 * np.sqrt(((tree.hi - tree.lo) ** 2).sum(-1))", TESTS),
    # the probability of the tree (1 - p_inf) left out of the reported pmf of a tree light
    ("tree-pmf-without-tree-probability", T,
     "pmf = dr.select(use_inf, p_j, (1.0 - p_inf) * pmf_t)",
     "pmf = dr.select(use_inf, p_j, pmf_t)", TESTS),
    # the importance forgets the distance: still unbiased, but no better than power
    ("tree-importance-without-distance", T,
     "imp = dr.abs(phi) * dr.maximum(cos_p, RECEIVER_FLOOR) * inv_d2",
     "imp = dr.abs(phi) * dr.maximum(cos_p, RECEIVER_FLOOR)", TESTS),
    # ris: the resampled weight without 1/M (the mean of the candidates' weights): too bright
    ("ris-weight-without-candidate-mean", T,
     "ratio = dr.select(ok, p_y * w_sum / (m * dr.select(ok, h_y, 1.0)), 1.0)",
     "ratio = dr.select(ok, p_y * w_sum / dr.select(ok, h_y, 1.0), 1.0)", TESTS),
    # ris: the reservoir's uniform is not rescaled after a decision: the kept candidate is no
    # longer drawn in proportion to its weight
    ("ris-reservoir-v-not-rescaled", T,
     "v = dr.select(take, v / dr.select(take, q, 1.0),\n"
     "                  (v - q) / dr.select(take | (q >= 1.0), 1.0, 1.0 - q))",
     "v = dr.select(take, v, v)", TESTS),
    # ris: the tree's weight 1 / p(Y) on the resampled choice
    ("ris-tree-weight-on-resampled-choice", T,
     "return emitter, sel, None, dr.select(ok, sel / dr.select(ok, ratio, 1.0), 0.0)",
     "return emitter, sel, None, dr.select(ok, sel, 0.0)", TESTS),
    # ris with the BSDF (resampled by the unshadowed contribution): the kept sample's direction
    # with the last candidate's emitter weight
    ("ris-contribution-weight-of-last-candidate", T,
     "weight = dr.select(take, we_k, weight)",
     "weight = we_k", TESTS),
    # ris with the BSDF: the weight without 1/M
    ("ris-contribution-without-candidate-mean", T,
     "weight = dr.select(ok, weight * (w_sum / (m * dr.select(ok, h_y, 1.0))), 0.0)",
     "weight = dr.select(ok, weight * (w_sum / dr.select(ok, h_y, 1.0)), 0.0)", TESTS),
    # the vectorised power kernel assigns samples to the wrong emitters
    ("power-samples-mixed-between-emitters", "integrators/sampling/light_selection.py",
     "mi.UInt32(np.repeat(idx, k).astype(np.uint32))",
     "mi.UInt32(np.tile(idx, k).astype(np.uint32))", ["test_light_selection.py", *TESTS]),
    # stratified next-event estimation: the light samples of a vertex independent again
    # whatever STRATIFY says (unbiased: the variance test must see the loss)
    ("nee-light-samples-not-stratified", "integrators/sampling/vertex.py",
     "        if not self.STRATIFY:", "        if True:", ["test_light_selection_variance.py"]),
    # a rotated uniform clamped below one instead of wrapped: the later strata pile up on the
    # last light of the cumulative pmf (biased)
    ("stratum-not-wrapped", "integrators/sampling/light_selection.py",
     "return dr.minimum(dr.select(uk >= 1.0, uk - 1.0, uk), ONE_MINUS_EPS)",
     "return dr.minimum(uk, ONE_MINUS_EPS)",
     ["test_light_selection_variance.py", "test_direct_mis.py", *TESTS]),
]
