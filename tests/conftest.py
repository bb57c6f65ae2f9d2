import pathlib
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def pytest_configure(config):
    """The test kit's pytest plugin (fixtures, the line counting statistical checks) comes
    through its ``pytest11`` entry point; register it here only where autoloading is off
    (PYTEST_DISABLE_PLUGIN_AUTOLOAD) and it was neither loaded nor blocked (-p no:integrators)."""
    pm = config.pluginmanager
    if pm.has_plugin("integrators") or pm.is_blocked("integrators"):
        return
    import integrators_pytest as pytest_plugin
    if not pm.is_registered(pytest_plugin):
        pm.register(pytest_plugin, "integrators")


@pytest.fixture(scope="module")
def specular_box():
    """``scenes/specular_box.xml`` (a glass sphere inside a null box, a mirror sphere, a phong
    box) at 24 px: the glass, mirror and null-boundary scene of the unbiasedness tests."""
    import mitsuba as mi
    return mi.load_file(str(ROOT / "scenes" / "specular_box.xml"), res="24")


@pytest.fixture(scope="module")
def specular_box_path(specular_box):
    """Mitsuba's ``path`` (max_depth 6) on it: 16 batches of 1024 spp, the reference side."""
    import mitsuba as mi
    from integrators import testing
    return testing.batch_images(specular_box, mi.load_dict({"type": "path", "max_depth": 6}),
                                batches=16, spp=1024, seed0=777)
