"""What every integrator template shares: reading its parameters, ``to_string``, ``max_depth``."""
from __future__ import annotations

from ..params import Param, read

MAX_DEPTH = Param("max_depth", "int", -1, min=0, allow=(-1,),
                  doc="Longest path depth (-1: unlimited; 1: emitters seen directly; "
                      "2: direct light), Mitsuba's meaning.")


class IntegratorTemplate:
    """Base of our integrator templates (made into ``mi.SamplingIntegrator`` subclasses)."""

    PARAMS: tuple = ()
    NAME = "integrator"

    def __init__(self, props):
        self._base.__init__(self, props)
        self.params = read(self.NAME, self.PARAMS, props)
        for k, v in self.params.items():
            setattr(self, k, v)
        self.setup()

    def setup(self):
        """Derived state from ``self.params`` (override)."""

    def aov_names(self):
        return []

    def to_string(self):
        body = ",\n".join(f"  {k} = {v!r}" for k, v in self.params.items())
        return f"{self.NAME}[\n{body}\n]"
