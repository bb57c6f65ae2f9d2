"""Registry: XML plugin name -> plugin template, and registration with Mitsuba per variant.

Python plugins must derive from the *variant's* ``mi.BSDF`` / ``mi.SamplingIntegrator``, and
nanobind allows a single base class.  So plugins are written as plain template classes
(decorated with :func:`plugin`) and the variant's class is made from the template at registration
time (:func:`build`): the template's namespace (its own and its template bases') over the
variant's Mitsuba base.  Templates call ``self._base.__init__(self, props)`` instead of
``super()``.

This module imports no plugin: the plugin modules (``integrators.plugins``) import it and declare
themselves; ``import integrators`` imports them and then calls :func:`install`, which registers
every plugin for the active variant and, through Mitsuba's variant-change callback, for every
variant activated later.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mitsuba as mi

from .params import Param, table


@dataclass
class Plugin:
    name: str
    kind: str                 # 'bsdf' | 'integrator'
    template: type
    params: Sequence[Param]
    summary: str


_PLUGINS: dict[str, Plugin] = {}
_BUILT: dict[tuple[str, str], type] = {}
_REGISTERED: set[str] = set()       # variants whose registration is done
_BASES = {"bsdf": "BSDF", "integrator": "SamplingIntegrator"}
_REGISTER = {"bsdf": "register_bsdf", "integrator": "register_integrator"}


def plugin(name: str, kind: str):
    """Class decorator: declare a plugin template under its XML name."""
    if kind not in _BASES:
        raise ValueError(f"plugin kind {kind!r}; allowed: {', '.join(_BASES)}")

    def deco(template):
        doc = (template.__doc__ or "").strip().splitlines()
        _PLUGINS[name] = Plugin(name, kind, template, tuple(getattr(template, "PARAMS", ())),
                                doc[0] if doc else "")
        template.NAME = name
        if _PLUGINS[name].params:   # the parameter table, from the specs it validates with
            template.__doc__ = (template.__doc__ or "").rstrip() + \
                "\n\n    Parameters:\n\n" + "\n".join(
                    "    " + row for row in table(_PLUGINS[name].params).splitlines()) + "\n"
        # a plugin declared after install() (a user's own) is registered at once
        if mi.variant() is not None and mi.variant() in _REGISTERED:
            _register(_PLUGINS[name], mi.variant())
        return template
    return deco


def plugins() -> dict[str, Plugin]:
    return dict(_PLUGINS)


def _variant_module(variant: str):
    return getattr(mi, variant)


def build(p: Plugin, variant: str | None = None) -> type:
    """The class of plugin ``p`` for ``variant`` (default: the active one), cached."""
    variant = variant or mi.variant()
    key = (p.name, variant)
    if key not in _BUILT:
        base = getattr(_variant_module(variant), _BASES[p.kind])
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


def _register(p: Plugin, variant: str) -> None:
    cls = build(p, variant)
    getattr(_variant_module(variant), _REGISTER[p.kind])(p.name, lambda props, cls=cls: cls(props))


def register_all(variant: str | None = None) -> None:
    """Register every declared plugin with Mitsuba for ``variant`` (default: the active one)."""
    variant = variant or mi.variant()
    if variant is None:
        return
    for p in _PLUGINS.values():
        _register(p, variant)
    _REGISTERED.add(variant)


def _on_variant_change(old, new) -> None:
    if new is not None:
        register_all(new)


_INSTALLED = {"done": False}


def install() -> None:
    """Register for the active variant now and for every variant activated later (once)."""
    if not _INSTALLED["done"]:
        mi.detail.add_variant_callback(_on_variant_change)
        _INSTALLED["done"] = True
    register_all()
