"""``python -m benchmarks run``: bad input ends in one line naming the problem (no traceback),
and a small quick run (the furnace, about 5 s) writes summary.json in the documented shape, charts and report."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def bench(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "benchmarks", "run", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def one_line_error(r, *words):
    assert r.returncode != 0
    err = r.stderr.strip()
    assert "Traceback" not in err, err
    for w in words:
        assert w in err, err


def test_unknown_scene():
    one_line_error(bench("--scenes", "nowhere"), "nowhere", "veach_mis")


def test_unknown_method():
    one_line_error(bench("--methods", "fastest"), "fastest", "nee_path")


def test_method_that_applies_to_no_requested_scene(tmp_path):
    r = bench("--scenes", "cornell_box", "--methods", "light_only", "--out", str(tmp_path))
    one_line_error(r, "light_only", "none applies")
    assert "skipped" in r.stdout
    assert not (tmp_path / "summary.json").exists()


def test_report_only_without_summary(tmp_path):
    one_line_error(bench("--report-only", "--out", str(tmp_path)), "summary.json", str(tmp_path))


def test_report_only_rejects_run_options(tmp_path):
    one_line_error(bench("--report-only", "--quick", "--out", str(tmp_path)), "--report-only")


def test_quick_run_writes_the_documented_outputs(tmp_path):
    r = bench("--quick", "--scenes", "furnace", "--methods", "bsdf_path", "--out", str(tmp_path),
              "--cache", str(tmp_path / "cache"), timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    sc = summary["scenes"]["furnace"]
    assert set(sc["reference"]) == {"path"}
    assert sc["reference"]["path"]["check_vs_closed_form"]["inside_passed"]
    for label in ("path", "bsdf_path"):            # the baseline is always kept
        m = sc["methods"][label]
        assert m["integrator"]["type"] == label
        assert len(m["points"]) == 8
        for p in m["points"]:
            assert {"spp", "time_s", "rmse", "relmse", "flip"} <= set(p)
    assert sc["methods"]["bsdf_path"]["integrator"]["hemisphere"] == "bsdf"  # defaults resolved
    for f in ("report.md", "furnace_chart.png", "furnace_path_grid.png"):
        assert (tmp_path / f).stat().st_size > 0
