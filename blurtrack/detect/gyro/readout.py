"""Which way the sensor reads its rows, decided by the frames (issue 45: never a convention on
trust where the data can decide it).

A rolling shutter exposes row ``y`` at ``t + readout * y / H``: the top row first. A sensor
mounted upside down, or frames stored turned by 180 degrees, read the bottom row first, and
nothing in a session says so; the blur model then predicts every streak at the wrong instant
by up to the readout (25-30 ms on the simulator's rigs), and the gyro's help turns into
confident errors (``dense`` seed 3 with its frames turned: ok-coverage 99.8 -> 20 %;
``hard`` seed 3: ok-precision 99.9 -> 94 %). The frames decide: the time-shift scan
(:func:`blurtrack.detect.gyro.timeshift.estimate_timeshift`, the orientation-free end mismatch of up
to 180 long streaks over +-50 ms) is run a second time on the session turned by 180 degrees,
where the bottom row is read first: every streak's coordinates ``(W - 1 - x, H - 1 - y)``, the
calibration turned with them (:func:`turned_calibration`). Each scan's least cost is a sum of
squared, normalised end mismatches (a chi-square up to its per-streak cap), so half the
difference of the two is a log-likelihood ratio of the two readout orders, each at its own
best shift. A rolling shutter's order shows wherever streaks spread over the rows and the
motion changes within a readout; a global shutter (readout 0) has none, and is not checked.
Where the bottom row is read first, :func:`blurtrack.detect.session.pipeline.detect_session` detects
again in the frames turned by 180 degrees (:class:`TurnedSession`), where the top row is read
first, and turns the table back (:func:`turned_table`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.timeshift import TimeshiftEstimate, estimate_timeshift
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import DetectionError
from blurtrack.geometry.camera import TURN_180, turned_camera

#: The statuses of :class:`ReadoutOrder` (``global``: no readout, nothing to decide).
STATUSES = ("top_first", "bottom_first", "undetermined", "global")


def turned_calibration(calib: Any) -> Any:
    """``calib`` (:class:`~blurtrack.geometry.calibration.Calibration`) for its frames turned
    by 180 degrees about the optical axis: the camera turned
    (:func:`~blurtrack.geometry.camera.turned_camera`), ``R_cam_imu`` and the lever arm
    pre-multiplied by :data:`~blurtrack.geometry.camera.TURN_180`; time offset and gyro terms
    unchanged. Turned twice it is ``calib`` again."""
    return replace(
        calib,
        camera=turned_camera(calib.camera),
        R_cam_imu=TURN_180 @ np.asarray(calib.R_cam_imu),
        t_cam_imu_m=TURN_180 @ np.asarray(calib.t_cam_imu_m),
    )


def turned_frame(fs: FrameStreaks, lines: bool = True) -> FrameStreaks:
    """``fs`` turned by 180 degrees: its ends, time midpoints and (``lines``) centre lines at
    ``(W - 1 - x, H - 1 - y)`` (lengths, profiles along the lines and flags do not change;
    without ``lines`` the centre lines are left as they are, for what reads only the ends,
    like the time-shift scan). Turned twice it is ``fs`` again."""
    if len(fs) == 0:
        return fs
    h, w = fs.shape
    at = np.array([w - 1.0, h - 1.0])
    return replace(
        fs,
        end_a=at - fs.end_a,
        end_b=at - fs.end_b,
        time_mid=at - fs.time_mid,
        points=[at - p for p in fs.points] if lines else fs.points,
    )


#: The streak table's point columns (x, y), turned back by :func:`turned_table`.
POINT_COLUMNS = (("start_x", "start_y"), ("end_x", "end_y"), ("mid_x", "mid_y"))


def turned_table(table: pd.DataFrame, resolution: tuple[int, int]) -> pd.DataFrame:
    """A streak table (:mod:`blurtrack.detect.session.table`) of frames turned by 180 degrees, in
    the frames' own pixels (``resolution``: ``(W, H)``): the points of :data:`POINT_COLUMNS`
    and of every ``centerline`` at ``(W - 1 - x, H - 1 - y)``; every other column as it is."""
    w, h = resolution
    out = table.copy()
    for x, y in POINT_COLUMNS:
        if x in out.columns:
            out[x] = (w - 1.0) - out[x].to_numpy(float)
            out[y] = (h - 1.0) - out[y].to_numpy(float)
    if "centerline" in out.columns:
        at = np.array([w - 1.0, h - 1.0])
        cells = np.empty(len(out), object)
        for i, c in enumerate(out["centerline"].to_numpy()):
            cells[i] = at - np.asarray(c, float).reshape(-1, 2)
        out["centerline"] = cells
    return out


class TurnedSession:
    """A loaded session (:class:`blurtrack.io.session.Session`) seen with its frames turned by
    180 degrees, so that a sensor that reads the bottom row first reads its top row first:
    every image turned, the initial calibration with it (:func:`turned_calibration`);
    everything else (times, gyro, metadata) the session's own."""

    def __init__(self, session: Any) -> None:
        self._session = session

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)

    def read_image(self, i: int) -> np.ndarray:
        """Frame ``i`` turned by 180 degrees (gray or colour)."""
        return np.ascontiguousarray(self._session.read_image(i)[::-1, ::-1])

    def initial_calibration(self) -> Any:
        """The session's initial calibration, turned."""
        return turned_calibration(self._session.initial_calibration())


@dataclass(frozen=True)
class ReadoutOrder:
    """The check's outcome: ``status`` (:data:`STATUSES`: ``top_first``, the session's order,
    ``bottom_first``, ``undetermined``, ``global``), the two scans' least costs
    (``cost_top_first``, ``cost_bottom_first``; NaN where a scan had too few streaks) and their
    log-likelihood ratio for the top row first (``llr``), and the streaks they used."""

    status: str
    cost_top_first: float = float("nan")
    cost_bottom_first: float = float("nan")
    n_streaks: int = 0

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise DetectionError(
                f"readout order status must be one of {STATUSES}, got {self.status!r}"
            )

    @property
    def llr(self) -> float:
        """Half the difference of the least costs (positive: the top row first)."""
        return 0.5 * (self.cost_bottom_first - self.cost_top_first)

    @property
    def usable(self) -> bool:
        """May the frames be used as stored with the session's calibration?"""
        return self.status != "bottom_first"

    def message(self) -> str:
        """One line for the user where the frames read the bottom row first."""
        return (
            "the frames' streaks fit rows read bottom to top, not the session's top first "
            f"(the gyro's end mismatch {self.cost_bottom_first:.0f} against "
            f"{self.cost_top_first:.0f} over {self.n_streaks} streaks): the sensor is mounted "
            "upside down or the frames are stored turned by 180 degrees; detection turned "
            "them (the table is in the frames' own pixels), but blurtrack calibrate reads "
            "the top row first and refuses this table: import the recording again with "
            "--turn-180"
        )

    def as_dict(self) -> dict[str, Any]:
        """For the summary (the user's line where the order is not the session's)."""
        out: dict[str, Any] = {
            "status": self.status,
            "cost_top_first": _finite_or_none(self.cost_top_first),
            "cost_bottom_first": _finite_or_none(self.cost_bottom_first),
            "llr_top_first": _finite_or_none(self.llr),
            "n_streaks": self.n_streaks,
        }
        if not self.usable:
            out["message"] = self.message()
        return out


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _least(est: TimeshiftEstimate | None) -> float:
    """A scan's least cost over its grid (NaN: no scan). A flat scan counts too: an order
    under which no shift fits says so by its cost."""
    if est is None:
        return float("nan")
    finite = est.cost[np.isfinite(est.cost)]
    return float(np.min(finite)) if finite.size else float("nan")


def readout_order(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    calib: Any,
    trace: Any,
    session_scan: TimeshiftEstimate | None,
    model_gyro: Any = None,
    params: DetectParams | None = None,
) -> ReadoutOrder:
    """Decide the rows' readout order (module text) from the first-pass frames ``found``, the
    session's ``calib`` and gyro ``trace`` (``model_gyro``: resampled as the blur model does)
    and the time-shift scan already run in the session's order (``session_scan``). The
    frames read bottom first where that order's scan is the better by a log-likelihood ratio
    of ``timeshift.readout_order_llr`` (top first likewise); else ``undetermined``, and the
    session's order stands."""
    dp = params or DetectParams()
    if float(calib.camera.readout_s) <= 0.0:
        return ReadoutOrder("global")
    top = _least(session_scan)
    n = 0 if session_scan is None else session_scan.n_streaks
    if not np.isfinite(top):
        return ReadoutOrder("undetermined", top, float("nan"), n)
    turned = estimate_timeshift(
        [turned_frame(fs, lines=False) for fs in found],
        timings,
        turned_calibration(calib),
        trace,
        model_gyro=model_gyro,
        params=dp,
    )
    bottom = _least(turned)
    out = ReadoutOrder("undetermined", top, bottom, n)
    if not np.isfinite(bottom):
        return out
    lo = dp.timeshift.readout_order_llr
    if out.llr >= lo:
        return replace(out, status="top_first")
    if out.llr <= -lo:
        return replace(out, status="bottom_first")
    return out
