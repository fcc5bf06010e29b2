"""The BlurTrack IMU wire protocols: a binary framed one and an ASCII line one.

Binary frame (all integers little-endian; documented with examples in docs/recording.md)::

    offset size field
    0      2    sync          0xA5 0x5A
    2      1    length        bytes from `type` to the end of the payload: 19 or 31
    3      1    type          0x01 gyro only, 0x02 gyro + accel
    4      2    counter       uint16 sample counter, +1 per sample, wraps at 65536
    6      4    t_us          uint32 device time of the sample in microseconds, wraps at 2**32
    10     12   gx gy gz      int32 angular rate in micro-rad/s (1e-6 rad/s)
    22     12   ax ay az      int32 acceleration in micro-m/s^2 (type 0x02 only)
    end    2    crc           CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection,
                              no final xor) over bytes 2 .. end of payload (length byte included)

ASCII line: ``t_us,gx,gy,gz[,ax,ay,az]*XX\\n`` with t_us a decimal integer, rates in rad/s and
accelerations in m/s^2 as decimal numbers, and XX the two upper-case hex digits of the XOR of
every byte before ``*`` (the NMEA 0183 checksum). ASCII lines carry no sample counter.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

from rigs.errors import ProtocolError

SYNC = b"\xa5\x5a"
TYPE_GYRO = 0x01
TYPE_GYRO_ACCEL = 0x02
#: payload length (type byte included) per frame type
LENGTH_OF_TYPE = {TYPE_GYRO: 19, TYPE_GYRO_ACCEL: 31}
HEADER_BYTES = 3  # sync + length
CRC_BYTES = 2
MAX_FRAME_BYTES = HEADER_BYTES + max(LENGTH_OF_TYPE.values()) + CRC_BYTES
GYRO_SCALE_RADPS = 1e-6  # one count of a binary gyro value, rad/s
ACCEL_SCALE_MPS2 = 1e-6  # one count of a binary accel value, m/s^2
COUNTER_MODULUS = 1 << 16
TIME_MODULUS_US = 1 << 32
_INT32_MIN, _INT32_MAX = -(1 << 31), (1 << 31) - 1
_BODY = struct.Struct("<BHI3i")
_BODY_ACCEL = struct.Struct("<BHI3i3i")


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF).

    ``binascii.crc_hqx`` is the standard library's implementation of this polynomial.

    >>> hex(crc16(b"123456789"))
    '0x29b1'
    """
    return binascii.crc_hqx(data, 0xFFFF)


def nmea_checksum(data: bytes) -> int:
    """XOR of all bytes, the ASCII line checksum.

    >>> f"{nmea_checksum(b'1000,0.1,0.2,0.3'):02X}"
    '03'
    """
    value = 0
    for byte in data:
        value ^= byte
    return value


@dataclass(frozen=True)
class RawSample:
    """One decoded IMU sample exactly as the device sent it.

    ``counter`` is None for ASCII lines. ``gyro_radps`` and ``accel_mps2`` are in the IMU frame;
    ``accel_mps2`` is None when the device sends gyro only. ``gyro_counts`` holds the binary
    integer values (None for ASCII).
    """

    counter: int | None
    t_us: int
    gyro_radps: tuple[float, float, float]
    accel_mps2: tuple[float, float, float] | None
    gyro_counts: tuple[int, int, int] | None = None


def _check_int32(values: tuple[int, ...], what: str) -> None:
    for v in values:
        if not _INT32_MIN <= v <= _INT32_MAX:
            raise ProtocolError(f"{what} value {v} does not fit in int32")


def encode_binary(
    counter: int,
    t_us: int,
    gyro_counts: tuple[int, int, int],
    accel_counts: tuple[int, int, int] | None = None,
) -> bytes:
    """One binary frame; counter and t_us are reduced modulo their wrap-around.

    >>> frame = encode_binary(1, 1000, (1, -2, 3))
    >>> len(frame), frame[:4].hex()
    (24, 'a55a1301')
    """
    gyro = tuple(int(v) for v in gyro_counts)
    _check_int32(gyro, "gyro")
    if accel_counts is None:
        body = _BODY.pack(TYPE_GYRO, counter % COUNTER_MODULUS, t_us % TIME_MODULUS_US, *gyro)
    else:
        accel = tuple(int(v) for v in accel_counts)
        _check_int32(accel, "accel")
        body = _BODY_ACCEL.pack(
            TYPE_GYRO_ACCEL, counter % COUNTER_MODULUS, t_us % TIME_MODULUS_US, *gyro, *accel
        )
    covered = bytes([len(body)]) + body
    return SYNC + covered + struct.pack("<H", crc16(covered))


def decode_binary_body(body: bytes) -> RawSample:
    """Decode the bytes from ``type`` to the end of the payload (CRC already checked)."""
    kind = body[0]
    if kind == TYPE_GYRO and len(body) == _BODY.size:
        _, counter, t_us, gx, gy, gz = _BODY.unpack(body)
        accel = None
    elif kind == TYPE_GYRO_ACCEL and len(body) == _BODY_ACCEL.size:
        _, counter, t_us, gx, gy, gz, ax, ay, az = _BODY_ACCEL.unpack(body)
        accel = (ax * ACCEL_SCALE_MPS2, ay * ACCEL_SCALE_MPS2, az * ACCEL_SCALE_MPS2)
    else:
        raise ProtocolError(f"frame type 0x{kind:02x} with {len(body)} bytes is not defined")
    gyro = (gx * GYRO_SCALE_RADPS, gy * GYRO_SCALE_RADPS, gz * GYRO_SCALE_RADPS)
    return RawSample(counter, t_us, gyro, accel, (gx, gy, gz))


def encode_ascii(
    t_us: int,
    gyro_radps: tuple[float, float, float],
    accel_mps2: tuple[float, float, float] | None = None,
) -> bytes:
    """One ASCII line (``repr`` of each float, so that decoding gives the same float back).

    >>> encode_ascii(1000, (0.1, 0.2, 0.3))
    b'1000,0.1,0.2,0.3*03\\n'
    """
    values = list(gyro_radps) + ([] if accel_mps2 is None else list(accel_mps2))
    text = ",".join([str(int(t_us) % TIME_MODULUS_US)] + [repr(float(v)) for v in values])
    body = text.encode("ascii")
    return body + f"*{nmea_checksum(body):02X}\n".encode("ascii")


def decode_ascii_line(line: bytes) -> RawSample:
    """Decode one line without its newline; raise ProtocolError on any defect.

    >>> decode_ascii_line(b"1000,0.1,0.2,0.3*03").gyro_radps
    (0.1, 0.2, 0.3)
    """
    line = line.rstrip(b"\r")
    star = line.rfind(b"*")
    if star < 0 or len(line) != star + 3:
        raise ProtocolError("ASCII line without a '*XX' checksum")
    try:
        expected = int(line[star + 1 :], 16)
    except ValueError:
        raise ProtocolError("ASCII checksum is not two hex digits") from None
    body = line[:star]
    if nmea_checksum(body) != expected:
        raise ProtocolError("ASCII checksum mismatch")
    fields = body.split(b",")
    if len(fields) not in (4, 7):
        raise ProtocolError(f"ASCII line has {len(fields)} fields, expected 4 or 7")
    try:
        t_us = int(fields[0])
        values = [float(f) for f in fields[1:]]
    except ValueError:
        raise ProtocolError("ASCII line holds a field that is not a number") from None
    if not 0 <= t_us < TIME_MODULUS_US:
        raise ProtocolError(f"ASCII time {t_us} us is out of range")
    if any(v != v or v in (float("inf"), float("-inf")) for v in values):
        raise ProtocolError("ASCII line holds NaN or infinity")
    gyro = (values[0], values[1], values[2])
    accel = (values[3], values[4], values[5]) if len(values) == 6 else None
    return RawSample(None, t_us, gyro, accel, None)
