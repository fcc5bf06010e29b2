"""How the fields of :mod:`blurtrack.detect.paramsections` are declared and checked: each
numeric field carries its range in its metadata (:func:`num_field`, :func:`int_field`), each
switch says so (:func:`switch_field`), and :func:`check_section` refuses a section whose field
is out of range in one line naming ``detect <section>.<field>``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

from blurtrack.errors import ConfigError


@dataclass(frozen=True)
class Range:
    """The values a numeric field takes: ``lo``..``hi`` (open where ``*_open``), integers only
    with ``integer``, infinity only with ``infinite``."""

    lo: float
    hi: float
    lo_open: bool
    hi_open: bool
    integer: bool
    infinite: bool

    def holds(self, v: Any) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return False
        if self.integer and not isinstance(v, int):
            return False
        if math.isnan(v) or (math.isinf(v) and not self.infinite):
            return False
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return above and below

    def text(self) -> str:
        kind = "an integer " if self.integer else ""
        if math.isinf(self.hi):
            return f"{kind}{'>' if self.lo_open else '>='} {self.lo:g}"
        left, right = "(" if self.lo_open else "[", ")" if self.hi_open else "]"
        return f"{kind}in {left}{self.lo:g}, {self.hi:g}{right}"


def num_field(
    default: float,
    lo: float,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    infinite: bool = False,
) -> Any:
    """A float field with its range (see :class:`Range`)."""
    return field(
        default=default, metadata={"range": Range(lo, hi, lo_open, hi_open, False, infinite)}
    )


def int_field(default: int, lo: int) -> Any:
    """An integer field of at least ``lo``."""
    return field(default=default, metadata={"range": Range(lo, math.inf, False, True, True, False)})


def switch_field(default: bool) -> Any:
    """A true/false field."""
    return field(default=default, metadata={"switch": True})


def check_section(obj: Any, section: str) -> None:
    """Raise a one-line :class:`ConfigError` naming ``detect <section>.<field>`` for the
    first field of ``obj`` outside its range (metadata of :func:`num_field`, :func:`int_field`,
    :func:`switch_field`)."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        if f.metadata.get("switch"):
            if not isinstance(v, bool):
                raise ConfigError(f"detect {section}.{f.name} must be true or false, got {v!r}")
            continue
        rng: Range = f.metadata["range"]
        if not rng.holds(v):
            raise ConfigError(f"detect {section}.{f.name} must be {rng.text()}, got {v!r}")


def check_order(obj: Any, section: str, low: str, high: str) -> None:
    """One-line :class:`ConfigError` unless ``obj.low <= obj.high``."""
    if not getattr(obj, low) <= getattr(obj, high):
        raise ConfigError(f"detect {section}.{low} must not exceed {section}.{high}")
