"""Progressive rendering: passes, time budget, SIGINT, checkpoints, header, variance, merge."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import integrators  # noqa: F401
from integrators.app import progressive
from integrators.app.imageio import read_layers

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "veach_mis.xml"
SMALL = ["-D", "width=64", "-D", "height=36"]


def cli(*args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "integrators", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=300, **kw)


def test_header_and_layers(tmp_path):
    out = tmp_path / "a.exr"
    r = cli("render", SCENE, *SMALL, "--spp", 16, "--seed", 7, "-o", out)
    assert r.returncode == 0, r.stderr
    layers, meta = read_layers(out)
    assert set(layers) == {"", "variance"} and layers[""].shape == (36, 64, 3)
    assert meta["spp"] == 16 and meta["passes"] >= 2
    assert meta["seed_first"] == 7 and meta["seed_last"] == 7 + meta["passes"] - 1
    assert meta["integrator"] == "direct_mis" and meta["variant"] == "llvm_ad_rgb"
    assert np.all(layers["variance"] >= 0) and layers["variance"].max() > 0


def test_time_budget_stops_within_one_pass(tmp_path):
    t0 = time.perf_counter()
    r = cli("render", SCENE, *SMALL, "--time", 2, "-o", tmp_path / "t.exr")
    wall = time.perf_counter() - t0
    assert r.returncode == 0, r.stderr
    seconds = float(read_layers(tmp_path / "t.exr")[1]["seconds"])
    assert 2.0 <= seconds < 2.0 + 1.5, seconds   # passes last ~0.25 s
    assert wall < 30


def test_sigint_writes_what_was_accumulated(tmp_path):
    out = tmp_path / "i.exr"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "integrators", "render", str(SCENE), *SMALL,
                          "--time", "60", "-o", str(out)], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(6)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, (p.returncode, stderr)
    assert "Traceback" not in stderr and "SIGINT" in stderr
    layers, meta = read_layers(out)
    assert int(meta["spp"]) > 0 and np.all(np.isfinite(layers[""]))
    assert float(meta["seconds"]) < 55


def test_checkpoint_written_during_render(tmp_path):
    out = tmp_path / "c.exr"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "integrators", "render", str(SCENE), *SMALL,
                          "--time", "8", "--checkpoint", "1", "-o", str(out)], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = None
    t0 = time.time()
    while p.poll() is None and time.time() - t0 < 60:
        if out.exists():
            seen = int(read_layers(out)[1]["spp"])
            break
        time.sleep(0.2)
    p.communicate(timeout=60)
    assert p.returncode == 0
    assert seen is not None and seen < int(read_layers(out)[1]["spp"])


def test_merge_is_sample_weighted_mean(tmp_path):
    a, b, m = tmp_path / "a.exr", tmp_path / "b.exr", tmp_path / "m.exr"
    assert cli("render", SCENE, *SMALL, "--spp", 8, "--seed", 0, "-o", a).returncode == 0
    assert cli("render", SCENE, *SMALL, "--spp", 24, "--seed", 100, "-o", b).returncode == 0
    r = cli("merge", a, b, "-o", m)
    assert r.returncode == 0, r.stderr
    la, lb, lm = (read_layers(p) for p in (a, b, m))
    expected = (8 * la[0][""].astype(np.float64) + 24 * lb[0][""]) / 32
    assert np.allclose(lm[0][""], expected, rtol=1e-5, atol=1e-6)
    assert lm[1]["spp"] == 32 and lm[1]["seed_first"] == 0
    # the merged variance is that of the merged estimate, pooled over every pass: exactly the
    # pooled algebra of the two parts (sum of each part's squared deviations about its mean,
    # plus its spp times its mean's squared offset from the merged mean, over passes - 1)
    pa, pb = la[1]["passes"], lb[1]["passes"]
    va, vb = (x[0]["variance"].astype(np.float64) for x in (la, lb))
    ma, mb = la[0][""].astype(np.float64), lb[0][""].astype(np.float64)
    dev = (va * 8 * (pa - 1) + vb * 24 * (pb - 1)
           + 8 * (ma - expected) ** 2 + 24 * (mb - expected) ** 2)
    pooled = dev / (pa + pb - 1) / 32
    assert np.allclose(lm[0]["variance"], pooled, rtol=1e-4, atol=1e-7)
    # and lower than either part's in the typical pixel (the mean over pixels is ruled by a
    # few heavy-tailed ones, whose pooled estimate can exceed a part's)
    assert np.median(lm[0]["variance"]) < min(np.median(va), np.median(vb))


def test_merge_refuses_overlapping_seeds_and_other_scenes(tmp_path):
    a, b, c = tmp_path / "a.exr", tmp_path / "b.exr", tmp_path / "c.exr"
    assert cli("render", SCENE, *SMALL, "--spp", 8, "--seed", 0, "-o", a).returncode == 0
    assert cli("render", SCENE, *SMALL, "--spp", 8, "--seed", 3, "-o", b).returncode == 0
    r = cli("merge", a, b, "-o", tmp_path / "m.exr")
    assert r.returncode == 2 and "overlap" in r.stderr, r.stderr
    assert cli("render", SCENE, *SMALL, "-D", "heuristic=balance", "--spp", 8, "--seed", 50,
               "-o", c).returncode == 0
    r = cli("merge", a, c, "-o", tmp_path / "m.exr")
    assert r.returncode == 2 and "differ in params" in r.stderr, r.stderr
    assert str(a) in r.stderr and str(c) in r.stderr and len(r.stderr.splitlines()) == 1


def test_variance_layer_predicts_the_error_between_runs():
    """For independent runs a, b with variance layers va, vb, d = (a - b)^2 / (va + vb) follows
    about F(1, 2 (P - 1)) per pixel when pass means are near normal (median ~0.47 for P = 8).
    The median over 1024 pixels of the Cornell box (no fireflies) must lie in [0.35, 0.65]; a
    layer off by the pass count or the sample count would be off by 8x or more.  (On the demo
    the mean of d is dominated by fireflies that 8 passes rarely contain: the median is the
    robust statistic.)"""
    scene = mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res="32")
    a = progressive.render(scene, spp=64, seed=0)
    b = progressive.render(scene, spp=64, seed=1000)
    assert a.passes == b.passes == 8
    d = (a.mean() - b.mean()) ** 2 / (a.variance() + b.variance())
    assert 0.35 < float(np.median(d)) < 0.65, float(np.median(d))


@pytest.mark.parametrize("args,needle", [
    (["--time", "abc"], "--time = 'abc' is not a number of seconds"),
    (["--time", "-1"], "--time = -1 must be a positive number of seconds"),
    (["--checkpoint", "0"], "--checkpoint = 0 must be a positive number"),
])
def test_bad_time_arguments(args, needle):
    r = cli("render", SCENE, *args)
    assert r.returncode == 2 and needle in r.stderr, r.stderr


# ---- refusals up front, seeds, films (issue 12) ---------------------------------------------
def _tiny(**kw):
    return mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res=str(kw.get("res", 8)))


def test_seeds_stay_32_bit():
    scene = _tiny()
    top = progressive.MAX_SEED
    with pytest.raises(progressive.RenderError, match="past the largest seed 4294967295; use a "
                                                      "seed <= 4294967288"):
        progressive.render(scene, spp=8, seed=top)     # 8 passes of 1 spp
    acc = progressive.render(scene, spp=8, seed=top - 7)
    assert (acc.seed_first, acc.seed_last, acc.passes) == (top - 7, top, 8)
    # with a time budget the render stops after the pass with the last seed, and says so
    acc = progressive.render(scene, time_budget=60, seed=top - 1)
    assert (acc.passes, acc.seed_last, acc.stopped) == (2, top, "seeds")
    for bad in (-1, top + 1, 1.5, True):
        with pytest.raises(progressive.RenderError, match="seed"):
            progressive.render(scene, spp=1, seed=bad)
    for bad in (0, -3, progressive.MAX_SPP + 1, 2.0):
        with pytest.raises(progressive.RenderError, match="spp"):
            progressive.render(scene, spp=bad)


FILM = """<scene version="3.0.0"><integrator type="nee_path"/>
<sensor type="orthographic"><film type="hdrfilm"><integer name="width" value="{w}"/>
<integer name="height" value="{h}"/><string name="pixel_format" value="{fmt}"/></film></sensor>
<emitter type="constant"/><shape type="sphere"/></scene>"""


def test_film_checks_and_pass_size(monkeypatch):
    cap = progressive.MAX_SAMPLES_PER_PASS
    assert progressive.pass_size(4096, 4096, 100) == (1, 1)
    assert progressive.pass_size(64, 64, 10_000) == (1250, cap // 4096)
    assert progressive.pass_size(64, 64, None) == (1, cap // 4096)
    for w, h, what in ((0, 8, "no pixels"), (8, 0, "no pixels"),
                       (4097, 4096, "more than a pass may hold")):
        with pytest.raises(progressive.RenderError, match=what):
            progressive.check_film(mi.load_string(FILM.format(w=w, h=h, fmt="rgb")))
    scene = mi.load_string(FILM.format(w=512, h=512, fmt="rgb"))
    assert progressive.check_film(scene) == (512, 512)
    monkeypatch.setattr(progressive, "memory_available", lambda: 10 << 20)
    with pytest.raises(progressive.RenderError, match=r"needs about 31 MiB of memory \(124 bytes "
                                                      r"per pixel\); 10 MiB are available"):
        progressive.check_film(scene)
    assert progressive.film_channels(mi.load_string(FILM.format(w=8, h=8, fmt="luminance"))) == 1
    assert progressive.bytes_per_pixel(3) == 124        # measured: about 126 (README)


@pytest.mark.parametrize("fmt,names", [("luminance", ("Y",)), ("rgb", ("R", "G", "B")),
                                       ("xyza", ("X", "Y", "Z", "A"))])
def test_film_channels_carried_to_the_file(fmt, names, tmp_path):
    acc = progressive.render(mi.load_string(FILM.format(w=6, h=4, fmt=fmt)), spp=2)
    assert acc.channels == names and acc.s.shape == (4, 6, len(names))
    progressive.write(tmp_path / "a.exr", acc, preview=True)
    back = progressive.read(tmp_path / "a.exr")
    assert back.channels == names and np.allclose(back.mean(), acc.mean(), rtol=1e-6)
    assert (tmp_path / "a.png").is_file()
