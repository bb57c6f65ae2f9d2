"""Command line: renders write EXR + PNG atomically; bad input is one clear line, exit 2."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "veach_mis.xml"
SMALL = ["-D", "width=48", "-D", "height=27", "--spp", "4"]


def cli(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "integrators", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd or ROOT, env=env, timeout=300)


def test_render_writes_exr_and_png(tmp_path):
    out = tmp_path / "sub" / "veach.exr"
    r = cli("render", SCENE, *SMALL, "-o", out)
    assert r.returncode == 0, r.stderr
    assert out.is_file() and out.with_suffix(".png").is_file()
    import integrators  # noqa: F401
    from integrators.app.imageio import read_exr
    img = read_exr(out)
    assert img.shape == (27, 48, 3) and np.all(np.isfinite(img)) and img.max() > 0
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temp files


def test_defines_select_integrator(tmp_path):
    r = cli("render", SCENE, *SMALL, "-D", "heuristic=cutoff", "-D", "light_samples=3",
            "-o", tmp_path / "b.exr")
    assert r.returncode == 0, r.stderr
    r = cli("render", ROOT / "scenes" / "bsdf_path.xml", "--spp", "2", "-D", "hemisphere=cosine",
            "-o", tmp_path / "c.exr")
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("args,needle", [
    (["render", "missing.xml"], "scene file not found: missing.xml"),
    (["render", SCENE, "-D", "heuristic=foo"],
     "direct_mis: parameter 'heuristic' = 'foo' is invalid; allowed: one of balance"),
    (["render", SCENE, "-D", "light_samples=-2"],
     "parameter 'light_samples' = -2 is invalid; allowed: an integer >= 0"),
    (["render", SCENE, "-D", "light_selection=best"], "'light_selection' = 'best'"),
    (["render", SCENE, "-D", "light_samples=x"], "could not parse integer value \"x\""),
    (["render", SCENE, "--spp", "-3"], "--spp = -3 must be a positive integer"),
    (["render", SCENE, "-o", "/proc/forbidden/x.exr"], "cannot write"),
    (["render", SCENE, "-o", "x.png"], "must end in .exr"),
])
def test_bad_input_is_one_clear_line(args, needle):
    r = cli(*args)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert needle in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr


def test_usage_errors_are_one_line_without_the_usage_block():
    """argparse's usage block is gone: one line, status 2 (the corpus has many more)."""
    for args in (["render", SCENE, "--spp", "0"], ["render"], [], ["render", SCENE, "--sp", "8"]):
        r = cli(*args)
        assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
        assert r.stderr.startswith("error: ") and "usage:" not in r.stderr
    r = cli("render", "--help")
    assert r.returncode == 0 and "usage:" in r.stdout


def test_malformed_scene_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0">\n  <shape type="sphere">\n</scene>\n')
    r = cli("render", bad)
    assert r.returncode == 2 and "bad.xml" in r.stderr and "line" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_unknown_plugin_parameter(tmp_path):
    scene = tmp_path / "s.xml"
    scene.write_text('<scene version="3.0.0"><integrator type="bsdf_path">'
                     '<integer name="max_dept" value="3"/></integrator>'
                     '<shape type="sphere"/></scene>')
    r = cli("render", scene, "--spp", "1", "-o", tmp_path / "s.exr")
    assert r.returncode == 2
    assert "bsdf_path: unknown parameter 'max_dept'" in r.stderr, r.stderr


def test_list_prints_every_plugin_with_parameters():
    r = cli("list")
    assert r.returncode == 0, r.stderr
    for name in ["phong (bsdf)", "bsdf_path (integrator)", "direct_mis (integrator)",
                 "heuristic: choice (default: balance); one of balance, power, cutoff, maximum,"
                 " average, partition", "hemisphere: choice (default: bsdf)",
                 "beta: float (default: 2); a number > 0"]:
        assert name in r.stdout, r.stdout
