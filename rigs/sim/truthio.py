"""Writing ``truth.yaml`` quickly.

A 100-frame truth file holds ~16 000 streaks with their centre lines (~10 MB). PyYAML's
representer needs ~20 s for that, so the ``frames`` list is emitted here directly, one flow
mapping per streak (plain YAML that ``yaml.safe_load`` reads back to the same values; the
round trip is tested), and only the small header goes through ``yaml.dump``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from blurtrack.io.yamlio import write_text_atomic
from rigs.sim.errors import SimError


def flow(value: Any) -> str:
    """One value as YAML flow text (bools, ints, finite floats, strings of digits and letters,
    lists and mappings of those).

    >>> flow({"dot": 3, "start": [1.5, 2e-07], "inside": True})
    '{dot: 3, start: [1.5, 2.0e-07], inside: true}'
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return int.__repr__(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise SimError(f"truth holds a non-finite number ({value})")
        r = float.__repr__(value)  # plain digits also for np.float64 (a float subclass)
        # PyYAML (YAML 1.1) reads 1e-07 as a string; it needs the dot, as its own dumper writes.
        return r.replace("e", ".0e") if "e" in r and "." not in r else r
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(flow(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)}: {flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, str) and value.isidentifier():
        return value
    raise SimError(f"truth value {value!r} cannot be written as flow YAML")


def _key(k: Any) -> str:
    if not (isinstance(k, str) and k.isidentifier()):
        raise SimError(f"truth key {k!r} must be an identifier")
    return k


def dump_truth(truth: dict[str, Any]) -> str:
    """YAML text of a truth dict whose ``frames`` list (if any) comes last."""
    head = {k: v for k, v in truth.items() if k != "frames"}
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    parts = [yaml.dump(head, Dumper=dumper, sort_keys=False, default_flow_style=None, width=100)]
    if "frames" in truth:
        parts.append("frames:\n" if truth["frames"] else "frames: []\n")
        for fr in truth["frames"]:
            first = True
            for k, v in fr.items():
                lead = "- " if first else "  "
                first = False
                if k == "streaks" and v:
                    parts.append(f"{lead}streaks:\n")
                    parts.extend(f"  - {flow(s)}\n" for s in v)
                else:
                    parts.append(f"{lead}{_key(k)}: {flow(v)}\n")
    return "".join(parts)


def write_truth(path: str | Path, truth: dict[str, Any]) -> None:
    """Write ``truth.yaml`` atomically."""
    write_text_atomic(path, dump_truth(truth))
