"""The README's parameter tables and module map match the code."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import integrators  # noqa: F401
from integrators import registry
from integrators.params import table

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_readme_parameter_tables_match_the_specs():
    out = subprocess.run([sys.executable, "-m", "integrators", "list", "--markdown"],
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout.strip()
    begin, end = "<!-- parameter tables: begin -->", "<!-- parameter tables: end -->"
    section = README[README.index(begin) + len(begin):README.index(end)].strip()
    assert section == out, "README parameter tables are stale: paste `./dev list --markdown`"


def test_every_plugin_docstring_holds_its_parameter_table():
    for name, p in registry.plugins().items():
        doc = p.template.__doc__ or ""
        for row in table(p.params).splitlines():
            assert row in doc, (name, row)


def test_module_map_matches_the_tree():
    block = README[README.index("## Module map"):README.index("## Parameters")]
    listed = set(re.findall(r"^\s+(\w+\.py)\s", block, re.M))
    pkg = ROOT / "integrators"
    actual = {f.name for f in pkg.rglob("*.py")
              if f.name not in ("__init__.py", "__main__.py", "_llvm.py")}
    assert actual <= listed, f"modules missing from the README's map: {sorted(actual - listed)}"
    assert listed <= actual | {"__init__.py"}, \
        f"the README's map names modules that do not exist: {sorted(listed - actual)}"
