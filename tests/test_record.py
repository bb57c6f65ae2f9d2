"""The run record in the EXR header (typed attributes, JSON round trip) and merge's checks of it:
an edited scene, overlapping seeds, unreadable inputs; EXR writes through OpenEXR."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

import integrators  # noqa: F401
import mitsuba as mi
from integrators.app import progressive
from integrators.app.imageio import read_exr, read_layers, write_layers
from integrators.app.record import RunRecord, file_sha1

ROOT = Path(__file__).resolve().parents[1]

SCENE = """<scene version="3.0.0">
  <default name="radiance" value="1"/>
  <integrator type="bsdf_path"/>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, -4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
  </sensor>
  <emitter type="constant"><rgb name="radiance" value="$radiance"/></emitter>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
</scene>
"""


def cli(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "integrators", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)


def render(scene, out, seed, spp=4, *extra):
    r = cli("render", scene, "--spp", spp, "--seed", seed, "--quiet", *extra, "-o", out)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs")
    scene = d / "s.xml"
    scene.write_text(SCENE)
    a = render(scene, d / "a.exr", 0, 4, "-D", "radiance=0.5")
    b = render(scene, d / "b.exr", 100, 8, "-D", "radiance=0.5")
    return {"dir": d, "scene": scene, "sha1": file_sha1(scene), "a": a, "b": b}


def test_header_holds_the_typed_record(runs):
    header = OpenEXR.File(str(runs["a"]), header_only=True).header()
    for k in ("spp", "passes", "seed_first", "seed_last"):
        assert type(header[k]) is int, (k, header[k])
    assert type(header["seconds"]) is float and header["seconds"] > 0
    for k in ("scene", "scene_sha1", "integrator", "variant", "run_record"):
        assert type(header[k]) is str, (k, header[k])
    assert header["spp"] == 4 and header["seed_first"] == 0
    assert header["seed_last"] == header["passes"] - 1
    assert header["scene"] == str(runs["scene"].resolve())
    assert header["scene_sha1"] == runs["sha1"]
    assert header["integrator"] == "bsdf_path" and header["variant"] == mi.variant()

    rec = RunRecord.from_header(header)
    assert rec == RunRecord.from_json(header["run_record"])
    assert (rec.spp, rec.passes, rec.seed_first, rec.seed_last) == \
        (header["spp"], header["passes"], header["seed_first"], header["seed_last"])
    assert rec.seed_ranges == [[0, header["passes"] - 1]]
    assert rec.scene_sha1 == runs["sha1"] and rec.defines == {"radiance": "0.5"}
    assert rec.integrator == "bsdf_path" and rec.params
    assert json.loads(header["params"]) == rec.params
    # round trip through the accumulator and the header again
    acc = progressive.read(runs["a"])
    assert acc.run_record() == rec
    assert RunRecord.from_json(rec.header()["run_record"]) == rec


def test_files_are_plain_exr_with_named_layers(runs):
    f = OpenEXR.File(str(runs["a"]), separate_channels=True)
    assert set(f.channels()) == {"R", "G", "B", "variance.R", "variance.G", "variance.B"}
    bmp = mi.Bitmap(str(runs["a"]))          # another reader sees the RGB layer
    rgb = dict(bmp.split())["<root>"]
    assert np.array_equal(np.array(rgb), read_exr(runs["a"]))
    assert read_exr(runs["a"]).shape == (6, 8, 3) and read_exr(runs["a"]).max() > 0


def test_merge_lists_every_seed_range(runs):
    m = runs["dir"] / "m.exr"
    r = cli("merge", runs["a"], runs["b"], "-o", m)
    assert r.returncode == 0, r.stderr
    ra, rb, rm = (RunRecord.from_header(read_layers(p)[1]) for p in (runs["a"], runs["b"], m))
    assert rm.seed_ranges == ra.seed_ranges + rb.seed_ranges
    assert rm.seed_ranges == [[0, ra.passes - 1], [100, 100 + rb.passes - 1]]
    assert (rm.spp, rm.passes) == (12, ra.passes + rb.passes)
    assert (rm.seed_first, rm.seed_last) == (0, rb.seed_last)
    assert rm.identity() == ra.identity()
    # a merged file merges on; overlapping one of its runs is refused
    c = render(runs["scene"], runs["dir"] / "c.exr", 50, 4, "-D", "radiance=0.5")
    m2 = runs["dir"] / "m2.exr"
    assert cli("merge", m, c, "-o", m2).returncode == 0
    assert RunRecord.from_header(read_layers(m2)[1]).seed_ranges == \
        [[0, ra.passes - 1], [50, 50 + ra.passes - 1], [100, 100 + rb.passes - 1]]
    r = cli("merge", m, runs["b"], "-o", runs["dir"] / "x.exr")
    assert r.returncode == 2 and "overlap" in r.stderr and len(r.stderr.splitlines()) == 1
    assert not (runs["dir"] / "x.exr").exists()


def test_merge_refuses_an_edited_scene(tmp_path):
    scene = tmp_path / "s.xml"
    scene.write_text(SCENE)
    a = render(scene, tmp_path / "a.exr", 0)
    scene.write_text(SCENE.replace('value="$radiance"', 'value="2"'))   # edited in between
    b = render(scene, tmp_path / "b.exr", 100)
    r = cli("merge", a, b, "-o", tmp_path / "m.exr")
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(a) in lines[0] and str(b) in lines[0], lines[0]
    assert lines[0].count(str(scene.resolve())) == 2 and "scene file differs" in lines[0]
    assert not (tmp_path / "m.exr").exists()


def test_merge_refuses_unreadable_inputs(runs, tmp_path):
    text = tmp_path / "text.exr"
    text.write_text("not an image\n")
    cut = tmp_path / "cut.exr"
    data = runs["a"].read_bytes()
    cut.write_bytes(data[: len(data) - 16])
    for bad in (text, cut):
        r = cli("merge", runs["a"], bad, "-o", tmp_path / "m.exr")
        assert r.returncode == 2, (r.returncode, r.stderr)
        assert r.stderr.splitlines() == [f"error: {bad}: not an EXR written by render "
                                         "(not a complete OpenEXR image)"], r.stderr
        assert r.stdout == ""
        with pytest.raises(ValueError, match="not an EXR written by render"):
            read_layers(bad)


# ---- in-process checks: no render -----------------------------------------------------------
def test_failed_write_leaves_the_old_file(tmp_path):
    out = tmp_path / "x.exr"
    img = np.ones((4, 5, 3), np.float32)
    write_layers(out, {"": img}, {"n": 3})
    with pytest.raises(ValueError):
        write_layers(out, {"": 2 * img, "variance": np.ones((2, 2, 3))}, {"n": 4})
    layers, meta = read_layers(out)
    assert np.array_equal(layers[""], img) and meta == {"n": 3}
    assert [p.name for p in tmp_path.iterdir()] == ["x.exr"]


def test_header_values_are_typed_and_never_wrapped(tmp_path):
    out = tmp_path / "x.exr"
    write_layers(out, {"": np.zeros((2, 2, 3))},
                 {"i": 7, "f": 0.5, "s": "text", "big": 2**31, "d": {"a": 1}, "b": True})
    meta = read_layers(out)[1]
    assert meta == {"i": 7, "f": 0.5, "s": "text", "big": str(2**31), "d": '{"a": 1}', "b": 1}


def test_merge_problem_checks_identity_and_seeds():
    a = RunRecord(scene="/s.xml", scene_sha1="1" * 40, integrator="x", params={"p": 1},
                  variant="v", seed_first=0, seed_last=7, seed_ranges=[[0, 7]])
    assert a.merge_problem(RunRecord(**{**a.to_dict(), "seed_first": 8, "seed_last": 9,
                                        "seed_ranges": [[8, 9]]})) is None
    msg = a.merge_problem(RunRecord(**{**a.to_dict(), "scene_sha1": "2" * 40,
                                       "seed_first": 8, "seed_ranges": [[8, 9]]}), "A", "B")
    assert "A" in msg and "B" in msg and "111111111111" in msg and "222222222222" in msg
    assert "differ in params" in a.merge_problem(RunRecord(**{**a.to_dict(), "params": {"p": 2},
                                                              "seed_ranges": [[8, 9]]}))
    assert "overlap" in a.merge_problem(RunRecord(**{**a.to_dict(), "seed_ranges": [[7, 9]]}))


def test_legacy_header_without_run_record():
    """Files written before the run record (string attributes) still read."""
    rec = RunRecord.from_header({"spp": "16", "passes": "8", "seed_first": "0",
                                 "seed_last": "7", "seconds": "1.5", "scene": "s.xml"})
    assert (rec.spp, rec.passes, rec.seed_ranges, rec.seconds) == (16, 8, [[0, 7]], 1.5)
    with pytest.raises(KeyError):
        RunRecord.from_header({"spp": 1})


# ---- writing outputs: groups replaced together, real I/O errors, stale temporaries ------------
def test_channel_names_round_trip(tmp_path):
    from integrators.app.imageio import read_layers_named
    for names, n in (("Y", 1), ("YA", 2), ("XYZ", 3), ("XYZA", 4), (None, 5)):
        img = np.random.default_rng(n).random((3, 4, n)).astype(np.float32)
        write_layers(tmp_path / "c.exr", {"": img, "variance": img}, channels=names)
        layers, _, got = read_layers_named(tmp_path / "c.exr")
        expect = tuple(names) if names else ("C0", "C1", "C2", "C3", "C4")
        assert got[""] == expect and got["variance"] == expect
        assert np.array_equal(layers[""], img)


def test_group_is_replaced_together_or_not_at_all(tmp_path, monkeypatch):
    from integrators.app.imageio import WriteError, write_together
    a, b = tmp_path / "x.exr", tmp_path / "x.png"

    def text(s):
        return lambda tmp: Path(tmp).write_text(s)
    write_together([(a, text("old a")), (b, text("old b"))])
    for fault in ("png-rename:EIO", "png-write", "exr-write:EDQUOT", "exr-rename:EXDEV"):
        monkeypatch.setenv("INTEGRATORS_TEST_FAULT", fault)
        with pytest.raises(WriteError) as e:
            write_together([(a, text("new a")), (b, text("new b"))])
        assert str(e.value).startswith(f"cannot write {a if 'exr' in fault else b}: ")
        assert "\n" not in str(e.value) and ".x." not in str(e.value)
        assert (a.read_text(), b.read_text()) == ("old a", "old b")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.png"]
    monkeypatch.delenv("INTEGRATORS_TEST_FAULT")
    write_together([(a, text("new a")), (b, text("new b"))])
    assert (a.read_text(), b.read_text()) == ("new a", "new b")


def test_write_errors_are_os_errors_not_silent(tmp_path):
    """OpenEXR and Mitsuba's writers report success on a full disk (leaving empty files):
    bytes go through Python's I/O, which raises."""
    from integrators.app.imageio import write_bytes
    with pytest.raises(OSError) as e:
        write_bytes("/dev/full", b"x" * 100_000)
    assert e.value.errno == 28


def test_stale_temporaries_of_dead_processes_only(tmp_path):
    import time as _time
    from integrators.app.imageio import remove_stale_temporaries
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    names = {f".r.{dead.pid}.abc_123.exr": True, f".r.{dead.pid}.abc_123.bak.exr": True,
             f".r.{os.getpid()}.abc_123.exr": False, f".r.{dead.pid}.abc_123.png": False,
             ".r.x1y2z3w4.exr": True, ".r.x1y2z3w5.exr": False, "r.exr": False,
             f".r.1.{dead.pid}.abc.exr": False}
    for n in names:
        (tmp_path / n).write_text("x")
    old = _time.time() - 7200
    os.utime(tmp_path / ".r.x1y2z3w4.exr", (old, old))
    removed = remove_stale_temporaries(tmp_path / "r.exr")
    assert sorted(removed) == sorted(n for n, stale in names.items() if stale)
