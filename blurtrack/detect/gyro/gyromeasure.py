"""Measurement of the gyro pass's placements (:mod:`blurtrack.detect.gyro.gyropass`) on their own
images, hairpins as two arms joined at the turn.

A hairpin's two arms lie 2-4 px apart, closer than the cross-section windows of
:func:`blurtrack.detect.lines.measure.measure_lines`: measured as one out-and-back line, each arm's
centroids are pulled towards the other and the edge fits see both arms' light. So each arm
is measured on its own image, the frame minus the other arm's and the other placements'
templates (the prior decides which light is which arm's), from the turn outwards; the start
is the first arm's far end, the end the second's, both edge fits of the image.
:func:`as_streaks` appends the measured streaks to the first pass's kept ones.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks
from blurtrack.detect.gyro.gyroconfirm import mismatch
from blurtrack.detect.gyro.gyrocurve import arm_templates, turn_index
from blurtrack.detect.lines.endpoints import plateau_extent
from blurtrack.detect.lines.lawfit import time_law
from blurtrack.detect.lines.measure import LineSet, Measured, measure_lines
from blurtrack.detect.separation.mosaic import overlapping_placements, placement_mosaic
from blurtrack.detect.separation.templates import Placement
from blurtrack.detect.trust import Evidence, assess


def _end_mismatch(d: dict[str, Any], s: np.ndarray, e: np.ndarray) -> float:
    """Orientation-free mean distance of a measured streak's ends from ``s, e``."""
    return float(mismatch(d["end_a"][None], d["end_b"][None], s[None], e[None])[0])


def _joined(m: Measured, rows: tuple[int, int], turn: np.ndarray) -> dict[str, Any]:
    """One streak from its two measured arms ``rows`` (each measured from the turn outwards,
    in either direction): start = the first arm's far end, end = the second's."""
    parts = []
    for r, outward in zip(rows, (False, True), strict=True):
        a_far = np.hypot(*(m.end_a[r] - turn)) > np.hypot(*(m.end_b[r] - turn))
        # Oriented start -> turn for the first arm, turn -> end for the second.
        fwd = a_far != outward
        pts, prof, pl = m.points[r], m.profile[r], m.plateau[r]
        if not fwd:
            pts, prof, pl = pts[::-1], prof[::-1], pl[::-1]
        parts.append((pts, prof, pl))
    pts = np.concatenate([parts[0][0], parts[1][0]])
    prof = np.concatenate([parts[0][1], parts[1][1]])
    step = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (prof[1:] + prof[:-1]) * step)])
    half = 0.5 * cum[-1]
    j = int(np.clip(np.searchsorted(cum, half), 1, len(cum) - 1))
    f = (half - cum[j - 1]) / max(cum[j] - cum[j - 1], 1e-12)
    saturated = bool(m.saturated[list(rows)].any())
    widths = m.width_px[list(rows)]
    widths = widths[np.isfinite(widths)]  # NaN where neither arm's width was measured
    # Blown out, no width: the arms lie 2-4 px apart and a blown-out core is wider, so the
    # clipped plateau runs from one arm into the other, and an arm's image (the frame less
    # the other arm's unclipped template) has no cross-section of its own.
    width = float(widths.mean()) if widths.size and not saturated else float("nan")
    return {
        "end_a": pts[0],
        "end_b": pts[-1],
        "time_mid": pts[j - 1] + f * (pts[j] - pts[j - 1]),
        "plateau": np.array([parts[0][2][0], parts[1][2][1]]),
        "length_px": float(m.length_px[rows[0]] + m.length_px[rows[1]]),
        "width_px": width,
        "points": pts,
        "profile": prof,
        "saturated": saturated,
        "crossing": bool(m.crossing[list(rows)].any()),
        "short": False,
        "width_unmeasured": saturated,
    }


#: ``arm_of``'s arm for a placement measured as one line: a whole curve, or a hairpin whose
#: short return makes it a hook (:func:`_arms`), measured only under its law.
WHOLE, HOOK = -1, -2


def _arms(pts: np.ndarray, k: int, arc: float, sigma_px: float, gp: Any) -> bool:
    """Whether a hairpin turning at sample ``k`` is measured as two arms: always without the
    time law; with it, unless one arm runs under ``gyro_pass.min_arm_px`` on a curve short
    enough to be fitted whole (no plateau, :func:`~blurtrack.detect.lines.endpoints.plateau_extent`
    at ``sigma_px``), whose law then runs past the end and back. A longer curve's ends are edge
    fits, which find the light's extremity, not where the dot turned back."""
    if not gp.time_law or arc >= plateau_extent(sigma_px):
        return True
    return min(_arc(pts[: k + 1]), _arc(pts[k:])) >= gp.min_arm_px


def _arc(pts: np.ndarray) -> float:
    """The arc length (px) of the polyline ``pts (S, 2)``."""
    return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))


def _measure_once(
    ctx: FrameContext,
    placements: list[Placement],
    ls: LineSet,
    arm_of: list[tuple[int, int]],
    sig: tuple[float, float],
    mosaic: tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray],
) -> tuple[dict[int, dict[str, Any]], float, float]:
    """Per placement index, its streak measured on ``mosaic`` (the mosaic of the placements,
    hairpins as their two arms ``arm_of``;
    :func:`~blurtrack.detect.separation.mosaic.placement_mosaic`) along the lines ``ls``,
    frame coordinates, placements not measured whole absent; and the cross-section sigmas
    used."""
    sig_s, sig_r = sig
    mos_s, mos_r, _, back = mosaic
    lit_median_factor = ctx.params.gyro_pass.lit_median_factor
    m = measure_lines(ctx.on(mos_s, mos_r), ls, sig_s, False, sig_r, lit_median_factor)
    off = back[m.src]
    m.end_a, m.end_b, m.time_mid = m.end_a + off, m.end_b + off, m.time_mid + off
    m.points = [q + o for q, o in zip(m.points, off, strict=True)]
    rows_of: dict[int, list[int]] = {}
    for r, i in enumerate(m.src.tolist()):
        rows_of.setdefault(i, []).append(r)
    arms: dict[int, list[int]] = {}  # per placement, its lines' indices in ``arm_of``
    for i, (jj, _) in enumerate(arm_of):
        arms.setdefault(jj, []).append(i)
    out: dict[int, dict[str, Any]] = {}
    for j, q in enumerate(placements):
        idx = arms.get(j, [])
        got = [rows_of.get(i, []) for i in idx]
        if any(len(g) != 1 for g in got):
            continue  # an arm split or lost: not measured whole
        if len(idx) == 1:
            r = got[0][0]
            if arm_of[idx[0]][1] == HOOK and not m.short[r]:
                # A hook's ends are where its law puts them; edge fits (the line came out
                # long: light of a neighbour left in its own image) find the extremity.
                continue
            out[j] = {n: getattr(m, n)[r] for n in _FIELDS} | {"width_unmeasured": False}
        else:
            turn = q.tpl.points[turn_index(q.tpl.points)] + q.shift
            out[j] = _joined(m, (got[0][0], got[1][0]), turn)
    return out, m.sigma_c, m.sigma_raw


def measure_placements(
    ctx: FrameContext,
    placements: list[Placement],
    placed_ends: np.ndarray,
    sig_s: float,
    sig_r: float,
) -> Measured:
    """Each placement measured on its own image by :func:`measure_lines`, frame coordinates;
    ``src`` indexes ``placements``. A hairpin is measured as its two arms (each on its own
    image: the frame minus the other arm's and the other placements' templates, so the prior
    decides which light is which arm's), joined at the turn.

    Each placement is measured on two own images, the frame minus the neighbours' templates
    as it is and with that difference clipped at zero (where the neighbours' templates cover
    more than the light, ``gyro_pass.clip_choice``), and keeps the line whose ends lie nearer its
    placed curve's ``placed_ends`` ``(P, 2, 2)`` (start, end; either orientation). Both lines
    are the image's; the prior chooses between two segmentations of the light, as it does
    when it places the templates.
    """
    gp = ctx.params.gyro_pass
    flat: list[Placement] = []
    arm_of: list[tuple[int, int]] = []
    for j, q in enumerate(placements):
        pts = q.tpl.points
        k = turn_index(pts)
        chord = float(np.hypot(*(pts[-1] - pts[0])))
        arc = _arc(pts)
        hairpin = 3 <= k <= len(pts) - 4 and chord < gp.arms_chord * arc
        if hairpin and _arms(pts, k, arc, sig_s, gp):
            a1, a2 = arm_templates(q.tpl, sig_s, sig_r)
            flat += [Placement(a1, q.shift, q.amp, q.comp), Placement(a2, q.shift, q.amp, q.comp)]
            arm_of += [(j, 0), (j, 1)]
        else:
            flat.append(q)
            arm_of.append((j, HOOK if hairpin else WHOLE))
    sig = (sig_s, sig_r)
    pad = int(np.ceil(6.0 * sig_s)) + 8
    mosaic = placement_mosaic(ctx.smooth, ctx.signal, flat, pad)
    # Arms of one hairpin share light by design: each takes its whole placement's flag.
    whole_cross = overlapping_placements(placements, ctx.params.separation.overlap_fraction)
    cross = [bool(whole_cross[j]) for j, _ in arm_of]
    # A whole placement's streak is its predicted curve's (uniform in time): its law spreads
    # the light between the ends; an arm's is half a hairpin, left to the density fit.
    law = (
        [
            time_law(q.tpl.points) if arm < 0 else None
            for q, (_, arm) in zip(flat, arm_of, strict=True)
        ]
        if gp.time_law
        else None
    )
    ls = LineSet(mosaic[2], [q.comp for q in flat], cross, [False] * len(flat), law)
    found, sigma_c, sigma_raw = _measure_once(ctx, placements, ls, arm_of, sig, mosaic)
    if gp.clip_choice:
        # The clipped own images: the same mosaic clipped at zero in place (its zeros
        # between tiles stay zero), the neighbours' templates warped once.
        for img in mosaic[:2]:
            np.maximum(img, 0.0, out=img)
        clipped = _measure_once(ctx, placements, ls, arm_of, sig, mosaic)[0]
        for j, c in clipped.items():
            o = found.get(j)
            s, e = placed_ends[j]
            if o is None or _end_mismatch(c, s, e) < _end_mismatch(o, s, e):
                found[j] = c
    srcs = sorted(found)
    out = [found[j] for j in srcs]
    own = [placements[j].comp for j in srcs]

    def arr(name: str, shape: tuple[int, ...], dtype: Any = float) -> np.ndarray:
        return np.array([o[name] for o in out], dtype).reshape((len(out), *shape))

    return Measured(
        own=np.array(own, np.int64),
        src=np.array(srcs, np.int64),
        end_a=arr("end_a", (2,)),
        end_b=arr("end_b", (2,)),
        time_mid=arr("time_mid", (2,)),
        plateau=arr("plateau", (2,)),
        length_px=arr("length_px", ()),
        width_px=arr("width_px", ()),
        points=[np.asarray(o["points"], float) for o in out],
        profile=[np.asarray(o["profile"], float) for o in out],
        saturated=arr("saturated", (), bool),
        crossing=arr("crossing", (), bool),
        looped=np.zeros(len(out), bool),
        short=arr("short", (), bool),
        sigma_c=sigma_c,
        sigma_raw=sigma_raw,
        width_unmeasured=arr("width_unmeasured", (), bool),
    )


#: The per-streak fields of :class:`Measured` that one placement's measurement carries.
_FIELDS = (
    "end_a",
    "end_b",
    "time_mid",
    "plateau",
    "length_px",
    "width_px",
    "points",
    "profile",
    "saturated",
    "crossing",
    "short",
)


def as_streaks(
    fs: FrameStreaks,
    keep: np.ndarray,
    m: Measured | None,
    ctx: FrameContext,
    psf: float,
) -> FrameStreaks:
    """The template pass's frame: rows ``keep`` of the first pass's ``fs`` followed by the
    measured streaks ``m`` (flags as the first pass sets them) on the frame ``ctx``. Each
    streak is held to the cross-section sigma it was measured with (``merged`` and all the
    evidence of :func:`~blurtrack.detect.trust.assess`): the measured ones to ``psf``, the
    one of the templates and the measurement, the kept first-pass lines to the frame's own
    ``fs.sigma_c_px``, as the first pass flagged them."""
    comps, p = ctx.comps, ctx.params
    k = np.flatnonzero(keep)
    if m is None or len(m) == 0:
        new: dict[str, Any] = {}
        n_new = 0
    else:
        n_new = len(m)
        flags = {
            "clipped": ctx.clipped(m.end_a, m.end_b),
            "saturated": m.saturated,
            "crossing": m.crossing,
            "merged": ctx.merged(m.width_px, psf),
            "looped": m.looped,
            "faint": comps.peaks[m.own] < p.faint_snr * ctx.noise_smooth,
        }
        new = {
            "end_a": m.end_a,
            "end_b": m.end_b,
            "time_mid": m.time_mid,
            "plateau": m.plateau,
            "length_px": m.length_px,
            "width_px": m.width_px,
            "snr": comps.peaks[m.own] / ctx.noise_smooth,
            "short": m.short,
            "flags": flags,
            "points": m.points,
            "profile": m.profile,
        }

    def cat(name: str) -> np.ndarray:
        old = getattr(fs, name)[k]
        return np.concatenate([old, new[name]]) if n_new else old

    short = fs.short if len(fs.short) == len(fs) else np.zeros(len(fs), bool)
    along = fs.along_curve if len(fs.along_curve) == len(fs) else np.zeros(len(fs), bool)
    points = [fs.points[i] for i in k] + (list(new["points"]) if n_new else [])
    profile = [fs.profile[i] for i in k] + (list(new["profile"]) if n_new else [])
    width = cat("width_px")
    # Two blown-out arms have no width to measure (:func:`_joined`): their fill decides
    # whether they are a point light's, and they are not ``merged``: the other light
    # alongside is their own other arm.
    unmeasured = np.zeros(len(width), bool)
    if n_new and m is not None and m.width_unmeasured is not None:
        unmeasured[len(k) :] = m.width_unmeasured
    # Measured again over the new set: the neighbours of the old streaks have changed.
    plateau = cat("plateau")
    evidence = assess(ctx, points, profile, plateau, width, psf, unmeasured)
    if len(k) and n_new and psf != fs.sigma_c_px:
        kept = assess(ctx, points, profile, plateau, width, fs.sigma_c_px, unmeasured)
        rows = np.arange(len(width))
        evidence = Evidence.concat([kept.take(rows[: len(k)]), evidence.take(rows[len(k) :])])
    return FrameStreaks(
        shape=fs.shape,
        end_a=cat("end_a"),
        end_b=cat("end_b"),
        time_mid=cat("time_mid"),
        plateau=cat("plateau"),
        length_px=cat("length_px"),
        width_px=width,
        snr=cat("snr"),
        points=points,
        profile=profile,
        flags={
            f: np.concatenate([fs.flags[f][k], new["flags"][f]]) if n_new else fs.flags[f][k]
            for f in FLAG_NAMES
        },
        sigma_c_px=fs.sigma_c_px,
        noise=fs.noise,
        hot_pixels=fs.hot_pixels,
        short=np.concatenate([short[k], new["short"]]) if n_new else short[k],
        saturated_fraction=fs.saturated_fraction,
        evidence=evidence,
        along_curve=np.concatenate([along[k], np.ones(n_new, bool)]) if n_new else along[k],
        light_bgr=fs.light_bgr,
    )
