"""The mutation harness as a (slow) test: every planted bias must be killed.

Run with ``./dev test -m slow`` (about a minute; the default suite deselects it)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_every_planted_bias_is_killed():
    r = subprocess.run([sys.executable, str(ROOT / "tests" / "mutation.py")], cwd=ROOT,
                       capture_output=True, text=True, timeout=3600)
    last = r.stdout.strip().splitlines()[-1]
    killed, _, total = last.removeprefix("killed ").partition(" of ")
    assert r.returncode == 0 and killed == total, r.stdout
