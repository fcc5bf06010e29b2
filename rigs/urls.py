"""Device URLs: ``scheme://target?key=value&...``, as pyserial's ``serial_for_url`` does.

IMU: ``serial:///dev/ttyUSB0?baud=921600&protocol=binary``, ``loop://``, ``sim://imu?rate=1000``.
Camera: ``v4l2://0``, ``opencv://0``, ``file:///path/video.mp4``, ``sim://camera?fps=30``.
Options are checked: an unknown key or a malformed value is a :class:`DeviceUrlError`, never
silently ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl, unquote, urlsplit

from rigs.errors import DeviceUrlError


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
