"""SIGINT and SIGTERM for the command line: at any moment they end the process with status 130 /
143 and one line on stderr, never a traceback, and never lose an output being written.

What a signal does depends on how far the run is (:class:`Interrupts`):

* **start-up** (imports, scene load, kernel compile, the first pass: nothing to keep yet): the
  process ends at once (``os._exit``: no Python or Dr.Jit teardown that could crash half-way);
  an existing output file is left as it was;
* **rendering** (a ``keeper`` is set once a pass has finished): the first signal asks the render
  to stop after the pass in flight (``keeper.stop``), which then writes what was accumulated; a
  second one abandons the pass in flight: the passes finished so far are written
  (``keeper.abandon``) and the process ends;
* **writing** (inside :func:`deferred`): signals are held until the outputs are complete, then
  acted on as above;
* **finished** (``finish()``: the final write is done or under way): the signal is noted; the
  command exits with its status once the write is complete.

``python -m integrators`` installs the handlers before Dr.Jit and Mitsuba are imported
(:func:`early`, called first thing by ``integrators/__init__``); a library user who imports
``integrators`` keeps Python's own handlers.

Mitsuba's render binding has a start-up race that the command line closes
(:func:`prime_mitsuba`): each call installs a C-level SIGINT handler that cancels the render
and re-raises the signal to the handler it replaced, which it keeps in a static variable that
starts out as ``SIG_DFL`` and is assigned only after the new handler is in place. A SIGINT in
that gap during the process's first render killed it outright (status -2, nothing on stderr).
The command line therefore holds SIGINT blocked from :func:`early` (so the threads Dr.Jit and
Mitsuba start while importing never take it) through one throw-away call of the binding per
variant, made with SIGINT blocked, which leaves Python's handler in that variable; a SIGINT
sent meanwhile waits and is acted on as soon as the hold ends (:func:`release`).

Test-only hooks (environment variables read by :func:`test_pause`; nothing else reads them):
``INTEGRATORS_TEST_PAUSE_AT`` is a comma-separated list of points (``start``, ``load``,
``compile``, ``pass``, ``write``, ``png``, ``rename``); at each, the process appends the point's
name and a newline to the file ``INTEGRATORS_TEST_PAUSE_FILE`` (if set) and sleeps
``INTEGRATORS_TEST_PAUSE_SECONDS`` (default 0), so a test can send a signal at a known moment.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time

EXIT_STATUS = {"SIGINT": 130, "SIGTERM": 143}
_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_active: "Interrupts | None" = None


def _say(line: str) -> None:
    with contextlib.suppress(Exception):
        sys.stderr.write(line.rstrip("\n") + "\n")
        sys.stderr.flush()


def exit_now(status: int, line: str | None = None) -> None:
    """End the process at once with ``status`` (after ``line`` on stderr): no exception that
    could be caught or printed as a traceback, no interpreter teardown."""
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    if line:
        _say(line)
    os._exit(status)


class Interrupts:
    """The process's SIGINT/SIGTERM handling (see the module docstring)."""

    def __init__(self):
        self.received: list[str] = []     # signals acted on, in order
        self.pending: list[str] = []      # signals held by a deferred() section
        self.depth = 0
        self.keeper = None                # set once there is something to keep
        self.finished = False
        self.installed = False
        #: what an interruption with nothing to keep says ("before the first pass finished")
        self.before = ""
        self.old: dict = {}

    # -------------------------------------------------------------------------------------
    def install(self) -> "Interrupts":
        if not self.installed and threading.current_thread() is threading.main_thread():
            self.old = {s: signal.getsignal(s) for s in _SIGNALS}
            for s in _SIGNALS:
                signal.signal(s, self._handler)
            self.installed = True
        return self

    def restore(self) -> None:
        if self.installed:
            for s, h in self.old.items():
                signal.signal(s, h if h is not None else signal.SIG_DFL)
            self.installed = False

    @property
    def status(self) -> int:
        """Exit status the signals received ask for (0 if none)."""
        return EXIT_STATUS[self.received[0]] if self.received else 0

    def finish(self) -> None:
        """From here on a signal is only noted: the command is writing its final output."""
        self.finished = True

    # -------------------------------------------------------------------------------------
    def _handler(self, signum, frame):
        name = signal.Signals(signum).name
        if self.depth and not self.finished:
            self.pending.append(name)
            return
        self._act(name)

    def _act(self, name: str) -> None:
        first = not self.received
        self.received.append(name)
        status = EXIT_STATUS[self.received[0]]
        if self.finished:
            if first:
                _say(f"{name}: the output is being written; exiting with status {status} after")
            return
        if self.keeper is None:
            exit_now(status, f"{name}: interrupted{self.before}; nothing written")
        if first:
            self.keeper.stop(name)
            return
        with self.deferred():
            line = self.keeper.abandon(name)
        exit_now(status, line)

    @contextlib.contextmanager
    def deferred(self):
        """Hold SIGINT/SIGTERM while the block runs (writing outputs, updating the sums)."""
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1
            if self.depth == 0 and self.pending:
                pending, self.pending = self.pending, []
                for name in pending:
                    self._act(name)


def active() -> Interrupts | None:
    return _active


def install() -> Interrupts:
    """The process's :class:`Interrupts` (installed now, or by :func:`early`)."""
    global _active
    if _active is None:
        _active = Interrupts()
    return _active.install()


def uninstall(ints: Interrupts) -> None:
    """Restore the handlers that were there before :func:`install` (not for the command line
    process itself, which keeps them until it exits)."""
    global _active
    if ints is _active and not _EARLY:
        ints.restore()
        _active = None


@contextlib.contextmanager
def deferred():
    """:meth:`Interrupts.deferred` of the installed handlers; nothing when there are none."""
    if _active is None or not _active.installed:
        yield
        return
    with _active.deferred():
        yield


_EARLY = False


def _is_command_line() -> bool:
    argv = list(getattr(sys, "orig_argv", None) or [])      # Python >= 3.10
    for i, a in enumerate(argv[:-1]):
        if a == "-m":
            return argv[i + 1] == "integrators"
    if not sys.argv:
        return False
    return sys.argv[0] == "-m" and not argv or os.path.basename(sys.argv[0]) == "integrators"


def early() -> None:
    """Install the handlers before anything slow is imported, when this process is the command
    line (``python -m integrators``, or the ``integrators`` console script)."""
    global _EARLY
    if _EARLY or not _is_command_line():
        return
    install()
    _EARLY = True
    if _CAN_MASK and threading.current_thread() is threading.main_thread():
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})   # until release()
    test_pause("start")


_primed: set = set()
#: POSIX signal masks (Mitsuba installs its handler only on Linux and macOS, which have them)
_CAN_MASK = hasattr(signal, "pthread_sigmask")


def prime_mitsuba() -> None:
    """Command line only: one call of Mitsuba's render binding in the current variant that
    fails at once (an empty scene has no sensor 0) after its SIGINT handler has been installed
    and removed again, made with SIGINT blocked in this thread, so that the binding's saved
    "previous handler" is Python's before the first real render (see the module docstring)."""
    if not (_EARLY and _CAN_MASK) or threading.current_thread() is not threading.main_thread():
        return
    import mitsuba as mi
    variant = mi.variant()
    if variant is None or variant in _primed:
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        scene = mi.load_dict({"type": "scene"})
        integrator = mi.load_dict({"type": "path"})
        with contextlib.suppress(Exception):
            integrator.render(scene, 0)       # "sensor index 0 is out of bounds"
        _primed.add(variant)
    except Exception:      # priming is a precaution: never a reason for the command to fail
        pass
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def release() -> None:
    """End the hold that :func:`early` put on SIGINT (a signal sent meanwhile is acted on now)."""
    if _EARLY and _CAN_MASK and threading.current_thread() is threading.main_thread():
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def test_pause(point: str) -> None:
    """Test-only hook (see the module docstring): mark and pause at ``point``."""
    points = os.environ.get("INTEGRATORS_TEST_PAUSE_AT")
    if not points or point not in points.split(","):
        return
    mark = os.environ.get("INTEGRATORS_TEST_PAUSE_FILE")
    if mark:
        with open(mark, "a") as f:
            f.write(point + "\n")
    seconds = float(os.environ.get("INTEGRATORS_TEST_PAUSE_SECONDS", "0") or 0)
    end = time.monotonic() + seconds
    while True:     # a handler that returns resumes the sleep (PEP 475); be explicit anyway
        left = end - time.monotonic()
        if left <= 0:
            break
        time.sleep(min(left, 0.05))
