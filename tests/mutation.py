"""Mutation harness: plant known biases in a temporary copy of the package and check that the
test suite catches (kills) every one.

    python tests/mutation.py [--only NAME ...] [--list]

Each mutant is a textual patch of one source file.  For each, the package and tests are copied
to a temporary directory, the patch is applied (it must match exactly once, so a refactor that
moves the code makes the harness fail loudly instead of testing nothing), and pytest runs
against the copy: first the test files that target the mutated code, then, if they pass, the
whole default suite; any failure kills the mutant.  The last line is ``killed K of M``; the
exit status is 0 only when every mutant was killed.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (name, file, original text, mutated text, test files that target it)
MUTANTS = [
    ("rr-no-compensation", "integrators/sampling/roulette.py",
     "beta = dr.select(rr_active, beta * dr.rcp(dr.select(q > 0, q, 1.0)), beta)",
     "beta = dr.select(rr_active, beta, beta)", ["test_bsdf_path.py", "test_nee_path.py"]),
    ("rr-survival-off", "integrators/sampling/roulette.py",
     "return beta, active & (lnot(rr_active) | (u < q))",
     "return beta, active & (lnot(rr_active) | (u < 0.9 * q))", ["test_nee_path.py"]),
    ("mis-weights-sum-1.05", "integrators/sampling/mis.py",
     "return [x * inv_total for x in s]",
     "return [x * inv_total * 1.05 for x in s]", ["test_mis.py", "test_direct_mis.py"]),
    ("mis-densities-without-sample-counts", "integrators/sampling/vertex.py",
     "self.heur.weight(0, [scale * ls.ds.pdf, *q_bsdf])",
     "self.heur.weight(0, [ls.ds.pdf, *q_bsdf])", ["test_direct_mis.py"]),
    ("light-pdf-without-selection", "integrators/sampling/light_selection.py",
     "return dr.select(active & (sel > 0), pdf * sel, 0.0)",
     "return dr.select(active & (sel > 0), pdf, 0.0)",
     ["test_direct_mis.py", "test_light_selection_variance.py"]),
    ("light-samples-not-divided-by-count", "integrators/sampling/vertex.py",
     "        return L / self.n_l\n", "        return L\n", ["test_direct_mis.py"]),
    ("phong-missing-cosine", "integrators/plugins/phong.py",
     "return dr.select(active, value * cos_o, 0.0)",
     "return dr.select(active, value, 0.0)", ["test_phong.py"]),
    ("phong-normalisation-e+1", "integrators/plugins/phong.py",
     "value += self.ks.eval(si, active) * ((self.exponent + 2.0) * dr.inv_two_pi * lobe)",
     "value += self.ks.eval(si, active) * ((self.exponent + 1.0) * dr.inv_two_pi * lobe)",
     ["test_phong.py"]),
    ("phong-sampling-exponent", "integrators/plugins/phong.py",
     "cos_a = dr.power(sample2.x, 1.0 / (self.exponent + 1.0))",
     "cos_a = dr.power(sample2.x, 1.0 / (self.exponent + 2.0))", ["test_phong.py"]),
    ("split-weight-1/(k-1)", "integrators/sampling/roulette.py",
     "    return 1.0 / k\n", "    return 1.0 / max(k - 1, 1)\n", ["test_nee_path.py"]),
    ("cosine-pdf-off", "integrators/sampling/techniques.py",
     "pdf = wo.z * dr.inv_pi", "pdf = wo.z * dr.inv_two_pi", ["test_bsdf_path.py"]),
    ("mis3-light-without-p3", "integrators/plugins/mis3.py",
     "L += beta * safe_div(vx.light_term(ls, f, q_b, light_scale=p3), p3)",
     "L += beta * vx.light_term(ls, f, q_b, light_scale=p3)", ["test_mis3.py"]),
    ("adaptive-pmf-not-normalised", "integrators/sampling/light_selection.py",
     "return (1.0 - DEFENSIVE) * adaptive + DEFENSIVE * p_power",
     "return adaptive + DEFENSIVE * p_power", ["test_light_selection_variance.py"]),
    ("adaptive-reservoir-skewed", "integrators/sampling/light_selection.py",
     "take = u < p\n", "take = u < p * 0.9\n", ["test_light_selection_variance.py"]),
    ("adaptive-stale-norm", "integrators/sampling/light_selection.py",
     "total = self._total(si) if norm is None else norm\n",
     "total = self._total(si) if norm is None else norm * 1.1\n",
     ["test_light_selection_variance.py", "test_nee_path.py", "test_mis3.py"]),
    # ---- issue 13: transmitting and back-facing surfaces, roulette through glass -------------
    ("hemisphere-back-side-ignored", "integrators/sampling/techniques.py",
     "side = dr.select(mi.Frame3f.cos_theta(si.wi) < 0, -1.0, 1.0)",
     "side = mi.Float(1.0)", ["test_furnace.py"]),
    ("hemisphere-never-transmits", "integrators/sampling/techniques.py",
     "flip = sphere & (s1 < 0.5)", "flip = sphere & (s1 < 0.0)", ["test_furnace.py"]),
    ("hemisphere-sphere-pdf-not-halved", "integrators/sampling/techniques.py",
     "pdf = pdf * dr.select(sphere, 0.5, 1.0)", "pdf = pdf * dr.select(sphere, 1.0, 1.0)",
     ["test_furnace.py"]),
    ("hemisphere-delta-eta-dropped", "integrators/sampling/techniques.py",
     "eta = dr.select(use_bsdf, bs.eta, eta)", "eta = dr.select(use_bsdf, 1.0, eta)",
     ["test_furnace.py"]),
    ("path-eta-not-accumulated", "integrators/sampling/vertex.py",
     "            eta *= d.bs.eta\n", "            eta = d.bs.eta\n", ["test_furnace.py"]),
    ("rr-eta-dropped", "integrators/sampling/roulette.py",
     "q = dr.minimum(beta_max * dr.square(eta), 0.95)", "q = dr.minimum(beta_max, 0.95)",
     ["test_furnace.py"]),
    ("rr-compensation-without-eta", "integrators/sampling/roulette.py",
     "beta = dr.select(rr_active, beta * dr.rcp(dr.select(q > 0, q, 1.0)), beta)",
     "q_c = q if mode == 'fixed' else dr.minimum(beta_max, 0.95)\n"
     "    beta = dr.select(rr_active, beta * dr.rcp(dr.select(q_c > 0, q_c, 1.0)), beta)",
     ["test_furnace.py"]),
    ("rr-throughput-not-clamped", "integrators/sampling/roulette.py",
     "q = dr.minimum(beta_max * dr.square(eta), 0.95)", "q = beta_max * dr.square(eta)",
     ["test_furnace.py"]),
    # ---- mis3 through specular and glossy chains -------------------------------------------
    ("mis3-delta-lobe-weight", "integrators/plugins/mis3.py",
     "base = dr.select(own, w_own, safe_div(",
     "base = dr.select(own, 0.5 * w_own, safe_div(", ["test_specular.py"]),
    ("mis3-glossy-continuation-weight", "integrators/plugins/mis3.py",
     "w_cont = dr.select(own, 1.0, dr.select(use_1, w_lobe[0], w_lobe[1]))",
     "w_cont = dr.select(own, 1.0, dr.select(use_1, w_lobe[0], 1.0))", ["test_specular.py"]),
    # ---- the progressive variance layer ----------------------------------------------------
    ("variance-layer-scale-12%", "integrators/app/progressive.py",
     "        return sigma2 / self.spp\n", "        return 1.12 * sigma2 / self.spp\n",
     ["test_variance_layer.py"]),
    ("merged-variance-passes", "integrators/app/progressive.py",
     "self.s2 + other.s2, rec.spp, rec.passes,", "self.s2 + other.s2, rec.spp, rec.passes + 2,",
     ["test_variance_layer.py"]),
    ("merge-from-file-passes", "integrators/app/progressive.py",
     "s2 = sigma2 * max(passes - 1, 0) + spp * mean * mean",
     "s2 = sigma2 * passes + spp * mean * mean", ["test_variance_layer.py"]),
    # ---- MIS parameter edges ---------------------------------------------------------------
    ("cutoff-alpha-1-drops-all", "integrators/sampling/mis.py",
     "s = [dr.select((x > 0) & (x >= self.alpha), x, 0.0) for x in r]",
     "s = [dr.select((x > 0) & (x > self.alpha), x, 0.0) for x in r]",
     ["test_parameter_edges.py"]),
    ("power-heuristic-unnormalised", "integrators/sampling/mis.py",
     "s = [dr.select(x > 0, dr.power(x, self.beta), 0.0) for x in r]",
     "s = [dr.select(x > 0, dr.power(x * qmax, self.beta), 0.0) for x in r]",
     ["test_parameter_edges.py"]),
    # ---- scene features (issue 12) ---------------------------------------------------------
    ("hide-emitters-ignored", "integrators/plugins/base.py",
     'if not self.params.get("hide_emitters", False):', "if True:",
     ["test_scene_features.py"]),
    # ---- mis3: every path continues, learned light probability (issue 14) -----------------
    ("mis3-lobe-choice-not-renormalised", "integrators/plugins/mis3.py",
     "pi1 = safe_div(p1, p1 + p2)\n", "pi1 = safe_div(p1, p1 + p2 + p3)\n",
     ["test_mis3_continuation.py", "test_mis3.py"]),
    ("stochastic-nee-not-divided", "integrators/sampling/vertex.py",
     "L = safe_div(self.light_term(ls, f_l, [self.n_b * pdf_l], scale), scale)",
     "L = self.light_term(ls, f_l, [self.n_b * pdf_l], scale)",
     ["test_mis3_learned.py"]),
    ("learned-emission-weight-without-p", "integrators/sampling/vertex.py",
     "scale = d.light_scale if learn else None", "scale = None", ["test_mis3_learned.py"]),
]


def _topic_mutants() -> list:
    """Mutants kept beside their tests: every ``tests/mutants_<topic>.py`` defines ``MUTANTS`` in
    the same (name, file, original, mutated, targets) form."""
    import importlib.util
    found = []
    for f in sorted((ROOT / "tests").glob("mutants_*.py")):
        spec = importlib.util.spec_from_file_location(f.stem, f)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        found.extend(mod.MUTANTS)
    return found


MUTANTS = MUTANTS + _topic_mutants()


def run_pytest(root: Path, files, env) -> tuple[str, str]:
    """'pass', 'fail' (a test failed: the mutant is caught) or 'error' (crash, collection or
    fixture error: that is no evidence the suite sees the bias, so it does not count)."""
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *files]
    r = subprocess.run(cmd, cwd=root / "tests", env=env, capture_output=True, text=True)
    tail = [ln for ln in r.stdout.strip().splitlines() if ln.strip()]
    line = tail[-1] if tail else r.stderr.strip()[-200:]
    if r.returncode == 0:
        return "pass", line
    if r.returncode == 1 and "failed" in line and "error" not in line:
        return "fail", line
    return "error", line


def run_mutant(name, path, old, new, targets) -> tuple[bool, str]:
    with tempfile.TemporaryDirectory(prefix="mutant-") as tmp:
        root = Path(tmp)
        for part in ("integrators", "tests", "scenes", "benchmarks"):
            shutil.copytree(ROOT / part, root / part,
                            ignore=shutil.ignore_patterns("__pycache__", "results"))
        src = root / path
        text = src.read_text()
        if text.count(old) != 1:
            raise SystemExit(f"mutant {name}: the original text occurs {text.count(old)} times "
                             f"in {path}; update tests/mutation.py")
        src.write_text(text.replace(old, new))
        env = dict(os.environ, PYTHONPATH=str(root), PYTHONDONTWRITEBYTECODE="1")
        outcome, line = run_pytest(root, targets, env)
        if outcome == "pass":
            outcome, line = run_pytest(root, [], env)
        return outcome, line


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="run only these mutants")
    ap.add_argument("--list", action="store_true", help="list the mutants")
    ap.add_argument("--control", action="store_true",
                    help="first run the suite on an unmutated copy (it must pass)")
    a = ap.parse_args(argv)
    mutants = [m for m in MUTANTS if not a.only or m[0] in a.only]
    if a.list:
        for m in mutants:
            print(f"{m[0]:40s} {m[1]}")
        return 0
    if a.control:
        outcome, line = run_mutant("control", "integrators/sampling/mis.py", "HEURISTICS = (",
                                   "HEURISTICS = (", [])
        print(f"control (unmutated copy): {outcome} ({line})", flush=True)
        if outcome != "pass":
            return 1
    killed = 0
    for name, path, old, new, targets in mutants:
        t0 = time.perf_counter()
        outcome, line = run_mutant(name, path, old, new, targets)
        killed += outcome == "fail"
        word = {"fail": "killed  ", "pass": "SURVIVED", "error": "ERROR   "}[outcome]
        print(f"{word} {name:40s} {time.perf_counter() - t0:6.1f} s  ({line})", flush=True)
    print(f"killed {killed} of {len(mutants)}")
    return 0 if killed == len(mutants) else 1


if __name__ == "__main__":
    raise SystemExit(main())
