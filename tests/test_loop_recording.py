"""Every symbolic loop of our integrators is recorded once per render call.

Dr.Jit records a loop a second time when a loop state variable comes out of the body unchanged
and is narrower than the loop, or (with ``JitFlag.OptimizeLoops``) whenever one comes out
unchanged: it logs ``re-recording loop "<label>"`` at the debug level.  Each recording traces
every virtual call in the body over every shape, emitter and BSDF instance, so at thousands of
lights a loop recorded twice costs seconds per render call (:func:`integrators.common.record_once`).
A structural check, not a timing: the render's debug log must hold no such line.  Negative
control: a loop with a narrow loop-invariant state variable is caught by the same check."""
from __future__ import annotations

import ctypes
import pathlib

import drjit as dr
import mitsuba as mi
import pytest

from integrators import common

_LIBC = ctypes.CDLL(None)
ROOT = pathlib.Path(__file__).resolve().parents[1]

CONFIGS = [
    {"type": "nee_path"},
    {"type": "nee_path", "light_selection": "ris"},
    {"type": "nee_path", "light_selection": "bvh", "light_samples": 3},
    {"type": "nee_path", "rr": "adaptive"},
    {"type": "nee_path", "rr": "adaptive", "split_policy": "always"},
    {"type": "nee_path", "split": 2},
    {"type": "mis3"},
    {"type": "mis3", "selection": "fixed"},
    {"type": "mis3", "selection": "adaptive"},
    {"type": "direct_mis", "bsdf_samples": 3},
    {"type": "bsdf_path"},
    {"type": "bdpt"},
    {"type": "pssmlt"},
    {"type": "pssmlt", "estimator": "path"},
]

pytestmark = pytest.mark.skipif(not common.is_jit(), reason="symbolic loops: JIT variants")


def _rerecorded(capfd, fn):
    capfd.readouterr()
    old = dr.log_level()
    dr.set_log_level(dr.LogLevel.Debug)
    try:
        fn()
    finally:
        dr.set_log_level(old)
        _LIBC.fflush(None)           # Dr.Jit logs through C's stdio, buffered off a terminal
    out = capfd.readouterr()
    log = out.out + out.err          # (here Dr.Jit's log goes to standard output)
    assert "jit_var" in log, "the debug log was not captured"

    return [line for line in log.splitlines() if "re-recording loop" in line]


@pytest.fixture(scope="module")
def scene():
    return mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res="16")


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: "-".join(
    f"{v}" for v in c.values()))
def test_every_loop_is_recorded_once(scene, capfd, config):
    integ = mi.load_dict(config)

    def render():
        dr.eval(mi.render(scene, integrator=integ, spp=2, seed=1))
    assert _rerecorded(capfd, render) == []


def test_ears_learning_kernels_recorded_once(scene, capfd, monkeypatch):
    """nee_path rr=adaptive's kernels as a render's passes trace them: the classic parts (the
    second estimates the learned roulette at each of its scales), the learning roulette pass that estimates the throughput rule, the learning split pass that
    estimates the roulette
    (split_policy=auto, the default; its fallbacks held off so that every mode runs)."""
    from integrators.sampling import splitting
    monkeypatch.setattr(splitting, "KERNEL_COST", 0.0)
    monkeypatch.setattr(splitting, "SPLIT_TRY", 0.0)
    integ = mi.load_dict({"type": "nee_path", "rr": "adaptive"})
    modes = []

    def render():
        for k in range(3):
            dr.eval(mi.render(scene, integrator=integ, spp=8, seed=k))
            modes.extend(m for m, _ in integ.stats["parts"])
    assert _rerecorded(capfd, render) == []
    assert modes[:4] == ["classic", "classic", "roulette", "split"], modes


@dr.syntax
def _loop_with_invariant(n, wide):
    limit = mi.UInt32(3)             # read by the body, never changed by it
    i = dr.zeros(mi.UInt32, n)
    if dr.hint(wide, mode="scalar"):
        limit = common.widen(limit, i)
    acc = dr.zeros(mi.Float, n)
    while dr.hint(i < 3, label=f"control wide={wide}"):
        acc += mi.Float(limit)
        i += 1
    return acc


def test_negative_control_a_rerecorded_loop_is_caught(capfd):
    def run(wide):
        return lambda: dr.eval(common.record_once(_loop_with_invariant)(64, wide))
    lines = _rerecorded(capfd, run(False))
    assert len(lines) == 1 and '"control wide=False"' in lines[0]
    # the remedy of record_once's docstring: the invariant as wide as the loop
    assert _rerecorded(capfd, run(True)) == []
