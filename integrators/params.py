"""Parameter specifications: one source for plugin validation and ``python -m integrators list``.

Each plugin declares a tuple of :class:`Param`.  :func:`read` pulls the values from a Mitsuba
``Properties`` object, checks type and range, and raises :class:`ParameterError` whose message
names the plugin, the parameter, the value and what is allowed.  Unknown parameter names are
rejected the same way (instead of Mitsuba's later "unreferenced property" error).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence


#: upper bound of every count parameter (samples per vertex, continuations): a 32-bit loop counter
#: holds far more, but one camera sample doing more work than this is a mistake, not a render
MAX_COUNT = 1 << 16
#: upper bound of depths (Mitsuba counts them in 32-bit unsigned integers, -1 = unlimited)
MAX_DEPTH_VALUE = (1 << 31) - 1


class ParameterError(ValueError):
    """A plugin parameter has a bad value; the message is meant for the user as is."""


@dataclass(frozen=True)
class Param:
    name: str
    kind: str                      # 'int' | 'float' | 'bool' | 'choice' | 'texture' | 'spectrum'
    default: Any = None
    doc: str = ""
    choices: Sequence[str] = ()
    min: float | None = None       # inclusive lower bound
    max: float | None = None       # inclusive upper bound
    min_exclusive: bool = False    # lower bound is strict (e.g. beta > 0)
    allow: Sequence[Any] = field(default_factory=tuple)  # extra admissible values (-1 = unlimited)

    def allowed(self) -> str:
        """Human readable statement of the admissible values."""
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices)
        if self.kind == "bool":
            return "true or false"
        if self.kind in ("texture", "spectrum"):
            return "a texture or a colour with components in [0, 1]" if self.kind == "texture" \
                else "a colour or spectrum with components in [0, 1]"
        word = "an integer" if self.kind == "int" else "a number"
        lo = hi = ""
        if self.min is not None:
            lo = f"{'>' if self.min_exclusive else '>='} {_fmt(self.min)}"
        if self.max is not None:
            hi = f"<= {_fmt(self.max)}"
        rng = " and ".join(x for x in (lo, hi) if x)
        extra = " or ".join(_fmt(a) for a in self.allow)
        text = f"{word} {rng}".strip()
        return f"{text} (or {extra})" if extra else text

    def describe(self) -> str:
        d = "" if self.default is None else f" (default: {_fmt(self.default)})"
        return f"{self.name}: {self.kind}{d}; {self.allowed()}. {self.doc}".rstrip()


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v)) if abs(v) >= 1 or v == 0 else repr(v)
    return str(v)


def fail(plugin: str, name: str, value: Any, allowed: str) -> ParameterError:
    return ParameterError(f"{plugin}: parameter '{name}' = {value!r} is invalid; allowed: {allowed}")


def check(plugin: str, spec: Param, value: Any) -> Any:
    """Validate one plain (non-texture) value against its spec and return it converted."""
    if spec.kind == "choice":
        if not isinstance(value, str) or value not in spec.choices:
            raise fail(plugin, spec.name, value, spec.allowed())
        return value
    if spec.kind == "bool":
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false"):
            return value.lower() == "true"
        # worded as Mitsuba words a wrongly typed boolean property (hide_emitters is read by
        # Mitsuba first), so every boolean parameter fails with the same kind of line
        raise ParameterError(f"{plugin}: parameter '{spec.name}' = {value!r} is invalid (wrong "
                             f"type for boolean property \"{spec.name}\"); allowed: "
                             f"{spec.allowed()}")
    if spec.kind == "int":
        if isinstance(value, bool):
            raise fail(plugin, spec.name, value, spec.allowed())
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, str):
            try:
                value = int(value)
            except ValueError:
                raise fail(plugin, spec.name, value, spec.allowed()) from None
        if not isinstance(value, int):
            raise fail(plugin, spec.name, value, spec.allowed())
    elif spec.kind == "float":
        if isinstance(value, bool):
            raise fail(plugin, spec.name, value, spec.allowed())
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise fail(plugin, spec.name, value, spec.allowed()) from None
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise fail(plugin, spec.name, value, spec.allowed())
        value = float(value)
    else:
        raise TypeError(f"check() does not handle kind {spec.kind}")
    if value in spec.allow:
        return value
    if spec.min is not None and (value < spec.min or (spec.min_exclusive and value == spec.min)):
        raise fail(plugin, spec.name, value, spec.allowed())
    if spec.max is not None and value > spec.max:
        raise fail(plugin, spec.name, value, spec.allowed())
    return value


def read(plugin: str, specs: Sequence[Param], props) -> dict[str, Any]:
    """Read and validate every plain parameter of ``specs`` from Mitsuba ``props``.

    Texture parameters are not read here (the plugin calls ``props.get_texture``), but they
    count as known names.  Returns ``{name: value}``."""
    known = {s.name for s in specs}
    for key in props.keys():
        if key not in known and not props.was_queried(key):
            names = ", ".join(sorted(known)) or "none"
            raise ParameterError(f"{plugin}: unknown parameter '{key}'; allowed parameters: {names}")
    out = {}
    for s in specs:
        if s.kind in ("texture", "spectrum"):
            continue
        value = props.get(s.name, s.default) if s.name in props else s.default
        out[s.name] = check(plugin, s, value)
    return out


def table(specs: Sequence[Param]) -> str:
    """The parameter table of a plugin (Markdown), from the specs it validates with: the table in
    its docstring, ``python -m integrators list --markdown`` and the README's tables."""
    rows = ["| parameter | type | default | allowed | meaning |", "| --- | --- | --- | --- | --- |"]
    for s in specs:
        v = s.default
        d = "" if v is None else f"`{v:.4g}`" if isinstance(v, float) and not v.is_integer() \
            else f"`{_fmt(v)}`"
        rows.append(f"| `{s.name}` | {s.kind} | {d} | {s.allowed()} | {s.doc} |")
    return "\n".join(rows)
