"""pytest plugin of the test kit (:mod:`integrators.testing`), loaded through the ``pytest11``
entry point ``integrators`` in every project that installs this package.  It is a top-level
module, outside the ``integrators`` package, so that loading it imports neither the package nor
Mitsuba: pytest starts as fast as without it in projects that never use the fixtures, and a
machine without a usable LLVM still runs their tests (``-p no:integrators`` disables it; with
``PYTEST_DISABLE_PLUGIN_AUTOLOAD`` set, load it with ``-p integrators``).  Naming it a second
time (``-p integrators_pytest``) does nothing.

Fixtures (mitsuba, numpy and scipy are imported only when a fixture is used):

* ``assert_unbiased`` - :func:`integrators.testing.assert_unbiased`;
* ``closed_box``, ``closed_sphere``, ``polygon_light_plane``, ``furnace`` - factories returning
  ``(scene dict, expected radiance)`` (:mod:`integrators.testing.scenes`), e.g.
  ``scene, expected = closed_box(rho=0.5, le=1.0)``.

At the end of a run that made statistical checks through the kit, one line reports how many
and the false-failure bound they imply (the sum of their significance levels).
"""
from __future__ import annotations

import sys

import pytest

_STATS = "integrators.testing.stats"
_DONE = "_integrators_testing_summary_written"
#: the names this plugin can be registered under: its entry-point name and its module name
_ALIASES = ("integrators", __name__)


def pytest_plugin_registered(plugin, plugin_name, manager):
    """Registered under one name, block the other: naming the plugin again (``-p
    integrators_pytest``, ``pytest_plugins``, a conftest registering it) is
    then a no-op instead of pytest's "Plugin already registered under a different name"."""
    if plugin is not sys.modules.get(__name__):
        return
    for name in _ALIASES:
        if name != plugin_name and manager.get_plugin(name) is None \
                and not manager.is_blocked(name):
            manager.set_blocked(name)


@pytest.fixture
def assert_unbiased():
    """:func:`integrators.testing.assert_unbiased`: ``assert_unbiased(scene, expected,
    integrator, spp=..., batches=..., alpha=..., max_rel_se=...)``."""
    from integrators.testing.unbiased import assert_unbiased as f
    return f


@pytest.fixture
def closed_box():
    """Factory ``closed_box(rho=0.5, le=1.0, max_depth=-1, spp=4096)`` -> (scene dict,
    le sum_{k<max_depth} rho^k): camera inside a closed emitting diffuse cube."""
    from integrators.testing.scenes import closed_box as f
    return f


@pytest.fixture
def closed_sphere():
    """Factory ``closed_sphere(rho=0.5, le=1.0, max_depth=-1, spp=4096)``: the same series in
    a closed emitting sphere (integrators without light sampling)."""
    from integrators.testing.scenes import closed_sphere as f
    return f


@pytest.fixture
def polygon_light_plane():
    """Factory ``polygon_light_plane(at=(0.7, 0.3, 0), rects=..., points=(), spp=4096)`` ->
    (scene dict, rho/pi x Lambert's polygon irradiance + point lights): direct light only."""
    from integrators.testing.scenes import polygon_light_plane as f
    return f


@pytest.fixture
def furnace():
    """Factory ``furnace(rho=0.6, env=1.0, bsdf=None, spp=4096)`` -> (scene dict, rho env):
    a sphere of albedo rho in a constant environment."""
    from integrators.testing.scenes import furnace as f
    return f


def pytest_terminal_summary(terminalreporter, config):
    """One line: statistical checks made through the kit and their false-failure bound."""
    stats = sys.modules.get(_STATS)       # not imported: no check ran, nothing to import
    if stats is None or getattr(config, _DONE, False):
        return
    setattr(config, _DONE, True)          # once per run, however often the plugin is loaded
    line = stats.checks_summary()
    if line:
        terminalreporter.write_line(line)
