import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))


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
