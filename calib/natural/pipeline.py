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

Before the fit, :func:`discover_axes` decides the camera–IMU axis mapping
(:mod:`calib.axes.search`); the fit starts from the winner and fits the gyro scale under a
prior (:mod:`calib.natural.scale`).

Lucas–Kanade between differently blurred frames is pulled along the difference of the blurs:
tracks are refined on equally blurred patches (:mod:`calib.natural.blur`, each end convolved
with the other end's kernel from the same blur model), making them mid-exposure positions; this
is repeated with the fitted calibration's kernels and the fit redone (:data:`EQUAL_BLUR_PASSES`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from blurtrack.features.tracks import FeatureTracks, TrackParams, to_gray8
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from calib.axes.rotations import ImageRotations, collect_rotations, rotations_from_pairs
from calib.axes.search import AxisSearch, check_axes, search_axes
from calib.data import StreakSet, relative_gyro
from calib.errors import AxisSearchError, CalibError
from calib.fit import FitOptions, calibrate
from calib.natural.blur import corrected_tracks, equal_blur_tracks, subset_tracks
from calib.natural.pairs import track_and_rotate
from calib.natural.scale import DEFAULT_SCALE_PRIOR, check_scale_prior, natural_sigma_fit
from calib.result import CalibResult

#: Fewest feature tracks and frame pairs a natural calibration starts from.
MIN_TRACKS = 60
MIN_FRAMES = 4
#: Most tracks the continuous fit uses (spread evenly over the frame pairs; the axis search
#: uses all). 12000 (40 per pair of 10 s of 30 fps video) against 4000: fx/fy within 0.3 %
#: in 10/10 seeds against 8-9/10, the rotation within 0.1 deg in 9 and 8/10 against 6 and 7/10,
#: truth in 3 sigma 97.8 % (docs/journal/natural.md, "MAX_FIT_TRACKS 12000 adopted").
MAX_FIT_TRACKS = 12000
#: Most tracks the translation decision and fits use (thinned from the rotation-only fit's):
#: their per-pair and per-block jackknives refit the travel for every cluster, so their cost
#: grows with the tracks; 1 s of driving 720p (9000 tracks) took 23-38 CPU-s with all of them
#: against 16-20 s with 4000, for the same offsets (docs/journal/natural.md,
#: "MAX_FIT_TRACKS 12000").
MAX_TRANSLATION_TRACKS = 4000
#: Cells (columns, rows) over which :func:`thinned` spreads each pair's tracks.
THIN_GRID = (4, 3)
#: How tracked points are related to mid-exposure positions before the fit: ``equal-blur``
#: (:func:`equal_blur_tracks`) or ``centroid`` (:func:`corrected_tracks`, the blur centroid's
#: predicted offset removed from Lucas–Kanade's points).
BLUR_MODES = ("equal-blur", "centroid")
#: Most bytes of 8-bit gray frames kept in memory between tracking and refinement (10 s of
#: 720p: 276 MB); longer videos are read twice.
FRAME_CACHE_BYTES = 512 * 1024 * 1024
#: Fits of equal-blur tracks: the first with kernels from the axis search's start, each later
#: one with kernels from the previous fit (a second pass moved a 100-frame 720p fit's offset
#: from +0.074 to −0.001 ms and its readout from −0.16 to −0.05 ms).
EQUAL_BLUR_PASSES = 2


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


class _FrameCache:
    """``read_frame`` returning 8-bit gray frames, kept in memory up to
    :data:`FRAME_CACHE_BYTES` in all (the equal-blur refinement reads every frame again)."""

    def __init__(self, read_frame: Callable[[int], np.ndarray], n_frames: int) -> None:
        self.read_frame, self.n_frames = read_frame, n_frames
        self.frames: dict[int, np.ndarray] = {}
        self.keep: bool | None = None

    def __call__(self, i: int) -> np.ndarray:
        if i in self.frames:
            return self.frames[i]
        img = to_gray8(self.read_frame(i))
        if self.keep is None:
            self.keep = img.nbytes * self.n_frames <= FRAME_CACHE_BYTES
        if self.keep:
            self.frames[i] = img
        return img


def thinned(tracks: FeatureTracks, n_max: int, grid: tuple[int, int] = THIN_GRID) -> FeatureTracks:
    """At most about ``n_max`` tracks, the same share kept from every frame pair, spread over
    the image: a pair's tracks are taken round-robin from the cells of a ``grid`` (columns,
    rows) laid over its points' extent, strongest first within a cell (``goodFeaturesToTrack``
    ranks them). Taking the strongest corners alone kept 13 per pair of a 300-frame 720p
    video, bunched where the texture is strongest, and left cy 15 px off."""
    if len(tracks) <= n_max:
        return tracks
    return subset_tracks(tracks, thin_mask(tracks, n_max, grid))


def thin_mask(tracks: FeatureTracks, n_max: int, grid: tuple[int, int] = THIN_GRID) -> np.ndarray:
    """Which tracks :func:`thinned` keeps ``(N,)`` (all where there are at most ``n_max``)."""
    if len(tracks) <= n_max:
        return np.ones(len(tracks), bool)
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
    return keep


def thinned_result(nat: NaturalResult, n_max: int) -> NaturalResult:
    """``nat`` with its tracks and their pseudo-streaks (one per track, in order) thinned to
    about ``n_max`` by :func:`thin_mask`; the fit result itself is kept."""
    keep = thin_mask(nat.tracks, n_max)
    if keep.all():
        return nat
    return replace(nat, tracks=subset_tracks(nat.tracks, keep), streaks=nat.streaks.subset(keep))


def check_tracks(tracks: FeatureTracks, tracked: FeatureTracks | None = None) -> None:
    """Refuse frames that do not support a calibration (one line naming what is missing).

    ``tracked``: the tracks before the equal-blur refinement, when ``tracks`` are what it
    kept (the message then says that the refinement dropped them, not the tracking)."""
    if tracks.n_frames < MIN_FRAMES:
        raise CalibError(
            f"too few frames for a natural-scene calibration: {tracks.n_frames} (need {MIN_FRAMES})"
        )
    good = int(np.count_nonzero(tracks.per_pair >= 8))
    if len(tracks) < MIN_TRACKS or good < MIN_FRAMES - 1:
        if tracked is not None:
            raise CalibError(
                f"too few feature tracks after the equal-blur refinement: {len(tracks)} of the "
                f"{len(tracked)} tracked kept, in {good} of {tracks.n_frames - 1} frame pairs "
                f"(need {MIN_TRACKS} in {MIN_FRAMES - 1}): the frames' blur differs too much "
                f"from what the axis search's start predicts"
            )
        raise CalibError(
            f"too few feature tracks: {len(tracks)} in {good} of {tracks.n_frames - 1} frame "
            f"pairs (need {MIN_TRACKS} in {MIN_FRAMES - 1}): the frames are textureless, too "
            f"blurred, or do not overlap"
        )


def image_rotations(
    tracks: FeatureTracks, frame_t_ns: np.ndarray, exposure_ns: np.ndarray, initial: Calibration
) -> ImageRotations:
    """Per-frame-pair rotations measured by the tracks (times relative to the first frame),
    translation a nuisance where the data need it (:mod:`calib.axes.translation`)."""
    from calib.axes.translation import fit_rotation_translating as fit

    ts, e = np.asarray(frame_t_ns, np.int64), np.asarray(exposure_ns, np.int64) * 1e-9
    t, cam = (ts - ts[0]) * 1e-9, initial.camera
    return rotations_from_pairs(tracks.pts_a, tracks.pts_b, tracks.frame_a, t, e, cam, pair_fit=fit)


def discover_axes(
    rots: ImageRotations,
    gyro: GyroTrace,
    t0_s: float,
    initial: Calibration,
    window_s: float,
    source: str,
    strict: bool = True,
    tracks: FeatureTracks | None = None,
    frame_t_ns: np.ndarray | None = None,
    exposure_ns: np.ndarray | None = None,
) -> tuple[AxisSearch, Calibration]:
    """Axis search (refusing an undecided one unless ``strict`` is off, for diagnostics that
    never write a calibration) and the initial calibration it implies (the winner's axes and
    time shift).

    With ``tracks`` (and their frames' times and exposures), a search the pure-rotation model
    does not decide is made again with the common-heading model (:mod:`calib.axes.heading`,
    a camera travelling along one direction: driving); the decision and both models' figures
    are in the returned search's ``decision``."""
    g = relative_gyro(gyro, t0_s)
    search = search_axes(
        rots, g, initial.camera.intrinsics[0], initial.timeshift_cam_imu_s, window_s, source
    )
    try:
        check_axes(search)
    except AxisSearchError as exc:
        if tracks is None or frame_t_ns is None or exposure_ns is None:
            if strict:
                raise
        else:
            search = _heading_decides(
                search, str(exc), tracks, frame_t_ns, exposure_ns, g, initial, window_s, strict
            )
    start = initial.with_(R_cam_imu=search.R_cam_imu, timeshift_cam_imu_s=search.winner.timeshift_s)
    return search, start


def _heading_decides(
    rotation: AxisSearch,
    refused: str,
    tracks: FeatureTracks,
    frame_t_ns: np.ndarray,
    exposure_ns: np.ndarray,
    gyro: GyroTrace,
    initial: Calibration,
    window_s: float,
    strict: bool,
) -> AxisSearch:
    """The common-heading search where the pure-rotation one (``rotation``, refused with
    ``refused``) did not decide; refuses with both models' figures when it does not decide
    either (unless not ``strict``: then the model whose winner explains more)."""
    from calib.axes.heading import search_axes_heading

    ts = np.asarray(frame_t_ns, np.int64)
    heading = search_axes_heading(
        tracks.pts_a,
        tracks.pts_b,
        tracks.frame_a,
        (ts - ts[0]) * 1e-9,
        np.asarray(exposure_ns, np.int64) * 1e-9,
        initial.camera,
        gyro.upsampled(GYRO_UPSAMPLE),
        initial.timeshift_cam_imu_s,
        window_s,
        rotation.motion_px,
    )
    h = heading.search
    decision = {
        "model": "common heading",
        "rotation_only": {**rotation.to_dict(), "refused": refused},
        "heading": heading.to_dict(),
    }
    try:
        check_axes(h)
    except AxisSearchError as exc:
        if strict:
            raise AxisSearchError(
                f"{refused}; the common-heading model does not decide either: {exc}"
            ) from None
        better = h.winner.score_px < rotation.winner.score_px
        decision["model"] = "common heading (undecided)" if better else "rotation (undecided)"
        return replace(h if better else rotation, decision=decision)
    return replace(h, decision=decision)


@dataclass(frozen=True)
class NaturalResult:
    """A natural-scene calibration: the fit, the axis search and the tracks behind them."""

    result: CalibResult
    axes: AxisSearch
    tracks: FeatureTracks
    streaks: StreakSet
    #: The translation model used and why (:mod:`calib.natural.motion`).
    translation: dict[str, Any] | None = None
    #: The rotation-only fit, when the per-pair translation fit replaced it.
    rotation_only: CalibResult | None = None
    #: The rotation-only fit's gyro scale and sigma model (:mod:`calib.natural.scale`).
    sigma: dict[str, Any] | None = None
    #: Tracks found by tracking, before the fit's thinning and equal-blur refinement
    #: (``tracks`` holds those the fit used); 0 where not known.
    n_tracked: int = 0

    def summary(self) -> dict[str, Any]:
        d = self.tracks.displacement_px
        return {
            "translation": self.translation,
            "sigma_model": self.sigma,
            "axes": self.axes.to_dict(),
            "features": {
                "tracks": len(self.tracks),
                "tracked": self.n_tracked or len(self.tracks),
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
    blur: str = "equal-blur",
    passes: int = EQUAL_BLUR_PASSES,
    strict_axes: bool = True,
    scale_prior: str = DEFAULT_SCALE_PRIOR,
) -> NaturalResult:
    """Track, decide the axes, and fit a natural-scene session (a loaded ``Session``).

    ``translation``: ``none`` (pure rotation), ``per-pair`` (an epipole per frame pair as a
    nuisance, :mod:`calib.natural.motion`) or ``auto`` (per-pair when the rotation-only
    fit leaves parallax, :func:`calib.natural.motion.prefers_translation`). ``strict_axes``
    off: fit from an undecided axis search's winner (diagnostics that write nothing).
    ``scale_prior``: the unfitted gyro scale's treatment (:mod:`calib.natural.scale`).
    """
    from calib.natural.motion import TRANSLATIONS

    if translation not in TRANSLATIONS:
        raise CalibError(f"translation must be one of {TRANSLATIONS}, got {translation!r}")
    if blur not in BLUR_MODES:
        raise CalibError(f"blur must be one of {BLUR_MODES}, got {blur!r}")
    check_scale_prior(scale_prior)
    frames = session.frames
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    exp = frames["exposure_ns"].to_numpy(np.int64)
    if ts.size < MIN_FRAMES:
        raise CalibError(
            f"too few frames for a natural-scene calibration: {ts.size} (need {MIN_FRAMES})"
        )
    read = _FrameCache(session.read_image, ts.size)
    initial, gyro = session.initial_calibration(), session.gyro()
    up = partial(gyro.upsampled, GYRO_UPSAMPLE)  # resampled while the frames are tracked
    tracks, pair_rots = track_and_rotate(
        read, ts, exp, initial, params or TrackParams(), progress, meanwhile=[up]
    )
    check_tracks(tracks)
    n_tracked = len(tracks)
    streaks = tracks_to_streaks(tracks, ts, exp)
    rots = collect_rotations(pair_rots)
    search, start = discover_axes(
        rots,
        gyro,
        streaks.t0_s,
        initial,
        options.shift_window_s,
        "feature tracks",
        strict_axes,
        tracks,
        ts,
        exp,
    )
    lk = thinned(tracks, MAX_FIT_TRACKS)
    if blur == "equal-blur":
        tracks = equal_blur_tracks(lk, read, ts, exp, start, gyro)
        check_tracks(tracks, lk)
    else:
        tracks = corrected_tracks(lk, ts, exp, start, gyro)
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
    nat = NaturalResult(
        res, search, tracks, streaks, {"mode": "none", "chosen_by": "option"}, n_tracked=n_tracked
    )
    if translation != "none":
        from calib.natural.travel import refit_with_translation

        moved = refit_with_translation(
            thinned_result(nat, MAX_TRANSLATION_TRACKS), gyro, opts, translation
        )
        if moved.rotation_only is not None:  # translation modelled: first-pass tracks
            return moved
        nat = replace(nat, translation=moved.translation)
    # Rotation only: the later passes take their kernels from the previous fit.
    for _ in range(passes - 1):
        if blur != "equal-blur" or res.status == "failed":
            break
        # from the previous pass's points: they are within a few hundredths of a pixel
        refined = equal_blur_tracks(tracks, read, ts, exp, res.calibration, gyro)
        check_tracks(refined, tracks)
        tracks = refined
        streaks = tracks_to_streaks(tracks, ts, exp)
        res = calibrate(streaks, gyro, res.calibration, opts)
    sigma_info = None
    if res.status != "failed":
        res, sigma_info = natural_sigma_fit(res, streaks, gyro, opts, scale_prior)
    return replace(nat, result=res, tracks=tracks, streaks=streaks, sigma=sigma_info)
