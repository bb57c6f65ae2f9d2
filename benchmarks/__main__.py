r"""``python -m benchmarks COMMAND [ARGS]``: one entry point for the benchmarks.

    python -m benchmarks run [--quick] [--scenes a b ...] [--methods m1 m2 ...] [--out DIR]
    python -m benchmarks speed [...]        (= python -m benchmarks.speed)
    python -m benchmarks efficiency [...]   (= python -m benchmarks.efficiency)
    python -m benchmarks memory [...]       (= python -m benchmarks.memory)
    python -m benchmarks distributed [...]  (= python -m benchmarks.distributed)

``run`` is the experiments of :mod:`benchmarks.run` (error against time per scene and method,
charts, image grids, report); the others are the older single-purpose benchmarks.
"""
from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "run": "benchmarks.run",
    "speed": "benchmarks.speed",
    "efficiency": "benchmarks.efficiency",
    "memory": "benchmarks.memory",
    "distributed": "benchmarks.distributed",
}


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(__doc__.strip())
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd not in COMMANDS:
        print(f"python -m benchmarks: unknown command {cmd!r}; one of {', '.join(COMMANDS)}",
              file=sys.stderr)
        return 2
    sys.argv = [f"python -m benchmarks {cmd}", *rest]
    result = importlib.import_module(COMMANDS[cmd]).main(rest)
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
