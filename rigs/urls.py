"""Device URLs: ``scheme://target?key=value&...``, as pyserial's ``serial_for_url`` does.

IMU: ``serial:///dev/ttyUSB0?baud=921600&protocol=binary``, ``loop://``, ``sim://imu?rate=1000``.
Camera: ``v4l2://0``, ``opencv://0``, ``file:///path/video.mp4``, ``sim://camera?fps=30``.
Options are checked: an unknown key or a malformed value is a :class:`DeviceUrlError`, never
silently ignored.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar
from urllib.parse import parse_qsl, unquote, urlsplit

from rigs.errors import DeviceUrlError

T = TypeVar("T")


@dataclass(frozen=True)
class DeviceUrl:
    """A parsed device URL; ``target`` is the host part plus the path (``/dev/ttyUSB0``, ``0``,
    ``imu``)."""

    url: str
    scheme: str
    target: str
    params: dict[str, str] = field(default_factory=dict)

    def check_keys(self, allowed: set[str]) -> None:
        unknown = sorted(set(self.params) - allowed)
        if unknown:
            raise DeviceUrlError(
                f"{self.url}: unknown option(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(sorted(allowed))}"
            )

    def get_str(self, key: str, default: str, choices: tuple[str, ...] | None = None) -> str:
        value = self.params.get(key, default)
        if choices is not None and value not in choices:
            raise DeviceUrlError(f"{self.url}: {key}={value!r} is not one of {choices}")
        return value

    def get_float(self, key: str, default: float, lo: float, hi: float) -> float:
        raw = self.params.get(key)
        if raw is None:
            return default
        try:
            value = float(raw)
        except ValueError:
            raise DeviceUrlError(f"{self.url}: {key}={raw!r} is not a number") from None
        if not lo <= value <= hi:
            raise DeviceUrlError(f"{self.url}: {key}={value} is outside [{lo}, {hi}]")
        return value

    def get_opt_float(self, key: str, lo: float, hi: float) -> float | None:
        return None if key not in self.params else self.get_float(key, 0.0, lo, hi)

    def get_int(self, key: str, default: int, lo: int, hi: int) -> int:
        raw = self.params.get(key)
        if raw is None:
            return default
        try:
            value = int(raw)
        except ValueError:
            raise DeviceUrlError(f"{self.url}: {key}={raw!r} is not an integer") from None
        if not lo <= value <= hi:
            raise DeviceUrlError(f"{self.url}: {key}={value} is outside [{lo}, {hi}]")
        return value


def parse_device_url(url: str) -> DeviceUrl:
    """Split a device URL.

    >>> u = parse_device_url("serial:///dev/ttyUSB0?baud=921600")
    >>> u.scheme, u.target, u.params
    ('serial', '/dev/ttyUSB0', {'baud': '921600'})
    >>> parse_device_url("sim://imu?rate=500").target
    'imu'
    """
    if "://" not in url:
        raise DeviceUrlError(f"{url!r} is not a device URL (expected scheme://...)")
    parts = urlsplit(url)
    if not parts.scheme:
        raise DeviceUrlError(f"{url!r} has no scheme")
    try:
        pairs = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise DeviceUrlError(f"{url!r} has a malformed query string") from None
    params: dict[str, str] = {}
    for key, value in pairs:
        if key in params:
            raise DeviceUrlError(f"{url!r} repeats option {key!r}")
        params[key] = value
    target = unquote(parts.netloc + parts.path)
    return DeviceUrl(url=url, scheme=parts.scheme.lower(), target=target, params=params)


class SchemeRegistry(Generic[T]):
    """Openers of one kind of device keyed by URL scheme, as pyserial's ``serial_for_url``.

    A driver module registers its opener for its schemes; ``open(url, ...)`` parses the URL,
    dispatches on its scheme and names the known schemes when it is unknown. Real and virtual
    devices register the same way, so nothing that opens a device knows which it got.

    >>> reg: SchemeRegistry[str] = SchemeRegistry("widget")
    >>> @reg.register("a", "b")
    ... def _open(u: DeviceUrl) -> str:
    ...     return u.target
    >>> reg.open("b://x")
    'x'
    >>> reg.open("c://x")
    Traceback (most recent call last):
    ...
    rigs.errors.DeviceUrlError: c://x: unknown widget scheme 'c' (known: a, b)
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._openers: dict[str, Callable[..., T]] = {}

    def register(self, *schemes: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
        def add(opener: Callable[..., T]) -> Callable[..., T]:
            for scheme in schemes:
                if scheme in self._openers:
                    raise ValueError(f"{self.kind} scheme {scheme!r} registered twice")
                self._openers[scheme] = opener
            return opener

        return add

    @property
    def schemes(self) -> tuple[str, ...]:
        return tuple(sorted(self._openers))

    def open(self, url: str, *args: object, **kwargs: object) -> T:
        u = parse_device_url(url)
        opener = self._openers.get(u.scheme)
        if opener is None:
            raise DeviceUrlError(
                f"{url}: unknown {self.kind} scheme {u.scheme!r} (known: {', '.join(self.schemes)})"
            )
        return opener(u, *args, **kwargs)
