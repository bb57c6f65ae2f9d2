"""Where a result came from: the command that produced it, the commit, the machine.

No Mitsuba import here.  :func:`command` rebuilds the command line from how Python was started
(``python -m benchmarks speed ...``, set as ``sys.argv[0]`` by :mod:`benchmarks.__main__`, or
``python -m benchmarks.speed ...``, from ``__main__.__spec__``) and the arguments actually
parsed, so every "Command:" line and ``"command"`` field is the command that made the file.
"""
from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def invoked_as(default: str) -> str:
    """``python -m MODULE [SUBCOMMAND]`` as this process was started; ``default`` when it was
    not started as a module (``main()`` called from Python)."""
    a0 = sys.argv[0] if sys.argv else ""
    if a0.startswith("python -m "):         # benchmarks.__main__ dispatching a subcommand
        return a0
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", None)
    if name:
        if name.endswith(".__main__"):
            name = name[: -len(".__main__")]
        return f"python -m {name}"
    return default


def command(default: str, argv=None) -> str:
    """The command line that ran this: :func:`invoked_as` plus the arguments (``argv`` as given
    to ``main``, else ``sys.argv[1:]``)."""
    args = list(sys.argv[1:] if argv is None else argv)
    prog = invoked_as(default)
    return prog + (" " + shlex.join(args) if args else "")


def git_state() -> dict:
    """{"commit": HEAD or None, "dirty": bool or None} of this working tree."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=REPO, capture_output=True,
                               text=True, check=True).stdout.strip() != ""
        return {"commit": head or None, "dirty": dirty}
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}


def cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def machine() -> dict:
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                         else None),
        "python": platform.python_version(),
    }


def now_utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def home_relative(path) -> str:
    p, home = str(Path(path).resolve()), str(Path.home().resolve())
    return "~" + p[len(home):] if p == home or p.startswith(home + os.sep) else p


def subprocess_env() -> dict:
    """The environment for a child ``python -m benchmarks...``: this repository importable."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    return env


def record(cmd: str, **fields) -> dict:
    """A results file's header: the command, the time, the commit and the machine, then
    ``fields``."""
    return {"command": cmd, "date_utc": now_utc(), "git": git_state(), "machine": machine(),
            **fields}


def command_block(cmd: str) -> list:
    """The Markdown lines of a "Command:" section."""
    return ["Command:", "", "```", cmd, "```", ""]
