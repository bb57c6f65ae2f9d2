"""``python -m benchmarks run``: bad input ends in one line naming the problem (no traceback),
and a small quick run (the furnace, about 5 s) writes summary.json in the documented shape, charts and report.
The references are Mitsuba's own ``path`` and their cache key follows the run record (a changed
scene file gives a new key)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from benchmarks import config

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
    ref = sc["reference"]["path"]
    assert ref["integrator"] == {"type": "path", "max_depth": 4}       # Mitsuba's own path
    assert ref["record"]["integrator"] == "PathIntegrator"
    assert ref["key"] in Path(ref["file"]).name
    assert Path(ref["file"]).with_suffix(".json").is_file()            # the record next to it
    assert summary["meta"]["command"].startswith("python -m benchmarks run --quick")
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


def test_help_of_every_command():
    for cmd in ("run", "speed", "efficiency", "memory"):
        r = subprocess.run([sys.executable, "-m", "benchmarks", cmd, "--help"], cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith(f"usage: python -m benchmarks {cmd}"), r.stdout[:200]


def test_reference_integrator_is_mitsubas_path():
    """No estimator under test renders a reference: every group's is Mitsuba's ``path`` at the
    group's max_depth (2: direct light), and the run record says so."""
    for g in config.GROUPS.values():
        assert config.reference_integrator(g["max_depth"]) == {"type": "path",
                                                               "max_depth": g["max_depth"]}
    from benchmarks import references
    spec = references.ReferenceSpec("furnace", config.scene_file("furnace"), {"res": "8"}, 8, 8,
                                    config.DIRECT_DEPTH, 64, 16, 0)
    rec = spec.record()
    assert rec.integrator == "PathIntegrator"
    assert "max_depth = 2" in rec.params["description"]


def _spec(path, **kw):
    from benchmarks import references
    return references.ReferenceSpec(**{"name": "sharp_glossy", "scene_path": path,
                                       "defines": {"res": "16"}, "width": 16, "height": 16,
                                       "max_depth": 4, "spp": 256, "passes": 16,
                                       "seed_first": 1_000_000, **kw})


def test_reference_cache_key_follows_the_scene_file(tmp_path):
    scene = tmp_path / "sharp_glossy.xml"
    shutil.copy(config.scene_file("sharp_glossy"), scene)
    key = _spec(scene).key()
    assert _spec(scene).key() == key                                   # stable
    assert key in _spec(scene).stem()
    text = scene.read_text()
    scene.write_text(text.replace('value="5000"', 'value="4000"'))     # the Phong exponent
    assert text != scene.read_text()
    assert _spec(scene).key() != key
    scene.write_text(text)
    assert _spec(scene).key() == key
    # and the other inputs of the render
    for kw in ({"defines": {"res": "17"}}, {"max_depth": 2}, {"spp": 512}, {"seed_first": 0},
               {"width": 32}):
        assert _spec(scene, **kw).key() != key, kw
