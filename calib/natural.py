"""Natural-scene calibration: feature tracks between frames as the calibration's residual.

A feature tracked from pixel ``p`` of frame ``a`` to ``p'`` of frame ``b = a + 1``
(:mod:`blurtrack.features.tracks`) was seen at ``t_a + readout · p_y / H + exposure_a / 2``
and ``t_b + readout · p'_y / H + exposure_b / 2`` (its rows' exposure midpoints). The
pure-rotation model must carry ``p`` between those times onto ``p'``: the inter-frame track
residual of :mod:`calib.tracks`, written as a pseudo-streak (``start = p``, ``end = p'``,
``frame_t = t_a + exposure_a / 2``, ``exposure = t_b + exposure_b / 2 − frame_t``, rows
``(p_y, p'_y)``), so :func:`calib.fit.calibrate` fits it unchanged: the same shift/focal
search, exact CasADi Jacobian, robust LM with outlier rejection, cluster-robust σ and frame
hold-out as laser tracks.

Before the fit, :func:`discover_axes` decides the camera–IMU axis mapping from the same tracks
(:mod:`calib.axes`) and the fit starts from the winner and its time shift.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from blurtrack.features.tracks import FeatureTracks, TrackParams, track_frames
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.calibration import Calibration
from calib.axes import AxisSearch, ImageRotations, check_axes, rotations_from_pairs, search_axes
from calib.data import StreakSet, relative_gyro
from calib.errors import CalibError
from calib.fit import FitOptions, calibrate
from calib.result import CalibResult

#: Fewest feature tracks and frame pairs a natural calibration starts from.
MIN_TRACKS = 60
MIN_FRAMES = 4
#: Most tracks the continuous fit uses (spread evenly over the frame pairs; the axis search
#: uses all): beyond a few thousand the estimate is limited by the gyro, not the tracks.
MAX_FIT_TRACKS = 4000
#: Cells (columns, rows) over which :func:`thinned` spreads each pair's tracks.
THIN_GRID = (4, 3)
#: Time samples of the blur-centroid correction.
CENTROID_SAMPLES = 8


def tracks_to_streaks(
    tracks: FeatureTracks, frame_t_ns: np.ndarray, exposure_ns: np.ndarray
) -> StreakSet:
    """Feature tracks as pseudo-streaks (see the module docstring); times relative to the
    first frame's timestamp."""
    ts = np.asarray(frame_t_ns, np.int64)
    t0 = int(ts[0])
    t = (ts - t0) * 1e-9
    e = np.asarray(exposure_ns, np.int64) * 1e-9
    a, b = tracks.frame_a, tracks.frame_b
    ft = t[a] + e[a] / 2
    return StreakSet(
        start=tracks.pts_a,
        end=tracks.pts_b,
        frame_t_s=ft,
        exposure_s=t[b] + e[b] / 2 - ft,
        frame=a,
        streak_id=np.arange(len(tracks)),
        t0_s=t0 * 1e-9,
        time_row=np.stack([tracks.pts_a[:, 1], tracks.pts_b[:, 1]], axis=1),
    )


def centroid_offsets(
    pts: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    calib: Calibration,
    gyro: GyroTrace,
    n: int = CENTROID_SAMPLES,
) -> np.ndarray:
    """``(N, 2)`` where a blurred feature's light is centred minus where the scene point was
    at mid-exposure, predicted by ``calib`` and the gyro.

    A tracked feature sits at the time average of its point's image over the exposure, not at
    the mid-exposure position: for shake at frequency ``F`` the average is low-passed by about
    ``(2π F · exposure)² / 24`` of the motion (1.6 % at 5 Hz, 20 ms), enough to bias the focal
    lengths by as much. Subtracting this prediction (a second-order term: a calibration a few
    percent off changes it by a few percent) removes the bias. ``frame_t_s``, ``exposure_s``:
    ``(N,)`` absolute camera times of each point's frame.
    """
    from blurtrack.geometry.blur_model import BlurModel

    model = BlurModel(calib, gyro, check_coverage=False)
    H = calib.camera.height
    tm = frame_t_s + calib.camera.readout_s * pts[:, 1] / H + exposure_s / 2
    acc = np.zeros_like(pts)
    for k in range(n):
        acc += model.warp(pts, tm, tm + exposure_s * ((k + 0.5) / n - 0.5))
    return acc / n - pts


def corrected_tracks(
    tracks: FeatureTracks,
    frame_t_ns: np.ndarray,
    exposure_ns: np.ndarray,
    calib: Calibration,
    gyro: GyroTrace,
) -> FeatureTracks:
    """The tracks with each point's :func:`centroid_offsets` removed."""
    t = np.asarray(frame_t_ns, np.int64) * 1e-9
    e = np.asarray(exposure_ns, np.int64) * 1e-9
    a, b = tracks.frame_a, tracks.frame_b
    return replace(
        tracks,
        pts_a=tracks.pts_a - centroid_offsets(tracks.pts_a, t[a], e[a], calib, gyro),
        pts_b=tracks.pts_b - centroid_offsets(tracks.pts_b, t[b], e[b], calib, gyro),
    )


def thinned(tracks: FeatureTracks, n_max: int, grid: tuple[int, int] = THIN_GRID) -> FeatureTracks:
    """At most about ``n_max`` tracks, the same share kept from every frame pair, spread over
    the image: a pair's tracks are taken round-robin from the cells of a ``grid`` (columns,
    rows) laid over its points' extent, strongest first within a cell (``goodFeaturesToTrack``
    ranks them). Taking the strongest corners alone kept 13 per pair of a 300-frame 720p
    video, bunched where the texture is strongest, and left cy 15 px off."""
    if len(tracks) <= n_max:
        return tracks
    per = max(1, n_max // max(1, int(np.count_nonzero(tracks.per_pair))))
    gx, gy = grid
    p = tracks.pts_a
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    cx = np.minimum((gx * (p[:, 0] - lo[0]) / span[0]).astype(np.int64), gx - 1)
    cy = np.minimum((gy * (p[:, 1] - lo[1]) / span[1]).astype(np.int64), gy - 1)
    cell = cy * gx + cx
    keep = np.zeros(len(tracks), bool)
    for f in np.unique(tracks.frame_a):
        sel = np.flatnonzero(tracks.frame_a == f)
        rank = np.zeros(sel.size, np.int64)
        for c in np.unique(cell[sel]):
            m = cell[sel] == c
            rank[m] = np.arange(np.count_nonzero(m))
        order = np.lexsort((cell[sel], rank))  # rank-major: one per cell, then the next
        keep[sel[order[:per]]] = True
    return replace(
        tracks,
        frame_a=tracks.frame_a[keep],
        frame_b=tracks.frame_b[keep],
        pts_a=tracks.pts_a[keep],
        pts_b=tracks.pts_b[keep],
        fb_error_px=tracks.fb_error_px[keep],
        per_pair=np.minimum(tracks.per_pair, per),
    )


def check_tracks(tracks: FeatureTracks) -> None:
    """Refuse frames that do not support a calibration (one line naming what is missing)."""
    if tracks.n_frames < MIN_FRAMES:
        raise CalibError(
            f"too few frames for a natural-scene calibration: {tracks.n_frames} (need {MIN_FRAMES})"
        )
    good = int(np.count_nonzero(tracks.per_pair >= 8))
    if len(tracks) < MIN_TRACKS or good < MIN_FRAMES - 1:
        raise CalibError(
            f"too few feature tracks: {len(tracks)} in {good} of {tracks.n_frames - 1} frame "
            f"pairs (need {MIN_TRACKS} in {MIN_FRAMES - 1}): the frames are textureless, too "
            f"blurred, or do not overlap"
        )


def image_rotations(
    tracks: FeatureTracks, frame_t_ns: np.ndarray, exposure_ns: np.ndarray, initial: Calibration
) -> ImageRotations:
    """Per-frame-pair rotations measured by the tracks (times relative to the first frame)."""
    ts = np.asarray(frame_t_ns, np.int64)
    return rotations_from_pairs(
        tracks.pts_a,
        tracks.pts_b,
        tracks.frame_a,
        (ts - ts[0]) * 1e-9,
        np.asarray(exposure_ns, np.int64) * 1e-9,
        initial.camera,
    )


def discover_axes(
    rots: ImageRotations,
    gyro: GyroTrace,
    t0_s: float,
    initial: Calibration,
    window_s: float,
    source: str,
) -> tuple[AxisSearch, Calibration]:
    """Axis search (refusing an undecided one) and the initial calibration it implies (the
    winner's axes and time shift)."""
    g = relative_gyro(gyro, t0_s)
    search = search_axes(
        rots, g, initial.camera.intrinsics[0], initial.timeshift_cam_imu_s, window_s, source
    )
    check_axes(search)
    start = initial.with_(R_cam_imu=search.R_cam_imu, timeshift_cam_imu_s=search.winner.timeshift_s)
    return search, start


@dataclass(frozen=True)
class NaturalResult:
    """A natural-scene calibration: the fit, the axis search and the tracks behind them."""

    result: CalibResult
    axes: AxisSearch
    tracks: FeatureTracks
    streaks: StreakSet
    #: The translation model used and why (:mod:`calib.natural_motion`).
    translation: dict[str, Any] | None = None
    #: The rotation-only fit, when the per-pair translation fit replaced it.
    rotation_only: CalibResult | None = None

    def summary(self) -> dict[str, Any]:
        d = self.tracks.displacement_px
        return {
            "translation": self.translation,
            "axes": self.axes.to_dict(),
            "features": {
                "tracks": len(self.tracks),
                "frames": self.tracks.n_frames,
                "per_pair_median": float(np.median(self.tracks.per_pair)),
                "displacement_px_median": float(np.median(d)) if d.size else 0.0,
            },
        }


def calibrate_natural(
    session: Any,
    options: FitOptions,
    params: TrackParams | None = None,
    progress: Callable[[int, int], None] | None = None,
    translation: str = "none",
) -> NaturalResult:
    """Track, decide the axes, and fit a natural-scene session (a loaded ``Session``).

    ``translation``: ``none`` (pure rotation), ``per-pair`` (an epipole per frame pair as a
    nuisance, :mod:`calib.natural_motion`) or ``auto`` (per-pair when the rotation-only
    fit leaves parallax, :func:`calib.natural_motion.prefers_translation`).
    """
    from calib.natural_motion import TRANSLATIONS

    if translation not in TRANSLATIONS:
        raise CalibError(f"translation must be one of {TRANSLATIONS}, got {translation!r}")
    frames = session.frames
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    exp = frames["exposure_ns"].to_numpy(np.int64)
    if ts.size < MIN_FRAMES:
        raise CalibError(
            f"too few frames for a natural-scene calibration: {ts.size} (need {MIN_FRAMES})"
        )
    tracks = track_frames(session.read_image, ts.size, params or TrackParams(), progress)
    check_tracks(tracks)
    initial = session.initial_calibration()
    streaks = tracks_to_streaks(tracks, ts, exp)
    rots = image_rotations(tracks, ts, exp, initial)
    gyro = session.gyro()
    search, start = discover_axes(
        rots, gyro, streaks.t0_s, initial, options.shift_window_s, "feature tracks"
    )
    tracks = corrected_tracks(thinned(tracks, MAX_FIT_TRACKS), ts, exp, start, gyro)
    streaks = tracks_to_streaks(tracks, ts, exp)
    if options.residuals not in ("auto", "endpoints"):
        raise CalibError("natural-scene sessions fit feature tracks; --residuals does not apply")
    # The tracks are the pseudo-streaks' "endpoints"; narrow the fit's own shift search to
    # the axis search's neighbourhood.
    opts = FitOptions(
        fit=options.fit,
        holdout_fraction=options.holdout_fraction,
        shift_window_s=min(options.shift_window_s, 0.02),
        max_iter=options.max_iter,
        seed=options.seed,
        residuals="endpoints",
    )
    res = calibrate(streaks, gyro, start, opts)
    if translation == "none":
        return NaturalResult(res, search, tracks, streaks, {"mode": "none", "chosen_by": "option"})
    from calib.natural_motion import with_translation

    return with_translation(NaturalResult(res, search, tracks, streaks), gyro, opts, translation)
