"""Mutants of nee_path rr=adaptive (EARS roulette and splitting with path replication; see
tests/mutation.py for the format).  Each plants one plausible bug in the replication, the
weights or the learned policy's scale; tests/test_ears.py (or the test a mutant names) must
fail for every one (``python tests/mutation.py --only NAME``)."""

_S = "integrators/sampling/splitting.py"
_T = ["test_ears.py"]

MUTANTS = [
    # each copy weighted 1/ceil(n): roulette uncompensated, splits under-weighted
    ("ears-copy-weight-ceil", _S,
     "    return safe_div(1.0, n)\n", "    return safe_div(1.0, dr.ceil(n))\n", _T),
    # the copies of a split weighted by the rounded-up factor instead of their drawn count
    ("ears-split-weight-ceil", _S,
     "copy_weight(n), safe_div(1.0, mi.Float(m)))", "copy_weight(n), safe_div(1.0, dr.ceil(n)))",
     _T),
    # stochastic rounding biased towards floor(n): fewer copies than n on average
    ("ears-rounding-biased", _S,
     "counts = mi.UInt32(dr.floor(ns + u))", "counts = mi.UInt32(dr.floor(ns + 0.8 * u))", _T),
    # the weight forgets the lane cap's scale s (copies counted with s n, weighted 1/n)
    ("ears-cap-scale-not-in-weight", _S,
     'beta = dr.gather(mi.Spectrum, st["beta"] * split_weight(ns, counts), idx)',
     'beta = dr.gather(mi.Spectrum, st["beta"] * copy_weight(n), idx)', _T),
    # a copy's camera sample taken from the compressed parent list instead of the lane:
    # contributions land in other pixels
    ("ears-sample-index-of-rank", _S,
     'sid=dr.gather(mi.UInt32, st["sid"], idx),',
     'sid=dr.gather(mi.UInt32, st["sid"], rank),', _T),
    # emission found by the continuation without the path's throughput
    ("ears-emission-without-throughput", _S,
     "c = dr.select(act, beta * L_w, 0.0)", "c = dr.select(act, L_w, 0.0)", _T),
    # the light samples at the vertex a continuation reaches counted for every copy made there
    # later as well as now (weighted with the throughput before the BSDF sample)
    ("ears-light-samples-old-throughput", _S,
     "        c += beta * L_nee\n", "        c += beta / dr.maximum(w, 1e-3) * L_nee\n", _T),
    # one bounce too many (max_depth off by one)
    ("ears-depth-limit-off-by-one", _S,
     "alive = act_or_here & si_n.is_valid() & (depth + 1 < limit)\n        L_nee",
     "alive = act_or_here & si_n.is_valid() & (depth < limit)\n        L_nee", _T),
    # the tail's roulette without its 1/n
    ("ears-tail-roulette-uncompensated", _S,
     "            beta *= copy_weight(q)\n            if dr.hint(len(regs)",
     "            if dr.hint(len(regs)", _T),
    # the one-kernel roulette (classic / roulette passes) without its 1/n, at the first hit
    # and at the later vertices
    ("ears-kernel-first-hit-roulette-uncompensated", _S,
     "        beta *= w0\n", "", _T),
    ("ears-kernel-roulette-uncompensated", _S,
     "            beta *= copy_weight(q)\n            end = active & lnot(alive)",
     "            end = active & lnot(alive)", _T),
    # the copies of a split vertex start the tail without a BSDF sample of their own (they
    # would take the zeros the tail starts with, or, had it been kept, their parent's)
    ("ears-tail-copies-share-sample", _S,
     "            if fresh is not None:", "            if False:", _T),
    # the first hit's copies in the kernel: a copy after the first restarts without the copy
    # weight 1/n, or without light samples and a BSDF sample of its own at the first hit (it
    # would take the BSDF sample drawn at the vertex where the last copy ended)
    ("ears-kernel-copy-restarts-unweighted", _S,
     "beta = dr.select(restart, mi.Spectrum(w0), beta)",
     "beta = dr.select(restart, mi.Spectrum(1.0), beta)", _T),
    ("ears-kernel-copy-reuses-sample", _S,
     "            stay = restart\n", "            stay = mi.Bool(False)\n", _T),
    # contributions written instead of added: the copies of a camera sample overwrite each
    # other (and the first hit's emission)
    ("ears-contribution-overwrites", _S,
     'dr.scatter_reduce(dr.ReduceOp.Add, self.L, st["own"][0], st["sid"], flush,\n'
     '                              mode=DIRECT)',
     'dr.scatter(self.L, st["own"][0], st["sid"], flush)', _T),
    # batches sized for two lanes per camera sample whatever the last pass asked for: the lane
    # cap scales the factors down (no bias, but not the learned policy)
    ("ears-batch-ignores-demand", _S,
     "demand = min(max(self.ears.lane_demand, 2.0), 2.0 * self.ears.split_max + 1.0)",
     "demand = 2.0", _T),
    # the throughput rule (where nothing is learned) applied without dividing the survivors
    # by their survival probability
    ("ears-throughput-rule-uncompensated", _S,
     "        beta, survives = self.ears.throughput_roulette(",
     "        _, survives = self.ears.throughput_roulette(", _T),
    # the pixel means that scale the learned factors taken with the sensor's weight (in
    # spectral variants the wavelength sample's importance weight): no bias, but the learned
    # policy rouletted at rr_min everywhere in spectral variants (caught in test_variants.py)
    ("ears-pixel-with-sensor-weight", _S,
     "            lum = luminance(L)\n", "            lum = luminance(L * weight)\n",
     ["test_variants.py::test_spectral_learned_roulette_traces_as_in_rgb"]),
    # the plain fallback's estimate of the throughput rule: the rule applied to the learned
    # throughput instead of the classic one (cost read 3-4 % high), the second moment without
    # its cross terms between a path's vertices
    ("ears-classic-estimate-learned-beta", _S,
     "r = self.classic_survival(beta * rho, eta, depth, pre)",
     "r = self.classic_survival(beta, eta, depth, pre)",
     ["test_ears.py::test_throughput_rule_estimated_on_the_learned_paths"]),
    # ... or, at the vertices that keep the rule in the pass (glass, mirrors, nothing learned),
    # the pass's own roulette taken for the rule's (the review's find: specular_box)
    ("ears-classic-estimate-classic-vertex-shared", _S,
     "on = active & (q_pass > 0)",
     "on = active & (q_pass > 0) & lnot(classic)",
     ["test_ears.py::test_throughput_rule_estimated_on_the_learned_paths"]),
    ("ears-classic-estimate-no-cross-terms", _S,
     "lc * (bare * Q_s + 2.0 * S_s)", "lc * bare * Q_s",
     ["test_ears.py::test_throughput_rule_estimated_on_the_learned_paths"]),
    # split_policy=auto's estimate of the learned roulette on a split pass's first copies:
    # the first hit's 1/n kept (the roulette's second moment read low), every copy counted
    # (read high), the throughput rule taken for the learned roulette behind the first hit
    ("ears-roulette-estimate-copy-weight", _S,
     "predict_add(Y, S, K, luminance(c) * scale,", "predict_add(Y, S, K, luminance(c),",
     ["test_ears.py::test_roulette_estimated_on_the_split_paths"]),
    ("ears-roulette-estimate-every-copy", _S,
     "on = first if versus else mi.Bool(True)", "on = mi.Bool(True)",
     ["test_ears.py::test_roulette_estimated_on_the_split_paths"]),
    ("ears-roulette-estimate-rule-behind", _S,
     "alive & on, scale, raw if use_raw else None,", "alive & on, scale, None,",
     ["test_ears.py::test_roulette_estimated_on_the_split_paths"]),
    # the classic pass's estimate of the learned roulette (what decides under never / auto):
    # the table's factors not used (the rule estimated: the pass itself), the table's rule
    # vertices (glass, mirrors, null, nothing learned) taken for learned ones, the estimate
    # not read the other way round (the rule's gain over the roulette taken for the gain)
    ("ears-learned-estimate-rule", _S,
     'use_raw = alt in ("roulette", "learned")', 'use_raw = alt == "roulette"',
     ["test_ears.py::test_learned_roulette_estimated_on_the_classic_paths"]),
    ("ears-learned-estimate-rule-vertices-learned", _S,
     "            n_r = dr.select(classic, -1.0, n_r)\n", "",
     ["test_ears.py::test_learned_roulette_estimated_on_the_classic_paths"]),
    ("ears-learned-estimate-not-inverted", _S,
     "ratios = v * c / (np.maximum(v_c, 1e-30) * c_c)",
     "ratios = v_c * c_c / (max(v, 1e-30) * c)",
     ["test_ears.py::test_auto_policy_decisions"]),
    # ... read at the first scale only, not the largest; the scale not applied to the factors
    ("ears-learned-estimate-first-scale", _S,
     "j = int(np.argmax(ratios))", "j = 0",
     ["test_ears.py::test_auto_policy_decisions"]),
    ("ears-learned-estimate-unscaled", _S,
     "dr.clip(s * raw * rho, self.rr_min, 1.0)", "dr.clip(raw * rho, self.rr_min, 1.0)",
     ["test_ears.py::test_learned_roulette_estimated_on_the_classic_paths"]),
    # split_policy=auto: splitting kept whatever the split pass estimated; the plain fallback
    # decided before splitting was tried; splitting's gain left out of it
    ("ears-auto-split-kept-regardless", _S,
     'return "split" if self.split_gain >= SPLIT_COST else "roulette"', 'return "split"',
     ["test_ears.py::test_auto_policy_tries_splitting_then_keeps_what_pays"]),
    ("ears-auto-plain-before-split-trial", _S,
     "            if self.split_pending:      #", "            if False:      #",
     ["test_ears.py::test_auto_policy_decisions"]),
    ("ears-auto-plain-without-split-gain", _S,
     "best = max(self.gain, self.gain * ratio / SPLIT_COST)", "best = self.gain",
     ["test_ears.py::test_auto_policy_decisions"]),
    # ... splitting tried whatever the roulette gained (where no fallback ends the render)
    ("ears-auto-split-tried-regardless", _S,
     'return "split" if self.split_pending else "roulette"', 'return "split"',
     ["test_ears.py::test_auto_policy_decisions"]),
    # the estimated gains of the other film's passes kept when the film changes
    ("ears-gains-kept-on-new-film", _S,
     "            self.gain = self.split_gain = None\n", "",
     ["test_ears.py::test_learning_settles_then_records_nothing"]),
    # the settling's count of learned passes kept across a change of mode
    ("ears-settled-counts-other-mode", _S,
     "self.learned_passes = self.learned_passes + 1 if same else 1",
     "self.learned_passes = self.learned_passes + 1",
     ["test_ears.py::test_auto_policy_tries_splitting_then_keeps_what_pays"]),
    # the plain passes without roulette (rr=none): unbiased, but not the throughput rule the
    # learned one was compared with (the passes then differ from nee_path's)
    ("ears-plain-without-roulette", "integrators/plugins/nee_path.py",
     'roulette.Roulette.from_params(dict(self.params, rr="throughput")))',
     'roulette.Roulette.from_params(dict(self.params, rr="none")))', _T),
    # learning never stops: settled passes still record (and the factors move on)
    ("ears-settled-still-records", _S,
     "return self.learning and not self.settled and self.forced is None",
     "return self.learning and self.forced is None",
     ["test_ears.py::test_learning_settles_then_records_nothing"]),
    # a new film keeps the settled factors, relative to pixels it does not have
    ("ears-settled-kept-on-new-film", _S,
     "            self.settled, self.learned_passes = False, 0\n            if self.mode",
     "            self.learned_passes = 0\n            if self.mode",
     ["test_ears.py::test_learning_settles_then_records_nothing"]),
    # settled after any learned pass, however few copies the cells hold ...
    ("ears-settled-without-copies", _S,
     "self.learned_passes >= SETTLED_PASSES and\n"
     "                            median_copy_cell(st_f[:, 2]) >= SETTLED_COPIES)",
     "self.learned_passes >= SETTLED_PASSES)",
     ["test_ears.py::test_learning_settles_then_records_nothing"]),
    # ... or counted over the cells (the rarely visited ones as much as the busy ones: the dark
    # scene never settles)
    ("ears-settled-median-cell", _S,
     "return float(c[np.searchsorted(np.cumsum(c), 0.5 * c.sum())])",
     "return float(np.median(c))",
     ["test_ears.py::test_median_copy_cell"]),
    # ... or after the first learned pass (the policy and its statistics not converged)
    ("ears-settled-after-one-pass", _S,
     "self.learned_passes >= SETTLED_PASSES and", "self.learned_passes >= 1 and",
     ["test_ears.py::test_learning_settles_then_records_nothing"]),
    # the per-pixel state of one view kept for another of the same size
    ("ears-pixel-state-other-view", _S,
     "if self.shape != tuple(shape) or self.view != view:",
     "if self.shape != tuple(shape):",
     ["test_ears.py::test_pixel_state_follows_the_view"]),
    # the statistics read back of every cell, as if each had copies (the unvisited ones get
    # their parent's factors instead of the throughput rule)
    ("ears-read-back-every-cell", "integrators/sampling/learning.py",
     "vis = np.flatnonzero(st[:, column] > 0)",
     "vis = np.arange(self.size)",
     ["test_ears.py::test_statistics_read_back"]),
    # a plain part within a call with its lanes inactive (its samples black, weighted as
    # rendered)
    ("ears-plain-part-inactive", _S,
     "sample_copies(scene, sampler, ray, copies,",
     "sample_copies(scene, sampler, ray, copies, False,",
     ["test_ears.py::test_plain_part_within_a_call"]),
    # the copies' difference not halved (the copies' share of the variance read 4x)
    ("ears-copy-half-not-halved", "integrators/plugins/nee_path.py",
     "half = dr.select(count >= 2, 0.5 * diff, 0.0)", "half = dr.select(count >= 2, diff, 0.0)",
     ["test_ears.py::test_copy_trial_splits_the_variance"]),
    # the variance the copies share taken as the trial's variance less a whole copy's, not its
    # 1/k share (the copies' gain read high)
    ("ears-copy-shared-variance", _S,
     "self.copy_var = (float(x.sum()) / n - v1 / self.trial_copies, v1)",
     "self.copy_var = (float(x.sum()) / n - v1, v1)",
     ["test_ears.py::test_copy_trial_splits_the_variance"]),
    # the same in the choice of copies: k copies' variance predicted from the trial's less a
    # whole copy's share
    ("ears-copies-shared-variance", _S,
     "w = X + 2.0 * Y * (1.0 / k - 1.0 / k_trial)", "w = X + 2.0 * Y * (1.0 / k - 1.0)",
     ["test_ears.py::test_copies_lower_takes_the_bound"]),
    # the plain kernel's copies weighted 1/2 whatever their count
    ("ears-plain-copies-weight-two", "integrators/plugins/nee_path.py",
     "weight = dr.opaque(mi.Float, roulette.split_weight(copies))",
     "weight = dr.opaque(mi.Float, roulette.split_weight(2))",
     ["test_nee_path.py::test_split_k_at_spp_over_k_matches_split_1"]),
    # the copy trial's lanes of two copies weighted as one (its image too bright)
    ("ears-trial-copies-unweighted", "integrators/plugins/nee_path.py",
     "weight = roulette.split_weight(mi.Float(count))", "weight = mi.Float(1.0)",
     ["test_ears.py::test_plain_part_within_a_call"]),
    # every lane of the copy trial's pass in its block, the one-copy lanes too
    ("ears-trial-block-every-lane", _S,
     "                                          active=in_trial)",
     "                                          active=True)",
     ["test_ears.py::test_copy_trial_takes_the_first_samples_of_every_pixel"]),
    # the trial's samples the first n_trial lanes of the pass instead of every pixel's first
    ("ears-trial-layout-pixel-major", _S,
     "k = dr.select(in_trial, j % M, r // R)", "k = dr.select(in_trial, j // R, r // R)",
     ["test_ears.py::test_copy_trial_takes_the_first_samples_of_every_pixel"]),
    # the trial's lattice every pixel of every s-th row (its other pixels in the trial)
    ("ears-trial-lattice-rows", _S,
     "    on[::s, ::s] = True\n", "    on[::s, :] = True\n",
     ["test_ears.py::test_copy_trial_takes_the_first_samples_of_every_pixel"]),
    # a lattice whatever the film's filter (a wide filter's pooling then left out)
    ("ears-trial-lattice-any-filter", _S,
     "lattice = trial_pixels(h, w, film.rfilter().is_box_filter())",
     "lattice = trial_pixels(h, w)",
     ["test_ears.py::test_copy_trial_takes_the_first_samples_of_every_pixel"]),
    # the copy trial's gate with no variance left to the camera sample (V_0 = 0: the Cornell
    # box's trial run for copies that cannot pay)
    ("ears-trial-gate-v0-zero", _S,
     "CAMERA_COST, self.rule_cost - CAMERA_COST, TRIAL_V0, 1.0, self.split_max) > 1:",
     "CAMERA_COST, self.rule_cost - CAMERA_COST, 0.0, 1.0, self.split_max) > 1:",
     ["test_ears.py::test_copy_trial_gate"]),
    # the bound part's costs per camera sample whatever the trial's copies (its rule's cost
    # and bound read high)
    ("ears-bound-trial-per-camera-sample", _S,
     "share = total / (total + (self.ears.trial_copies - 1) * n_trial * lattice[2])",
     "share = 1.0",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the trial the bound part carried left unmeasured (the plain render then runs a trial
    # of its own)
    ("ears-bound-trial-unmeasured", _S,
     "        if trial and self.copy_trial:\n            self.measure_copies(spp)\n",
     "        if False:\n            self.measure_copies(spp)\n",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the copies chosen from the trial's estimate, not its lower confidence bound
    ("ears-copies-no-bound", _S,
     "gain = (R - z * se) * (a + b) / (a + b * k)", "gain = R * (a + b) / (a + b * k)",
     ["test_ears.py::test_copies_lower_takes_the_bound"]),
    # the trial part the first part's size (a sixteenth of the call in two copies)
    ("ears-trial-part-first-size", _S,
     "size = min(TRIAL_SAMPLES if trial else first if k == 0 else done, left)",
     "size = min(first if k == 0 or trial else done, left)",
     ["test_ears.py::test_copy_trial_takes_the_first_samples_of_every_pixel"]),
    # a call that starts with the copy trial always split into the trial and the rest (an
    # extra part's trace, whatever the call's length)
    ("ears-trial-part-unweighed", _S,
     "if (k > 0 or trial) and weigh:", "if k > 0 and weigh:",
     ["test_ears.py::test_parts_weigh_their_fixed_cost"]),
    # a bound part whatever the depth (where the throughput rule ends paths, a roulette may
    # lower the variance)
    ("ears-bound-any-depth", _S,
     "self.policy in (\"never\", \"auto\") and 0 <= self.max_depth <= self.rr_depth",
     "self.policy in (\"never\", \"auto\")",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the bound's first cost without the first hit's light samples (the bound read high)
    ("ears-bound-first-light-left-out", _S,
     "first = dr.select(active & (first < 0.0), shadow, first)",
     "first = dr.select(active & (first < 0.0), 0.0, first)",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the bound part's continuation rays not counted (its bound read low)
    ("ears-bound-rays-uncounted", _S,
     "return cost + dr.select(active, 1.0, 0.0), first", "return cost, first",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the bound against KERNEL_COST alone (a roulette pass run where at its best it gains
    # less than BOUND_LOSS over the plain kernel)
    ("ears-bound-no-margin", _S,
     "if self.gain_bound * (1.0 - BOUND_LOSS) < KERNEL_COST:",
     "if self.gain_bound < KERNEL_COST:",
     ["test_ears.py::test_bound_part_bounds_the_roulette_gain"]),
    # the parts of a call that decide the mode all of the first part's size (the split trial
    # as small as the classic part)
    ("ears-parts-not-doubling", _S,
     "size = min(TRIAL_SAMPLES if trial else first if k == 0 else done, left)",
     "size = min(TRIAL_SAMPLES if trial else first, left)",
     ["test_ears.py::test_auto_policy_tries_splitting_then_keeps_what_pays"]),
    # the first hit's light samples, in the megakernel, counted whole by the first copy where
    # it splits instead of weighted 1/n like the rest of it (the unit of its copies is the
    # light samples and the continuation), or weighted 1/n where roulette does not drop them
    ("ears-first-light-unweighted", _S,
     "c_nee = dr.select(n < 1.0, 1.0, w0) * L_nee", "c_nee = L_nee", _T),
    ("ears-first-light-rouletted", _S,
     "c_nee = dr.select(n < 1.0, 1.0, w0) * L_nee", "c_nee = w0 * L_nee", _T),
    # a restarting copy of the first hit takes no light samples there (the continuation alone)
    ("ears-restart-without-light", _S,
     "        c += beta * L_nee\n        return",
     "        c += dr.select(here, 0.0, beta) * L_nee if stay is not None else beta * L_nee\n"
     "        return", _T),
    # the replicated first bounce without the first hit's light samples
    ("ears-replicated-first-without-light", _S,
     'own = (state["own"][0] + c + c0, state["own"][1] + k + k0)',
     'own = (state["own"][0] + c, state["own"][1] + k + k0)', _T),
    # a deciding part split off whatever its fixed cost against the samples left
    ("ears-part-cost-ignored", _S,
     "if left * per_spp * (1.0 - 1.0 / max(KERNEL_COST, 1.0)) < fixed:",
     "if left * per_spp * (1.0 - 1.0 / max(KERNEL_COST, 1.0)) < 0.0:",
     ["test_ears.py::test_parts_weigh_their_fixed_cost"]),
    # the gain estimate's weights from the means that hold the pass's own samples
    ("ears-gain-denominators-own-samples", _S,
     "        if before.min() >= 1:\n", "        if False:\n",
     ["test_ears.py::test_gain_estimate_denominators"]),
    # the gain estimate's variances about the mean of all samples (the weights' among them)
    ("ears-gain-variance-all-samples", _S,
     "        if spp >= 2:\n            m = s1 / spp",
     "        if False:\n            m = s1 / spp",
     ["test_ears.py::test_gain_estimate_denominators"]),
    # learning settles while the split trial is still to run
    ("ears-settled-while-deciding", _S,
     "            if self.split_pending:\n"
     "                self.settled = False",
     "            if False:\n                self.settled = False",
     ["test_ears.py::test_no_settling_before_the_split_trial"]),
    # the learned roulette estimated (and deciding) before the pixels hold MATURE_SPP samples
    ("ears-estimate-before-mature", _S,
     'return self.policy not in ("never", "auto") or self.pix_n.min() >= MATURE_SPP',
     'return True',
     ["test_ears.py::test_auto_policy_decisions"]),
]
