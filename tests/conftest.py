import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))


def pytest_terminal_summary(terminalreporter):
    """Report how many statistical checks ran and the false-failure bound they imply."""
    try:
        from integrators import testing
    except Exception:
        return
    n = testing.CHECKS["count"]
    if n:
        terminalreporter.write_line(
            f"statistical checks (t / Welch) in this run: {n} at alpha {testing.DEFAULT_ALPHA:g} "
            f"each: false-failure bound {100 * n * testing.DEFAULT_ALPHA:.2f} %")
