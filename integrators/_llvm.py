"""Find a libLLVM that Dr.Jit's LLVM backend can use.

Dr.Jit 1.5 aborts the process on LLVM 15 ("Cannot select: ... fminimum"), which is the first
libLLVM a fresh Debian 12 machine offers.  LLVM 16 or newer works.  This module must not import
drjit or mitsuba: it runs before them (``import integrators``) and as a script from ``./dev``
(``python integrators/_llvm.py`` prints the path, or nothing and exit status 1).
"""
from __future__ import annotations

import glob
import os
import re
import sys

MIN_VERSION = 16

_SEARCH_DIRS = [
    "/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/lib/x86_64-linux-gnu",
    "/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib",
]


def _version(path: str) -> int | None:
    name = os.path.basename(path)
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"libLLVM\.(\d+)\.dylib",
                    r"libLLVM-(\d+)\.dylib"):
        m = re.search(pattern, name)
        if m:
            return int(m.group(1))
    # /usr/lib/llvm-19/lib/libLLVM.so: take the version from the directory
    m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def candidates() -> list[tuple[int, str]]:
    """(version, path) of every libLLVM found on this machine, newest first."""
    found = {}
    patterns = []
    for d in _SEARCH_DIRS:
        patterns += [f"{d}/libLLVM-*.so*", f"{d}/libLLVM.so.*", f"{d}/libLLVM*.dylib"]
    patterns += ["/usr/lib/llvm-*/lib/libLLVM.so*", "/usr/lib/llvm-*/lib/libLLVM-*.so*"]
    for pat in patterns:
        for path in glob.glob(pat):
            v = _version(path)
            if v is not None and os.path.isfile(path):
                found.setdefault(os.path.realpath(path), (v, path))
    return sorted(found.values(), key=lambda t: (-t[0], t[1]))


def find() -> str | None:
    """Path of the newest libLLVM >= MIN_VERSION, or None."""
    for v, path in candidates():
        if v >= MIN_VERSION:
            return path
    return None


def configure() -> str | None:
    """Point DRJIT_LIBLLVM_PATH at a working LLVM unless the user already chose one.

    Must run before drjit is imported; returns the path in use (or None)."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    path = find()
    if path is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


if __name__ == "__main__":
    p = find()
    if p is None:
        sys.exit(1)
    print(p)
