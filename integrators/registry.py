"""Registry: XML plugin name -> plugin class, and registration with Mitsuba.

Python plugins must derive from the *active variant's* ``mi.BSDF`` / ``mi.SamplingIntegrator``,
and nanobind allows a single base class.  So plugins are written as plain template classes
(decorated with :func:`plugin`) and the variant's class is made from the template at registration
time (:func:`build`): the template's namespace (its own and its template bases') over the
variant's Mitsuba base.  Templates call ``self._base.__init__(self, props)`` instead of
``super()``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mitsuba as mi

from .params import Param


@dataclass
class Plugin:
    name: str
    kind: str                 # 'bsdf' | 'integrator'
    template: type
    params: Sequence[Param]
    summary: str


_PLUGINS: dict[str, Plugin] = {}
_BUILT: dict[tuple[str, str], type] = {}
_BASES = {"bsdf": "BSDF", "integrator": "SamplingIntegrator"}
_REGISTER = {"bsdf": "register_bsdf", "integrator": "register_integrator"}


def plugin(name: str, kind: str):
    """Class decorator: declare a plugin template under its XML name."""
    def deco(template):
        doc = (template.__doc__ or "").strip().splitlines()
        _PLUGINS[name] = Plugin(name, kind, template, tuple(template.PARAMS),
                                doc[0] if doc else "")
        template.NAME = name
        return template
    return deco


def plugins() -> dict[str, Plugin]:
    _load_all()
    return dict(_PLUGINS)


def build(p: Plugin, variant: str | None = None) -> type:
    """The class of plugin ``p`` for the active variant (cached)."""
    variant = variant or mi.variant()
    key = (p.name, variant)
    if key not in _BUILT:
        base = getattr(mi, _BASES[p.kind])
        ns = {}
        for klass in reversed(p.template.__mro__):
            if klass is object:
                continue
            ns.update({k: v for k, v in vars(klass).items()
                       if k not in ("__dict__", "__weakref__")})
        ns["_base"] = base
        ns["__qualname__"] = ns["__name__"] = p.template.__name__
        _BUILT[key] = type(p.template.__name__, (base,), ns)
    return _BUILT[key]


def register_all() -> None:
    """Register every plugin with Mitsuba for the active variant."""
    _load_all()
    for p in _PLUGINS.values():
        cls = build(p)
        getattr(mi, _REGISTER[p.kind])(p.name, lambda props, cls=cls: cls(props))


def _load_all() -> None:
    # importing the plugin modules fills _PLUGINS through the decorator
    from . import phong, bsdf_path, direct_mis, nee_path, mis3  # noqa: F401
