"""nee_path: closed forms for every Russian-roulette mode, and the same expected image as
Mitsuba's built-in ``path`` (an independent implementation) on the Cornell box.

Closed-form checks: H0 unbiased, Student t on 32 batch means, Sidak over RGB, alpha = 1e-4, and
relative standard error < 0.5 %.  Image checks: H0 "same expected image", Welch t on 4x4-pixel
blocks with both sides' variances, Sidak over all blocks and channels, alpha = 1e-4
(integrators.testing.image_test).  Negative controls: Mitsuba's path with max_depth 7 against
ours with 8, Russian roulette without compensation, a split weight of 1/(k-1)."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import pytest

import integrators  # noqa: F401
from integrators import testing
from integrators.sampling.roulette import RR_MODES
from integrators.testing import assert_unbiased, check_unbiased, closed_box

ROOT = Path(__file__).resolve().parents[1]
# closed box (rho 0.5, le 1): 32 batches of 4096 spp, alpha DEFAULT_ALPHA, relative s.e. < 0.5 %;
# images: 16 batches of 512 spp against as many of Mitsuba's path, 4x4 blocks, median relative
# s.e. of a block < 0.5 %
IMAGES = {"batches": 16, "spp": 512}


@pytest.mark.parametrize("rr", RR_MODES)
@pytest.mark.parametrize("max_depth", [-1, 3])
def test_closed_sphere_every_rr_mode(rr, max_depth):
    if rr == "none" and max_depth == -1:
        max_depth = 40  # without roulette an unlimited path in a closed sphere never ends
    assert_unbiased(*closed_box(max_depth=max_depth),
                    {"type": "nee_path", "rr": rr, "rr_depth": 1, "max_depth": max_depth})


@pytest.mark.parametrize("extra", [{"light_samples": 3, "heuristic": "balance"},
                                   {"light_samples": 0},
                                   {"split": 3, "heuristic": "maximum"},
                                   {"light_selection": "uniform", "heuristic": "partition"}])
def test_closed_sphere_other_settings(extra):
    assert_unbiased(*closed_box(), {"type": "nee_path", **extra})


def test_negative_control_rr_without_compensation(monkeypatch):
    from integrators.sampling import roulette
    orig = roulette.roulette

    def biased(mode, rr_depth, rr_prob, beta, eta, depth, u, active):
        return beta, orig(mode, rr_depth, rr_prob, beta, eta, depth, u, active)[1]
    monkeypatch.setattr(roulette, "roulette", biased)
    r = check_unbiased(*closed_box(), {"type": "nee_path", "rr": "fixed", "rr_depth": 1})
    assert not r.passed, r


@pytest.fixture(scope="module")
def cornell():
    return mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), res="32")


@pytest.fixture(scope="module")
def mitsuba_path_images(cornell):
    return testing.batch_images(cornell, mi.load_dict({"type": "path", "max_depth": 8}),
                                batches=16, spp=512, seed0=1000)


def test_same_image_as_mitsuba_path(cornell, mitsuba_path_images):
    assert_unbiased(cornell, mitsuba_path_images,
                    {"type": "nee_path", "max_depth": 8, "heuristic": "power",
                     "light_selection": "uniform", "rr": "throughput", "light_samples": 1,
                     "split": 1}, **IMAGES)


@pytest.mark.parametrize("extra", [{"light_selection": "power", "heuristic": "balance"},
                                   {"light_samples": 4, "rr": "fixed"}])
def test_other_settings_same_image_as_mitsuba_path(cornell, mitsuba_path_images, extra):
    assert_unbiased(cornell, mitsuba_path_images, {"type": "nee_path", "max_depth": 8, **extra},
                    **IMAGES)


def test_split_k_at_spp_over_k_matches_split_1(cornell):
    one = testing.batch_images(cornell, mi.load_dict({"type": "nee_path", "max_depth": 8}),
                               batches=16, spp=512, seed0=0)
    assert_unbiased(cornell, one, {"type": "nee_path", "max_depth": 8, "split": 4},
                    batches=16, spp=128, seed0=100)


def test_negative_control_max_depth_7_vs_8(cornell, mitsuba_path_images):
    r = check_unbiased(cornell, mitsuba_path_images, {"type": "nee_path", "max_depth": 7},
                       **IMAGES)
    assert not r.passed, r


def test_negative_control_split_weight(monkeypatch):
    from integrators.sampling import roulette
    monkeypatch.setattr(roulette, "split_weight", lambda k: 1.0 / (k - 1))
    r = check_unbiased(*closed_box(), {"type": "nee_path", "split": 4})
    assert not r.passed, r
