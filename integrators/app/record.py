"""The run record: everything that determines a render's expected image and its samples.

One object, :class:`RunRecord`, describes a run: the scene (path and SHA-1 of its file), the
integrator (plugin name and every parameter), the Mitsuba variant, the ``-D`` defines, the seed
range, the samples per pixel, the number of passes and the seconds spent.  ``render`` writes it
into the EXR header, ``merge`` checks it (:meth:`RunRecord.merge_problem`: a scene whose SHA-1
differs, another integrator, variant or defines, overlapping seeds), and the experiments key
their reference cache by it (:meth:`RunRecord.key`).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

#: fields that decide the expected image (runs that agree on them may be merged)
IDENTITY = ("scene_sha1", "integrator", "params", "variant", "defines")

#: typed EXR header attributes of a record (besides ``params`` and ``defines`` as JSON strings
#: and the whole record as the JSON string ``run_record``, the one read back)
HEADER_INTS = ("spp", "passes", "seed_first", "seed_last")
HEADER_FLOATS = ("seconds",)
HEADER_STRINGS = ("scene", "scene_sha1", "integrator", "variant")


def file_sha1(path) -> str:
    return hashlib.sha1(Path(path).read_bytes()).hexdigest()


def integrator_description(integrator) -> tuple[str, dict]:
    """(plugin name, {parameter: value}) of a loaded integrator: ours report every resolved
    parameter; Mitsuba's built-ins only their class name (their ``to_string`` text is kept)."""
    params = getattr(integrator, "params", None)
    name = getattr(integrator, "NAME", None)
    if isinstance(params, dict) and name:
        return name, {k: v for k, v in params.items()}
    text = " ".join(str(integrator).split())
    return text.split("[", 1)[0].strip() or type(integrator).__name__, {"description": text}


@dataclass
class RunRecord:
    scene: str = ""                 # path of the scene file as given (resolved)
    scene_sha1: str = ""
    integrator: str = ""            # plugin name
    params: dict = field(default_factory=dict)
    variant: str = ""
    defines: dict = field(default_factory=dict)
    seed_first: int = 0
    seed_last: int = -1
    spp: int = 0
    passes: int = 0
    seconds: float = 0.0
    #: seed ranges of merged runs ([[first, last], ...]); one entry for a single run
    seed_ranges: list = field(default_factory=list)
    #: what the integrator says of its own state after the run (``run_notes()``: e.g. what a
    #: learning integrator learned and when it stopped); not part of the identity
    notes: dict = field(default_factory=dict)

    # -------------------------------------------------------------------------------------
    @classmethod
    def for_scene(cls, scene_path, integrator, variant: str, defines: dict | None = None,
                  **kw) -> "RunRecord":
        name, params = integrator_description(integrator)
        path = Path(scene_path)
        return cls(scene=str(path.resolve()), scene_sha1=file_sha1(path), integrator=name,
                   params=params, variant=variant, defines=dict(sorted((defines or {}).items())),
                   **kw)

    def identity(self) -> dict:
        return {k: getattr(self, k) for k in IDENTITY}

    def key(self, *extra: Any) -> str:
        """Stable hex key of this record (identity, spp, seed range) and any ``extra`` values:
        a cache key for a render made from it."""
        body = {**self.identity(), "spp": self.spp, "seed_first": self.seed_first,
                "seed_last": self.seed_last, "extra": [str(e) for e in extra]}
        text = json.dumps(body, sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    # -------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "RunRecord":
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, default=str)

    @classmethod
    def from_json(cls, text: str) -> "RunRecord":
        d = json.loads(text)
        if not isinstance(d, dict):
            raise ValueError("a run record is a JSON object")
        return cls.from_dict(d)

    def header(self) -> dict:
        """EXR header attributes: typed copies of the main fields (for other tools) and the
        whole record as JSON (``run_record``)."""
        h: dict = {k: int(getattr(self, k)) for k in HEADER_INTS}
        h.update({k: float(getattr(self, k)) for k in HEADER_FLOATS})
        h.update({k: str(getattr(self, k)) for k in HEADER_STRINGS})
        h["params"] = json.dumps(self.params, sort_keys=True, default=str)
        h["defines"] = json.dumps(self.defines, sort_keys=True, default=str)
        h["run_record"] = self.to_json()
        return h

    @classmethod
    def from_header(cls, header: dict) -> "RunRecord":
        """The record of an EXR header: its ``run_record``, or for files written before there
        was one, the loose ``spp``, ``passes``, ``seed_first``, ``seed_last`` (and
        ``seconds``, ``scene``, ...) attributes.  Raises ValueError (or KeyError) without."""
        if "run_record" in header:
            return cls.from_json(str(header["run_record"]))
        rec = cls(**{k: int(header[k]) for k in HEADER_INTS},
                  seconds=float(header.get("seconds", 0.0)),
                  **{k: str(header[k]) for k in ("scene", "scene_sha1", "integrator", "variant")
                     if k in header})
        rec.seed_ranges = [[rec.seed_first, rec.seed_last]]
        return rec

    def ranges(self) -> list[tuple[int, int]]:
        """The seed ranges of this run (one, or one per merged run); empty ranges left out."""
        rs = self.seed_ranges or [[self.seed_first, self.seed_last]]
        return [(int(f), int(l)) for f, l in rs if l >= f]

    # -------------------------------------------------------------------------------------
    def merge_problem(self, other: "RunRecord", name_self: str = "", name_other: str = "") \
            -> str | None:
        """One line saying why ``other`` cannot be merged with this run, or None."""
        a, b = name_self or "the first run", name_other or "this run"
        if self.scene_sha1 != other.scene_sha1:
            return (f"{b} rendered scene {other.scene} (sha1 {other.scene_sha1[:12]}) but {a} "
                    f"rendered {self.scene} (sha1 {self.scene_sha1[:12]}): the scene file differs; "
                    "only runs of the same scene can be merged")
        for k in ("integrator", "params", "variant", "defines"):
            if getattr(self, k) != getattr(other, k):
                return (f"{b} and {a} differ in {k}: {b} has {getattr(other, k)!r}, {a} has "
                        f"{getattr(self, k)!r}; only runs of the same scene and integrator can "
                        "be merged")
        for f1, l1 in self.ranges():
            for f2, l2 in other.ranges():
                if f1 <= l2 and f2 <= l1:
                    return (f"{a} (seeds {f1}-{l1}) and {b} (seeds {f2}-{l2}) overlap: their "
                            "samples are not independent; render with disjoint --seed ranges")
        return None

    def merged(self, other: "RunRecord") -> "RunRecord":
        """The record of this run and ``other`` merged (sample counts and seeds added)."""
        ranges = sorted(self.ranges() + other.ranges())
        return replace(self, spp=self.spp + other.spp, passes=self.passes + other.passes,
                       seconds=self.seconds + other.seconds,
                       seed_first=min(self.seed_first, other.seed_first),
                       seed_last=max(self.seed_last, other.seed_last),
                       seed_ranges=[list(r) for r in ranges])
