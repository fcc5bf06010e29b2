"""Gyro sources for synthesis: where the camera shake of each triplet comes from.

Three kinds, each picking a segment by a seeded generator so the choice is reproducible and
recorded in the manifest:

* ``session`` — a recorded session folder (its ``imu0``). The calibration belongs to this IMU,
  so its time shift and gyro bias apply (``own_imu``).
* ``shake`` — a plain shake file (GyroDeblurNet's ``timestamp_ns wx wy wz``), read by
  :mod:`blurtrack.io.shake` (manifest times count from the file's first sample). The trace is
  another device's, so the calibration's time shift and bias are not applied (they describe
  the calibrated IMU, not this one); its axes are taken as the IMU axes and rotated by the
  calibration's ``R_cam_imu``.
* ``synthetic`` — smooth random motion: per axis a sum of sinusoids at hand-tremor frequencies
  (1–12 Hz) scaled to a chosen RMS angular rate, the roll axis at half amplitude.

Segments that would touch a gyro gap are redrawn (up to ``MAX_DRAWS`` times).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import BlurTrackError, CoverageError, SynthesisError
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.shake import read_shake_trace

#: Redraws of a segment that hits a gap before giving up.
MAX_DRAWS = 200
#: Sample rate of synthetic motion (Hz).
SYNTH_RATE_HZ = 1000.0


@dataclass(frozen=True)
class Segment:
    """A gyro trace (IMU clock, s), the frame start on the camera clock (s) and what the
    manifest records about it."""

    trace: GyroTrace
    frame_t_s: float
    info: dict[str, Any] = field(default_factory=dict)


class GyroSource:
    """Base class: ``segment(rng, span_s, margin_s, timeshift_s)``."""

    kind = "base"
    own_imu = False
    spec = ""

    def segment(
        self, rng: np.random.Generator, span_s: float, margin_s: float, timeshift_s: float = 0.0
    ) -> Segment:
        raise NotImplementedError

    @property
    def tag(self) -> str:
        """Short name for dataset folders."""
        return self.kind

    def fingerprint(self) -> str:
        """What identifies the motion this source yields, independent of where it was read."""
        return self.spec


class TraceSource(GyroSource):
    """Segments of one recorded trace (a session's IMU or a shake file)."""

    def __init__(
        self, trace: GyroTrace, kind: str, spec: str, own_imu: bool, t0_ns: int = 0
    ) -> None:
        self.trace = trace
        self.kind = kind
        self.spec = spec
        self.own_imu = own_imu
        self.t0_ns = t0_ns

    def fingerprint(self) -> str:
        """SHA-256 of the samples read (and how they are used), not of the file's path."""
        h = hashlib.sha256(f"{self.kind}|{self.own_imu}|{self.t0_ns}|".encode())
        h.update(np.ascontiguousarray(self.trace.t_s, dtype="<f8").tobytes())
        h.update(np.ascontiguousarray(self.trace.omega_radps, dtype="<f8").tobytes())
        return f"{self.kind}:{h.hexdigest()}"

    def segment(
        self, rng: np.random.Generator, span_s: float, margin_s: float, timeshift_s: float = 0.0
    ) -> Segment:
        """A frame start ``t`` (camera clock) whose IMU window ``[t + shift - margin,
        t + shift + span + margin]`` the trace covers without gaps."""
        shift = timeshift_s if self.own_imu else 0.0
        lo = self.trace.t_s[0] + margin_s - shift
        hi = self.trace.t_s[-1] - margin_s - span_s - shift
        if hi <= lo:
            raise SynthesisError(
                f"gyro source {self.spec} is shorter than one segment "
                f"({span_s + 2 * margin_s:.3f} s)"
            )
        for _ in range(MAX_DRAWS):
            t = float(rng.uniform(lo, hi))
            a, b = t + shift - margin_s, t + shift + span_s + margin_s
            if self.trace.covers(a, b):
                seg = self.trace.segment(a, b)
                info = {
                    "source": self.kind,
                    "spec": self.spec,
                    "frame_t_ns": round(t * 1e9) + self.t0_ns,
                    "imu_window_ns": [round(a * 1e9) + self.t0_ns, round(b * 1e9) + self.t0_ns],
                }
                return Segment(seg, t, info)
        raise SynthesisError(
            f"gyro source {self.spec}: no gap-free segment of "
            f"{span_s + 2 * margin_s:.3f} s found in {MAX_DRAWS} draws"
        )


class SyntheticSource(GyroSource):
    """Smooth random shake with RMS angular rate ``rms_radps`` per axis (roll halved)."""

    kind = "synthetic"

    def __init__(self, rms_radps: float = 0.7, n_tones: int = 6) -> None:
        if not (math.isfinite(rms_radps) and rms_radps >= 0):
            raise SynthesisError(f"synthetic rms must be >= 0 rad/s, got {rms_radps}")
        self.rms_radps = float(rms_radps)
        self.n_tones = int(n_tones)
        self.spec = f"synthetic:{self.rms_radps:g}"

    def segment(
        self, rng: np.random.Generator, span_s: float, margin_s: float, timeshift_s: float = 0.0
    ) -> Segment:
        t = np.arange(0.0, span_s + 2 * margin_s + 2 / SYNTH_RATE_HZ, 1 / SYNTH_RATE_HZ)
        freq = rng.uniform(1.0, 12.0, (3, self.n_tones))
        phase = rng.uniform(0, 2 * np.pi, (3, self.n_tones))
        amp = rng.rayleigh(1.0, (3, self.n_tones))
        # Sum of tones with random phases: RMS = sqrt(sum amp^2 / 2) per axis.
        amp *= self.rms_radps / np.sqrt(np.sum(amp**2, axis=1, keepdims=True) / 2)
        amp[2] *= 0.5
        w = np.einsum(
            "ak,akt->ta",
            amp,
            np.sin(2 * np.pi * freq[:, :, None] * t[None, None, :] + phase[:, :, None]),
        )
        info = {
            "source": self.kind,
            "spec": self.spec,
            "tones_hz": np.round(freq, 4).tolist(),
            "frame_t_ns": round(margin_s * 1e9),
        }
        return Segment(GyroTrace(t, w), margin_s, info)


def open_source(spec: str) -> GyroSource:
    """A gyro source from a command-line spec: ``synthetic[:RMS]``, a session folder, a shake
    file, or a folder holding one ``*.txt`` shake file (e.g. ``real/gyrodeblurnet-shake``)."""
    if spec == "synthetic" or spec.startswith("synthetic:"):
        try:
            rms = float(spec.split(":", 1)[1]) if ":" in spec else 0.7
        except ValueError:
            raise SynthesisError(
                f"bad synthetic gyro spec {spec!r} (synthetic:RMS_RADPS)"
            ) from None
        return SyntheticSource(rms)
    p = Path(spec)
    try:
        if (p / "session.yaml").is_file():
            from blurtrack.io.session import load_session

            s = load_session(p)
            if s.imu_t_ns.size < 2:
                raise SynthesisError(f"session {p} has no gyro samples")
            return TraceSource(
                GyroTrace(s.imu_times_s - s.imu_times_s[0], s.omega_radps),
                "session",
                str(p),
                own_imu=True,
                t0_ns=int(s.imu_t_ns[0]),
            )
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.suffix == ".txt" and f.is_file())
            if len(files) != 1:
                raise SynthesisError(
                    f"gyro folder {p} must be a session or hold exactly one "
                    f".txt shake file, found {len(files)}"
                )
            p = files[0]
        return TraceSource(read_shake_trace(p), "shake", str(p), own_imu=False)
    except SynthesisError:
        raise
    except (BlurTrackError, CoverageError) as exc:
        raise SynthesisError(f"gyro source {spec}: {exc}") from None
