"""Incremental decoding of an IMU byte stream, with resynchronisation after garbage.

The decoder is fed whatever bytes the port delivered and returns the samples completed by them.
Binary frames are found by their sync word; a frame whose CRC fails costs one byte (the first
sync byte) and the search restarts right after it, so a corrupted, shortened or lengthened frame
never takes its intact neighbours with it. ASCII lines are split at newlines; a line whose
checksum fails is searched for the longest valid suffix (garbage glued before a good line).

Written by hand because no maintained library decodes this framing; the CRC itself is the
standard library's ``binascii.crc_hqx``.
"""

from __future__ import annotations

import struct
from dataclasses import asdict, dataclass

from rigs.errors import ProtocolError
from rigs.protocol import (
    CRC_BYTES,
    HEADER_BYTES,
    LENGTH_OF_TYPE,
    SYNC,
    RawSample,
    crc16,
    decode_ascii_line,
    decode_binary_body,
)

PROTOCOLS = ("binary", "ascii", "auto")
MAX_ASCII_LINE = 256
_VALID_LENGTHS = frozenset(LENGTH_OF_TYPE.values())
_NUMBER_BYTES = frozenset(bytes([c]) for c in b"0123456789+-.,eE")


@dataclass
class DecoderStats:
    """Counters of one stream: what was decoded, and every kind of damage seen."""

    bytes_in: int = 0
    samples: int = 0
    crc_errors: int = 0  # frames/lines with a plausible header whose checksum failed
    malformed: int = 0  # checksum right but content invalid (unknown type, bad fields)
    skipped_bytes: int = 0  # bytes thrown away while searching for the next frame
    resyncs: int = 0  # runs of skipped bytes

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class _Binary:
    def __init__(self, stats: DecoderStats) -> None:
        self.buf = bytearray()
        self.stats = stats
        self._skipping = False

    def _skip(self, n: int) -> None:
        if n <= 0:
            return
        del self.buf[:n]
        self.stats.skipped_bytes += n
        if not self._skipping:
            self.stats.resyncs += 1
            self._skipping = True

    def feed(self, data: bytes) -> list[RawSample]:
        self.buf += data
        out: list[RawSample] = []
        buf = self.buf
        while True:
            start = buf.find(SYNC)
            if start < 0:
                # keep a trailing first sync byte: its partner may be in the next read
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                self._skip(len(buf) - keep)
                return out
            self._skip(start)
            if len(buf) < HEADER_BYTES:
                return out
            length = buf[2]
            if length not in _VALID_LENGTHS:
                self._skip(1)
                continue
            total = HEADER_BYTES + length + CRC_BYTES
            if len(buf) < total:
                return out
            covered = bytes(buf[2 : HEADER_BYTES + length])
            (crc,) = struct.unpack_from("<H", buf, HEADER_BYTES + length)
            if crc16(covered) != crc:
                self.stats.crc_errors += 1
                self._skip(1)
                continue
            try:
                sample = decode_binary_body(covered[1:])
            except ProtocolError:
                self.stats.malformed += 1
                self._skip(1)
                continue
            del buf[:total]
            self._skipping = False
            self.stats.samples += 1
            out.append(sample)


class _Ascii:
    def __init__(self, stats: DecoderStats) -> None:
        self.buf = bytearray()
        self.stats = stats

    def _decode(self, line: bytes) -> RawSample | None:
        try:
            return decode_ascii_line(line)
        except ProtocolError:
            pass
        # garbage glued before a good line: try every later start (lines are short)
        for i in range(1, len(line)):
            # a good line can only start at a digit that follows a byte no number contains
            if not line[i : i + 1].isdigit() or line[i - 1 : i] in _NUMBER_BYTES:
                continue
            try:
                sample = decode_ascii_line(line[i:])
            except ProtocolError:
                continue
            self.stats.skipped_bytes += i
            self.stats.resyncs += 1
            return sample
        if b"*" in line:
            self.stats.crc_errors += 1
        else:
            self.stats.malformed += 1
        self.stats.skipped_bytes += len(line)
        return None

    def feed(self, data: bytes) -> list[RawSample]:
        self.buf += data
        out: list[RawSample] = []
        while True:
            nl = self.buf.find(b"\n")
            if nl < 0:
                if len(self.buf) > MAX_ASCII_LINE:
                    self.stats.skipped_bytes += len(self.buf)
                    self.stats.resyncs += 1
                    self.buf.clear()
                return out
            line = bytes(self.buf[:nl]).rstrip(b"\r")
            del self.buf[: nl + 1]
            if not line:
                continue
            sample = self._decode(line)
            if sample is not None:
                self.stats.samples += 1
                out.append(sample)


class StreamDecoder:
    """Decode a byte stream in the ``binary``, ``ascii`` or ``auto`` protocol.

    ``auto`` runs both decoders until one of them produces a valid sample, then keeps only
    that one (its statistics restart from the bytes it has seen).

    >>> from rigs.protocol import encode_binary
    >>> d = StreamDecoder("binary")
    >>> stream = b"junk" + encode_binary(7, 100, (1, 2, 3)) + encode_binary(8, 200, (4, 5, 6))
    >>> [s.counter for s in d.feed(stream[:30])], [s.counter for s in d.feed(stream[30:])]
    ([7], [8])
    >>> d.stats.skipped_bytes, d.stats.resyncs
    (4, 1)
    """

    def __init__(self, protocol: str = "binary") -> None:
        if protocol not in PROTOCOLS:
            raise ProtocolError(f"unknown IMU protocol {protocol!r}; expected one of {PROTOCOLS}")
        self.protocol = protocol
        self._candidates: dict[str, _Binary | _Ascii] = {}
        if protocol in ("binary", "auto"):
            self._candidates["binary"] = _Binary(DecoderStats())
        if protocol in ("ascii", "auto"):
            self._candidates["ascii"] = _Ascii(DecoderStats())
        self._bytes_in = 0

    @property
    def locked(self) -> str | None:
        """The protocol in use (None while ``auto`` has not decided yet)."""
        return next(iter(self._candidates)) if len(self._candidates) == 1 else None

    @property
    def stats(self) -> DecoderStats:
        stats = next(iter(self._candidates.values())).stats
        stats.bytes_in = self._bytes_in
        return stats

    def feed(self, data: bytes) -> list[RawSample]:
        self._bytes_in += len(data)
        if len(self._candidates) == 1:
            return next(iter(self._candidates.values())).feed(data)
        for name, dec in list(self._candidates.items()):
            out = dec.feed(data)
            if out:
                self._candidates = {name: dec}
                return out
        return []
