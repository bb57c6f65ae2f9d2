"""Regression corpus of bad inputs and faults (issue 12): each case asserts the exit status and
that stderr holds exactly the expected lines -- one line naming the parameter, value or path --
and never a traceback.

Categories: command line (usage errors, counts, seeds, variants, output paths), parameters (every
parameter of every plugin, generated from the specs `python -m integrators list` prints: out of
range, wrong type, unknown names; through -D and XML), scenes (missing, malformed, unknown
plugins, media, NaN/Inf/negative emitters and textures, empty and huge films), merge inputs,
outputs and faults (full disk, failing renames, read-only folders, stale temporaries, concurrent
renders), plugin exceptions, and signals at start-up, mid-pass and mid-write.

The many load-time cases run in-process (``cli.main([...])`` with stderr captured); signals,
SIGKILL and concurrency need subprocesses.  The signal cases use the test-only hook
``INTEGRATORS_TEST_PAUSE_AT`` (integrators.app.interrupt), the faults ``INTEGRATORS_TEST_FAULT``
(integrators.app.imageio); a real full disk uses a small tmpfs where this user may mount one.
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import integrators
import mitsuba as mi
from integrators import registry
from integrators.app import cli, imageio, progressive
from integrators.app.imageio import read_layers

ROOT = Path(__file__).resolve().parents[1]

SENSOR = """  <sensor type="{sensor}">
    <transform name="to_world"><lookat origin="0, 0, -4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>
      <string name="pixel_format" value="{fmt}"/></film>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>{sensor_extra}
  </sensor>"""


def scene_xml(integrator='<integrator type="nee_path"/>', emitter=None, shape=None, extra="",
              w=8, h=8, fmt="rgb", spp=2, sensor="perspective", sensor_extra=""):
    emitter = '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>' \
        if emitter is None else emitter
    shape = '<shape type="sphere"><bsdf type="diffuse"/></shape>' if shape is None else shape
    return "\n".join(['<scene version="3.0.0">', "  " + integrator,
                      SENSOR.format(sensor=sensor, w=w, h=h, fmt=fmt, spp=spp,
                                    sensor_extra=sensor_extra),
                      "  " + emitter, "  " + shape, extra, "</scene>", ""])


def write_scene(tmp_path, text, name="s.xml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def lines(text):
    return [ln for ln in text.splitlines() if ln.strip()]


def run_main(capfd, *args):
    """``python -m integrators ARGS`` in this process: (status, stdout, stderr lines)."""
    capfd.readouterr()
    rc = cli.main([str(a) for a in args])
    out, err = capfd.readouterr()
    return rc, out, lines(err)


def assert_error(rc, err, status, needles):
    assert rc == status, (rc, err)
    assert len(err) == 1, err
    line = err[0]
    assert "Traceback" not in line and 'File "' not in line, line
    for n in needles:
        assert str(n) in line, (n, line)
    return line


def no_temporaries(d):
    return [p.name for p in Path(d).iterdir() if p.name.startswith(".")] == []


# =============================================================================================
# command line: usage errors, one line each, status 2, in-process
CLI_CASES = [
    # (id, args after "render SCENE", needles)
    ("spp-zero", ["--spp", "0"], ["--spp = 0 must be a positive integer"]),
    ("spp-negative", ["--spp", "-5"], ["--spp = -5"]),
    ("spp-fraction", ["--spp", "1.5"], ["--spp = '1.5' is not an integer"]),
    ("spp-word", ["--spp", "many"], ["--spp = 'many'"]),
    ("spp-too-large", ["--spp", str(2**32)], ["--spp = 4294967296 is too large"]),
    ("spp-absurd", ["--spp", "1" + "0" * 30], ["--spp", "too large"]),
    ("spp-no-value", ["--spp"], ["--spp needs a value"]),
    ("time-zero", ["--time", "0"], ["--time = 0 must be a positive number"]),
    ("time-negative", ["--time", "-3"], ["--time = -3"]),
    ("time-nan", ["--time", "nan"], ["--time = nan"]),
    ("time-inf", ["--time", "inf"], ["--time = inf"]),
    ("time-word", ["--time", "abc"], ["--time = 'abc' is not a number of seconds"]),
    ("seed-negative", ["--seed", "-1"], ["--seed = -1 must be an integer >= 0"]),
    ("seed-too-large", ["--seed", str(2**32)], ["--seed = 4294967296 is too large"]),
    ("seed-word", ["--seed", "x"], ["--seed = 'x' is not an integer"]),
    ("seed-range-overflow", ["--seed", str(2**32 - 1), "--spp", "8"],
     ["seed 4294967295", "past the largest seed 4294967295"]),
    ("checkpoint-zero", ["--checkpoint", "0"], ["--checkpoint = 0 must be a positive number"]),
    ("checkpoint-negative", ["--checkpoint", "-1"], ["--checkpoint = -1"]),
    ("checkpoint-nan", ["--checkpoint", "nan"], ["--checkpoint = nan"]),
    ("unknown-option", ["--bogus"], ["unknown option --bogus"]),
    ("unknown-option-value", ["--bogus=3"], ["unknown option --bogus"]),
    ("abbreviation-spp", ["--sp", "8"], ["unknown option --sp", "--spp"]),
    ("abbreviation-checkpoint", ["--check", "1"], ["unknown option --check", "--checkpoint"]),
    ("abbreviation-variant", ["--var", "scalar_rgb"], ["unknown option --var"]),
    ("extra-argument", ["another.xml"], ["unexpected argument 'another.xml'"]),
    ("define-without-equals", ["-D", "width"], ["-D 'width': expected NAME=VALUE"]),
    ("define-without-name", ["-D", "=3"], ["-D '=3': expected NAME=VALUE"]),
    ("define-no-value", ["-D"], ["-D needs a value"]),
    ("variant-unknown", ["--variant", "nonsense_rgb"], ["'nonsense_rgb' is not available"]),
    ("output-not-exr", ["-o", "{tmp}/x.png"], ["must end in .exr"]),
    ("output-no-suffix", ["-o", "{tmp}/x"], ["must end in .exr"]),
    ("output-is-directory", ["-o", "{tmp}/dir.exr"], ["dir.exr is a directory"]),
    ("preview-is-directory", ["-o", "{tmp}/pdir.exr"], ["pdir.png is a directory"]),
    ("output-parent-is-file", ["-o", "{tmp}/afile/x.exr"], ["afile is not a directory"]),
    ("output-in-proc", ["-o", "/proc/forbidden/x.exr"], ["cannot write /proc/forbidden/x.exr"]),
]


@pytest.fixture
def tiny(tmp_path):
    (tmp_path / "dir.exr").mkdir()
    (tmp_path / "pdir.png").mkdir()
    (tmp_path / "afile").write_text("x")
    return write_scene(tmp_path, scene_xml())


@pytest.mark.parametrize("case", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_command_line(case, tiny, tmp_path, capfd):
    _, args, needles = case
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if "-o" not in args:
        args += ["-o", tmp_path / "out.exr"]
    rc, out, err = run_main(capfd, "render", tiny, *args)
    assert_error(rc, err, 2, needles)
    assert not (tmp_path / "out.exr").exists()


OTHER_USAGE = [
    ("no-command", [], ["missing command: render, merge or list"]),
    ("unknown-command", ["draw"], ["unknown command 'draw'"]),
    ("command-abbreviated", ["rend", "x.xml"], ["unknown command 'rend'"]),
    ("render-no-scene", ["render"], ["render: missing scene"]),
    ("render-missing-scene", ["render", "{tmp}/missing.xml"], ["scene file not found",
                                                                "missing.xml"]),
    ("render-scene-is-directory", ["render", "{tmp}"], ["is a directory"]),
    ("merge-no-inputs", ["merge", "-o", "{tmp}/m.exr"], ["merge: missing inputs"]),
    ("merge-no-output", ["merge", "{tmp}/a.exr"], ["missing -o/--output"]),
    ("merge-missing-input", ["merge", "{tmp}/nope.exr", "-o", "{tmp}/m.exr"],
     ["input not found", "nope.exr"]),
    ("merge-input-directory", ["merge", "{tmp}", "-o", "{tmp}/m.exr"], ["is not a file"]),
    ("list-unknown-option", ["list", "--all"], ["unknown option --all"]),
    ("top-unknown-option", ["--verbose", "list"], ["unknown option --verbose"]),
]


@pytest.mark.parametrize("case", OTHER_USAGE, ids=[c[0] for c in OTHER_USAGE])
def test_other_usage(case, tmp_path, capfd):
    _, args, needles = case
    rc, out, err = run_main(capfd, *[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert_error(rc, err, 2, needles)


def test_cuda_variant_without_gpu(tiny, tmp_path, capfd):
    import drjit as dr
    if "cuda_ad_rgb" not in mi.variants():
        pytest.skip("this Mitsuba build has no cuda_ad_rgb")
    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine has a CUDA device")
    rc, out, err = run_main(capfd, "render", tiny, "--variant", "cuda_ad_rgb",
                            "-o", tmp_path / "o.exr")
    assert_error(rc, err, 2, ["'cuda_ad_rgb' needs an NVIDIA GPU"])
    assert mi.variant() == integrators.DEFAULT_VARIANT


# =============================================================================================
# parameters: every parameter of every plugin, from its spec
def _num(v):
    return repr(float(v)) if isinstance(v, float) else str(v)


def _bad_values(spec):
    """(form, XML tag, value, needles) of bad values for ``spec``; form "xml" writes the value
    into the scene, "define" passes it with -D into a ``$v`` of the scene."""
    out = []
    name = spec.name
    if spec.kind == "int":
        if spec.min is not None:
            v = int(spec.min) - 1
            while v in spec.allow:
                v -= 1
            out += [("define", "integer", v, [f"'{name}' = {v}", "invalid"]),
                    ("xml", "integer", v, [f"'{name}' = {v}"])]
        if spec.max is not None:
            v = int(spec.max) + 1
            out.append(("xml", "integer", v, [f"'{name}' = {v}"]))
        out += [("xml", "string", "abc", [f"'{name}' = 'abc'"]),
                ("xml", "float", 2.5, [f"'{name}' = 2.5"]),
                ("define", "integer", "x1", ['could not parse integer value "x1"'])]
    elif spec.kind == "float":
        if spec.min is not None:
            v = float(spec.min) if spec.min_exclusive else float(spec.min) - 0.5
            out += [("define", "float", v, [f"'{name}' = {_num(v)}"]),
                    ("xml", "float", v, [f"'{name}' = {_num(v)}"])]
        if spec.max is not None:
            v = float(spec.max) + 0.5
            out.append(("xml", "float", v, [f"'{name}' = {_num(v)}"]))
        out += [("xml", "float", "nan", [f"'{name}' = nan"]),
                ("xml", "float", "inf", [f"'{name}' = inf"]),
                ("xml", "string", "abc", [f"'{name}' = 'abc'"]),
                ("define", "float", "fast", ['could not parse floating point value "fast"'])]
    elif spec.kind == "choice":
        upper = spec.choices[0].upper()
        out += [("define", "string", "foo", [f"'{name}' = 'foo'", spec.choices[0]]),
                ("xml", "string", upper, [f"'{name}' = '{upper}'"]),
                ("xml", "integer", 1, [f"'{name}' = 1"])]
    elif spec.kind == "bool":
        out += [("xml", "string", "maybe", [f'"{name}"', "wrong type"]),
                ("define", "boolean", "maybe", ['could not parse boolean value "maybe"'])]
    elif spec.kind in ("texture", "spectrum"):
        out += [("xml", "float", "nan", [name]),
                ("xml", "float", 1.5, ["phong"]),
                ("xml", "rgb", "-0.5", ["-0.5"])]
    return out


def _param_cases():
    cases = []
    for pname, p in sorted(registry.plugins().items()):
        if p.kind not in ("integrator", "bsdf"):
            continue
        for spec in p.params:
            for form, tag, value, needles in _bad_values(spec):
                cases.append(pytest.param(pname, p.kind, spec.name, form, tag, value, needles,
                                          id=f"{pname}-{spec.name}-{form}-{tag}-{value}"))
        first = p.params[0].name if p.params else "x"
        cases.append(pytest.param(pname, p.kind, first + "_typo", "xml", "integer", 1,
                                  [f"unknown parameter '{first}_typo'"],
                                  id=f"{pname}-unknown-name"))
    return cases


@pytest.mark.parametrize("plugin,kind,name,form,tag,value,needles", _param_cases())
def test_bad_parameter(plugin, kind, name, form, tag, value, needles, tmp_path, capfd):
    shown = "$v" if form == "define" else value
    elem = f'<{tag} name="{name}" value="{shown}"/>'
    if kind == "integrator":
        text = scene_xml(integrator=f'<integrator type="{plugin}">{elem}</integrator>')
    else:
        text = scene_xml(shape=f'<shape type="sphere"><bsdf type="{plugin}">{elem}</bsdf></shape>')
    scene = write_scene(tmp_path, text)
    args = ["-D", f"v={value}"] if form == "define" else []
    rc, out, err = run_main(capfd, "render", scene, *args, "-o", tmp_path / "o.exr")
    line = assert_error(rc, err, 2, needles)
    assert str(scene) in line
    assert not (tmp_path / "o.exr").exists()


def test_parameter_corpus_covers_every_parameter():
    seen = {(c.values[0], c.values[2]) for c in _param_cases()}
    for pname, p in registry.plugins().items():
        for spec in p.params:
            assert (pname, spec.name) in seen, (pname, spec.name)


# =============================================================================================
# scenes
SCENE_CASES = [
    ("empty-file", "", ["No document element found"]),
    ("xml-syntax", '<scene version="3.0.0"><shape type="sphere"></scene>', ["line 1"]),
    ("not-xml", "\x89PNG binary junk \x01\x02", ["Parsing of XML file"]),
    ("unknown-bsdf", scene_xml(shape='<shape type="sphere"><bsdf type="nope"/></shape>'),
     ['Plugin "nope" not found']),
    ("unknown-integrator", scene_xml(integrator='<integrator type="nope_path"/>'),
     ['Plugin "nope_path" not found']),
    ("unknown-shape", scene_xml(shape='<shape type="blob"/>'), ['Plugin "blob" not found']),
    ("undefined-variable", scene_xml(shape='<shape type="sphere"><bsdf type="diffuse"><rgb '
                                           'name="reflectance" value="$refl"/></bsdf></shape>'),
     ["undefined parameter: $refl"]),
    ("bad-version", scene_xml().replace('version="3.0.0"', 'version="x"'), ["version"]),
    ("medium-interior", scene_xml(shape='<shape type="sphere"><bsdf type="null"/>'
                                        '<medium name="interior" type="homogeneous"/></shape>'),
     ["participating medium", "interior", "volpath"]),
    ("medium-sensor", scene_xml(sensor_extra='<medium type="homogeneous"/>'),
     ["participating medium", "sensor", "volpath"]),
    ("emitter-nan", scene_xml(emitter='<emitter type="constant"><rgb name="radiance" '
                                      'value="nan"/></emitter>'), ["radiance", "nan"]),
    ("emitter-inf", scene_xml(shape='<shape type="sphere"><emitter type="area"><rgb '
                                    'name="radiance" value="inf"/></emitter></shape>'),
     ["radiance", "inf"]),
    ("emitter-negative", scene_xml(emitter='<emitter type="constant"><rgb name="radiance" '
                                           'value="-1"/></emitter>'), ["radiance", "-1"]),
    ("point-light-nan", scene_xml(emitter='<emitter type="point"><rgb name="intensity" '
                                          'value="nan"/></emitter>'), ["intensity", "nan"]),
    ("texture-nan", scene_xml(shape='<shape type="sphere"><bsdf type="diffuse"><rgb '
                                    'name="reflectance" value="nan"/></bsdf></shape>'),
     ["reflectance", "nan"]),
    ("nested-texture-nan", scene_xml(shape='<shape type="sphere"><bsdf type="diffuse"><texture '
                                           'name="reflectance" type="checkerboard"><rgb '
                                           'name="color0" value="nan"/></texture></bsdf></shape>'),
     ["color0", "nan"]),
    ("film-width-zero", scene_xml(sensor="orthographic", w=0), ["0x8", "no pixels"]),
    ("film-height-zero", scene_xml(sensor="orthographic", h=0), ["8x0", "no pixels"]),
    ("film-width-zero-perspective", scene_xml(w=0), ["perspective"]),
    ("film-20000", scene_xml(w=20000, h=20000), ["20000x20000", "GiB of memory"]),
    ("film-100000", scene_xml(w=100000, h=100000), ["100000x100000", "GiB of memory"]),
    ("film-past-pass-cap", scene_xml(w=4097, h=4096), ["4097x4096", "more than a pass may hold"]),
]


@pytest.mark.parametrize("case", SCENE_CASES, ids=[c[0] for c in SCENE_CASES])
def test_bad_scene(case, tmp_path, capfd):
    _, text, needles = case
    scene = write_scene(tmp_path, text)
    rc, out, err = run_main(capfd, "render", scene, "--spp", "1", "-o", tmp_path / "o.exr")
    line = assert_error(rc, err, 2, needles)
    assert str(scene) in line
    assert not (tmp_path / "o.exr").exists()


def test_film_larger_than_memory_is_refused_with_the_memory_needed(tmp_path, capfd,
                                                                   monkeypatch):
    monkeypatch.setattr(progressive, "memory_available", lambda: 5 << 20)
    scene = write_scene(tmp_path, scene_xml(w=256, h=256))
    rc, out, err = run_main(capfd, "render", scene, "-o", tmp_path / "o.exr")
    assert_error(rc, err, 2, ["256x256", "needs about 8 MiB of memory", "5 MiB are available"])


@pytest.mark.parametrize("fmt,channels", [("luminance", "Y"), ("luminance_alpha", "YA"),
                                          ("rgba", "RGBA"), ("xyz", "XYZ")])
def test_film_pixel_formats_render_and_merge(fmt, channels, tmp_path, capfd):
    scene = write_scene(tmp_path, scene_xml(fmt=fmt))
    a, b, m = (tmp_path / f"{n}.exr" for n in "abm")
    for out, seed in ((a, 0), (b, 100)):
        rc, _, err = run_main(capfd, "render", scene, "--seed", seed, "-o", out)
        assert rc == 0 and err == [], err
    rc, _, err = run_main(capfd, "merge", a, b, "-o", m)
    assert rc == 0 and err == [], err
    layers, meta, names = imageio.read_layers_named(m)
    assert "".join(names[""]) == channels and layers[""].shape == (8, 8, len(channels))
    assert np.all(np.isfinite(layers[""])) and m.with_suffix(".png").is_file()


# ---- exceptions raised by plugins: the real one-line message, not Mitsuba's wrapping ---------
class _Raiser:
    def __init__(self, props):
        mi.SamplingIntegrator.__init__(self, props)
        if props.get("fail_in_constructor", False):
            raise ValueError("corpus_raiser: refused in the constructor")

    def sample(self, scene, sampler, ray, medium=None, active=True):
        raise ValueError("corpus_raiser: refused while tracing")

    def to_string(self):
        return "CorpusRaiser[]"


def _register_raiser():
    cls = type("CorpusRaiser", (mi.SamplingIntegrator,), dict(vars(_Raiser)))
    mi.register_integrator("corpus_raiser", lambda props: cls(props))


@pytest.mark.parametrize("where", ["constructor", "sample"])
def test_plugin_exception_is_its_own_line(where, tmp_path, capfd):
    _register_raiser()
    flag = '<boolean name="fail_in_constructor" value="true"/>' if where == "constructor" else ""
    scene = write_scene(tmp_path, scene_xml(integrator=f'<integrator type="corpus_raiser">{flag}'
                                                       '</integrator>'))
    rc, out, err = run_main(capfd, "render", scene, "--spp", "1", "-o", tmp_path / "o.exr")
    line = assert_error(rc, err, 2, ["corpus_raiser: refused in the " + where if where ==
                                     "constructor" else "corpus_raiser: refused while tracing"])
    assert "drjit.custom" not in line and "(see above)" not in line


def test_unexpected_internal_error_is_status_1(tiny, tmp_path, capfd, monkeypatch):
    def broken(*a, **k):
        raise TypeError("an internal bug")
    monkeypatch.setattr(progressive, "render", broken)
    rc, out, err = run_main(capfd, "render", tiny, "-o", tmp_path / "o.exr")
    assert_error(rc, err, 1, ["internal error: TypeError: an internal bug", "--debug"])


# =============================================================================================
# merge inputs
@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("corpus_runs")
    scene = write_scene(d, scene_xml())
    other = write_scene(d, scene_xml(emitter='<emitter type="constant"><rgb name="radiance" '
                                             'value="2"/></emitter>'), "other.xml")
    wide = write_scene(d, scene_xml(w=12), "wide.xml")
    lum = write_scene(d, scene_xml(fmt="luminance"), "lum.xml")
    out = {}
    for name, sc, seed in (("a", scene, 0), ("b", scene, 100), ("c", scene, 1), ("o", other, 200),
                           ("w", wide, 300), ("y", lum, 400)):
        assert cli.main(["render", str(sc), "--seed", str(seed), "-o", str(d / f"{name}.exr")]) == 0
        out[name] = d / f"{name}.exr"
    (d / "text.exr").write_text("not an image\n")
    data = out["a"].read_bytes()
    (d / "cut.exr").write_bytes(data[: len(data) // 2])
    (d / "empty.exr").write_bytes(b"")
    imageio.write_exr(d / "plain.exr", np.ones((8, 8, 3)))
    out["dir"] = d
    return out


MERGE_CASES = [
    ("text-file", ["a", "text.exr"], ["text.exr: not an EXR written by render"]),
    ("truncated", ["a", "cut.exr"], ["cut.exr: not an EXR written by render"]),
    ("empty-file", ["a", "empty.exr"], ["empty.exr: not an EXR written by render"]),
    ("png-input", ["a", "a.png"], ["a.png: not an EXR written by render"]),
    ("plain-exr", ["a", "plain.exr"], ["plain.exr: not an EXR written by render"]),
    ("overlapping-seeds", ["a", "c"], ["overlap"]),
    ("same-file-twice", ["a", "a"], ["overlap"]),
    ("other-scene", ["a", "o"], ["scene file differs"]),
    ("other-size", ["a", "w"], ["image size 12x8 differs"]),
    ("other-channels", ["a", "y"], ["channels Y differ"]),
    ("output-not-exr", ["a", "b", "-o", "m.png"], ["must end in .exr"]),
]


@pytest.mark.parametrize("case", MERGE_CASES, ids=[c[0] for c in MERGE_CASES])
def test_bad_merge(case, runs, capfd):
    _, names, needles = case
    d = runs["dir"]
    args = [str(d / (n if "." in n else n + ".exr")) for n in names if n != "-o"]
    if "-o" not in names:
        args += ["-o", str(d / "m.exr")]
    else:
        args = args[:-1] + ["-o", str(d / names[-1])]
    rc, out, err = run_main(capfd, "merge", *args)
    assert_error(rc, err, 2, needles)
    assert not (d / "m.exr").exists() and out == ""


# =============================================================================================
# outputs: faults while writing, read-only folders, stale temporaries
def _pair(out):
    return out.read_bytes(), out.with_suffix(".png").read_bytes()


def _pair_matches(out) -> bool:
    """The PNG beside ``out`` is the preview of that very EXR (same bytes when re-encoded)."""
    import io
    layers, _, names = imageio.read_layers_named(out)
    buf = io.BytesIO()
    imageio.encode_png(layers[""], names[""])(buf)
    return buf.getvalue() == out.with_suffix(".png").read_bytes()


@pytest.mark.parametrize("fault,failing,reason", [
    ("exr-write", "o.exr", "No space left on device"),
    ("png-write", "o.png", "No space left on device"),
    ("exr-write:EIO", "o.exr", "Input/output error"),
    ("png-rename:EIO", "o.png", "Input/output error"),
    ("exr-rename:EACCES", "o.exr", "Permission denied"),
    ("exr-write:EROFS", "o.exr", "Read-only file system"),
])
def test_write_fault_keeps_the_old_pair(fault, failing, reason, tiny, tmp_path, capfd,
                                        monkeypatch):
    out = tmp_path / "o.exr"
    assert run_main(capfd, "render", tiny, "-o", out)[0] == 0
    old = _pair(out)
    monkeypatch.setenv("INTEGRATORS_TEST_FAULT", fault)
    rc, _, err = run_main(capfd, "render", tiny, "--seed", 50, "-o", out)
    line = assert_error(rc, err, 2, [f"cannot write {tmp_path / failing}: {reason}"])
    assert ".tmp" not in line and "/." not in line          # names the output, not a temporary
    assert _pair(out) == old
    assert no_temporaries(tmp_path)


def test_write_fault_with_no_previous_output_leaves_nothing(tiny, tmp_path, capfd, monkeypatch):
    monkeypatch.setenv("INTEGRATORS_TEST_FAULT", "png-rename:EIO")
    rc, _, err = run_main(capfd, "render", tiny, "-o", tmp_path / "o.exr")
    assert_error(rc, err, 2, ["o.png: Input/output error"])
    assert {p.name for p in tmp_path.iterdir()} == {"s.xml", "afile", "dir.exr", "pdir.png"}


@contextlib.contextmanager
def _mounted_tmpfs(path, options):
    path.mkdir(exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)],
                       capture_output=True)
    if r.returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


@contextlib.contextmanager
def _read_only_dir(path):
    if os.geteuid() != 0:
        path.mkdir()
        path.chmod(0o555)
        try:
            yield path
        finally:
            path.chmod(0o755)
        return
    with _mounted_tmpfs(path, "ro,size=16k") as p:    # root writes through chmod 555
        yield p


@pytest.mark.parametrize("target", ["ro/x.exr", "ro/sub/x.exr"])
def test_read_only_folder(target, tiny, tmp_path, capfd):
    with _read_only_dir(tmp_path / "ro"):
        rc, _, err = run_main(capfd, "render", tiny, "-o", tmp_path / target)
        assert_error(rc, err, 2, [f"cannot write {tmp_path / target}", "not writable"])


def test_merge_into_read_only_folder(runs, tmp_path, capfd):
    with _read_only_dir(tmp_path / "ro"):
        rc, _, err = run_main(capfd, "merge", runs["a"], runs["b"], "-o", tmp_path / "ro/m.exr")
        assert_error(rc, err, 2, ["cannot write", "not writable"])


@pytest.mark.parametrize("fill,failing", [(4096, "a.png"), (8192, "a.exr")])
def test_full_disk(fill, failing, tiny, tmp_path, capfd):
    """A real full disk (tmpfs of four pages): with one page left the new EXR fits but its
    PNG does not; with none, the EXR fails.  Either way the old pair stays, with no
    temporaries (the EXR and PNG writers ignore ENOSPC: written through Python's I/O)."""
    with _mounted_tmpfs(tmp_path / "disk", "size=16k") as disk:
        out = disk / "a.exr"
        assert run_main(capfd, "render", tiny, "-o", out)[0] == 0
        old = _pair(out)
        (disk / "fill").write_bytes(b"\0" * fill)
        rc, _, err = run_main(capfd, "render", tiny, "--seed", 9, "-o", out)
        assert_error(rc, err, 2, [f"cannot write {disk / failing}: No space left on device"])
        assert _pair(out) == old
        assert no_temporaries(disk)


def test_stale_temporaries_are_removed(tiny, tmp_path, capfd):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    live = os.getpid()
    stale = [f".o.{dead.pid}.abcd1234.exr", f".o.{dead.pid}.abcd1234.png",
             f".o.{dead.pid}.efgh5678.bak.exr", ".o.k2j4h5g6.exr"]
    keep = [f".o.{live}.zzzz9999.exr", ".other.123.abcd1234.exr", f".o.x.{dead.pid}.a.exr"]
    for n in stale + keep:
        (tmp_path / n).write_bytes(b"partial")
    old = time.time() - 7200
    os.utime(tmp_path / ".o.k2j4h5g6.exr", (old, old))
    rc, _, err = run_main(capfd, "render", tiny, "-o", tmp_path / "o.exr")
    assert rc == 0 and err == [], err
    names = {p.name for p in tmp_path.iterdir()}
    assert not names & set(stale), names & set(stale)
    assert set(keep) <= names


# =============================================================================================
# subprocesses: signals at controlled moments, SIGKILL, concurrent renders
def _env(**extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("INTEGRATORS_TEST_FAULT", None)
    env.update({k: str(v) for k, v in extra.items()})
    return env


def _spawn(args, tmp_path, pause_at=None, pause_s=1.0, env_extra=None, **kw):
    mark = tmp_path / "paused"
    env = _env(INTEGRATORS_TEST_PAUSE_AT=pause_at or "", INTEGRATORS_TEST_PAUSE_FILE=mark,
               INTEGRATORS_TEST_PAUSE_SECONDS=pause_s, **(env_extra or {}))
    p = subprocess.Popen([sys.executable, "-m", "integrators", *map(str, args)], env=env,
                         cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, **kw)
    return p, mark


def _wait_for(mark, p, timeout=60):
    t0 = time.monotonic()
    while not mark.exists():
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < timeout, "the process never reached the pause"
        time.sleep(0.005)


SIGNAL_CASES = [
    # (id, pause point, pause seconds, delay after the mark, signal, extra args, status,
    #  stderr lines, output written: True, False, or None for either -- a signal sent during
    #  imports or the first kernel's compilation may land after the first pass on a fast
    #  machine, and then the render stops after the pass in flight and writes it)
    ("sigint-at-start", "start", 3, 0, signal.SIGINT, [], 130, 1, False),
    ("sigterm-at-start", "start", 3, 0, signal.SIGTERM, [], 143, 1, False),
    ("sigint-during-imports", "start", 0, 0.15, signal.SIGINT, ["--time", 30], 130, 1, None),
    ("sigint-at-scene-load", "load", 3, 0, signal.SIGINT, [], 130, 1, False),
    ("sigint-during-compile", "compile", 0, 0, signal.SIGINT, ["--time", 30], 130, 1, None),
    ("sigint-mid-render", "pass", 1, 0, signal.SIGINT, ["--time", 30], 130, 1, True),
    ("sigterm-mid-render", "pass", 1, 0, signal.SIGTERM, ["--time", 30], 143, 1, True),
    ("sigint-during-write", "write", 1, 0, signal.SIGINT, [], 130, 1, True),
    ("sigterm-between-exr-and-png", "png", 1, 0, signal.SIGTERM, [], 143, 1, True),
    ("sigint-between-renames", "rename", 1, 0, signal.SIGINT, [], 130, 1, True),
]


@pytest.mark.parametrize("case", SIGNAL_CASES, ids=[c[0] for c in SIGNAL_CASES])
def test_signal(case, tiny, tmp_path):
    _, point, pause_s, delay, sig, extra, status, nlines, written = case
    out = tmp_path / "o.exr"
    p, mark = _spawn(["render", tiny, "-o", out, *extra], tmp_path, point, pause_s)
    _wait_for(mark, p)
    time.sleep(delay)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=120)
    err = lines(stderr)
    assert p.returncode == status, (p.returncode, stderr)
    assert len(err) == nlines and "Traceback" not in stderr, stderr
    assert signal.Signals(sig).name in err[0]
    if written is None:
        written = out.exists()
    assert out.exists() == written and out.with_suffix(".png").exists() == written
    if written:
        layers, meta = read_layers(out)
        assert meta["spp"] > 0 and np.all(np.isfinite(layers[""]))
        assert f"stopped by {signal.Signals(sig).name}" in stdout
    else:
        assert "nothing written" in err[0]
    assert no_temporaries(tmp_path)


# Mitsuba's render binding installs its SIGINT handler and only then stores the handler it
# replaced (a static that starts as SIG_DFL): a SIGINT in that gap, in the first render of a
# process, used to kill the command outright (status -2, nothing on stderr; CI caught it once in
# sigint-during-compile).  This shim widens the gap: glibc's signal() (which only Mitsuba calls;
# Python uses sigaction) sleeps after its first SIGINT install, and marks a file meanwhile, so the
# signal can be sent right inside it.  Negative control: without interrupt.prime_mitsuba the
# process dies of the signal (the mutant "no-mitsuba-sigint-priming").
_SHIM = r"""
#define _GNU_SOURCE
#include <dlfcn.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>
typedef void (*handler_t)(int);
static int calls;
handler_t signal(int sig, handler_t h) {
    static handler_t (*real)(int, handler_t);
    if (!real) real = (handler_t (*)(int, handler_t)) dlsym(RTLD_NEXT, "signal");
    handler_t old = real(sig, h);
    const char *mark = getenv("SHIM_MARK");
    if (sig == SIGINT && mark && calls++ == 0) {
        FILE *f = fopen(mark, "w");
        if (f) fclose(f);
        usleep(1500000);
    }
    return old;
}
"""


@pytest.fixture(scope="module")
def signal_gap_shim(tmp_path_factory):
    import shutil
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler to build the signal() shim")
    d = tmp_path_factory.mktemp("shim")
    (d / "shim.c").write_text(_SHIM)
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(d / "shim.so"), str(d / "shim.c"),
                    "-ldl"], check=True, capture_output=True)
    return d / "shim.so"


def test_sigint_in_mitsubas_first_handler_install_is_one_line(signal_gap_shim, tiny, tmp_path):
    out = tmp_path / "o.exr"
    gap = tmp_path / "in-the-gap"
    p, _ = _spawn(["render", tiny, "-o", out, "--time", 30], tmp_path,
                  env_extra={"LD_PRELOAD": signal_gap_shim, "SHIM_MARK": gap})
    t0 = time.monotonic()
    while not gap.exists():
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < 60, "Mitsuba's render binding was never called"
        time.sleep(0.005)
    p.send_signal(signal.SIGINT)
    _, stderr = p.communicate(timeout=120)
    err = lines(stderr)
    assert p.returncode == 130, (p.returncode, stderr)
    assert len(err) == 1 and "SIGINT" in err[0] and "Traceback" not in stderr, stderr
    assert no_temporaries(tmp_path)


def test_second_sigint_abandons_the_pass_and_keeps_the_finished_ones(tiny, tmp_path):
    out = tmp_path / "o.exr"
    p, mark = _spawn(["render", tiny, "-o", out, "--time", 30], tmp_path, "pass", 2)
    _wait_for(mark, p)
    p.send_signal(signal.SIGINT)
    time.sleep(0.3)
    p.send_signal(signal.SIGINT)
    _, stderr = p.communicate(timeout=60)
    err = lines(stderr)
    assert p.returncode == 130 and len(err) == 2 and "Traceback" not in stderr, stderr
    assert "abandoned the pass in flight" in err[1] and str(out) in err[1]
    assert read_layers(out)[1]["spp"] > 0 and no_temporaries(tmp_path)


def test_signal_during_the_write_keeps_the_old_output_until_the_new_one_is_complete(tiny,
                                                                                   tmp_path):
    out = tmp_path / "o.exr"
    assert cli.main(["render", str(tiny), "-o", str(out)]) == 0
    old = _pair(out)
    p, mark = _spawn(["render", tiny, "--seed", 70, "-o", out], tmp_path, "png", 1)
    _wait_for(mark, p)
    assert _pair(out) == old             # mid-write: the old pair is still there, whole
    p.send_signal(signal.SIGINT)
    p.communicate(timeout=60)
    assert p.returncode == 130
    assert _pair(out) != old and _pair_matches(out)
    assert read_layers(out)[1]["seed_first"] == 70


def test_sigint_during_merge_write(runs, tmp_path):
    m = tmp_path / "m.exr"
    p, mark = _spawn(["merge", runs["a"], runs["b"], "-o", m], tmp_path, "write", 1)
    _wait_for(mark, p)
    p.send_signal(signal.SIGINT)
    _, stderr = p.communicate(timeout=60)
    assert p.returncode == 130 and len(lines(stderr)) == 1, stderr
    assert read_layers(m)[1]["spp"] == 4 and m.with_suffix(".png").exists()


def test_sigkill_mid_write_leaves_temporaries_the_next_run_removes(tiny, tmp_path):
    out = tmp_path / "o.exr"
    assert cli.main(["render", str(tiny), "-o", str(out)]) == 0
    old = _pair(out)
    p, mark = _spawn(["render", tiny, "--seed", 80, "-o", out], tmp_path, "png", 5)
    _wait_for(mark, p)
    p.kill()
    p.communicate(timeout=60)
    left = [n.name for n in tmp_path.iterdir() if n.name.startswith(".o.")]
    assert left, "the killed write should have left its temporaries"
    assert _pair(out) == old
    assert cli.main(["render", str(tiny), "--seed", "90", "-o", str(out)]) == 0
    assert no_temporaries(tmp_path)
    assert read_layers(out)[1]["seed_first"] == 90


def test_concurrent_renders_to_one_output(tiny, tmp_path):
    """Three renders of one output at once: all succeed, and what is left is one complete,
    matching EXR + PNG pair (the PNG is the preview of that very EXR) and no temporaries."""
    out = tmp_path / "o.exr"
    procs = [subprocess.Popen([sys.executable, "-m", "integrators", "render", str(tiny),
                               "--seed", str(1000 * i), "-o", str(out)], env=_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(3)]
    for p in procs:
        _, stderr = p.communicate(timeout=120)
        assert p.returncode == 0 and stderr == "", stderr
    assert _pair_matches(out)
    assert read_layers(out)[1]["seed_first"] in (0, 1000, 2000)
    assert no_temporaries(tmp_path)


def test_dev_resolves_relative_paths_against_the_callers_directory(tmp_path):
    sub = tmp_path / "work"
    sub.mkdir()
    write_scene(sub, scene_xml(), "rel.xml")
    r = subprocess.run([str(ROOT / "dev"), "render", "rel.xml", "-o", "out/rel.exr"], cwd=sub,
                       env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (sub / "out" / "rel.exr").is_file() and (sub / "out" / "rel.png").is_file()
    r = subprocess.run([str(ROOT / "dev"), "render", "missing.xml"], cwd=sub, env=_env(),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and lines(r.stderr) == ["error: scene file not found: missing.xml"]


def test_corpus_size():
    n = (len(CLI_CASES) + len(OTHER_USAGE) + len(_param_cases()) + len(SCENE_CASES)
         + len(MERGE_CASES) + len(SIGNAL_CASES))
    assert n >= 100, n
