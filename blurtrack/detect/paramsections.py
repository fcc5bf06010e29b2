"""The stage sections of :class:`blurtrack.detect.params.DetectParams`: one frozen,
self-validating dataclass per stage folder (``lines``, ``separation``, ``quality``,
``gyro_pass``), each field range-checked from its metadata
(:func:`~blurtrack.detect.paramfields.check_section`).

Defaults are the values the detector was tuned with; the measurements behind them are in the
field descriptions (``hard``/``dense``/``realistic``: the simulator's presets; ``night1``,
``night2``, ``phone``: the real photographs of docs/detection.md). Lengths in px, everything
else a ratio (to a plateau, a peak, a length, a cross-section sigma) unless named otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

from blurtrack.detect.paramfields import (
    check_order,
    check_section,
    int_field,
    num_field,
    switch_field,
)


@dataclass(frozen=True)
class LinesParams:
    """Centre lines and their extent (:mod:`blurtrack.detect.lines`; YAML ``lines:``).

    - ``lit_fraction``: a line's points whose cross-section integral exceeds this fraction of
      the line's lit level are moved onto the light and bound the line's extent
      (:func:`~blurtrack.detect.lines.centreline.refine_lines`; below an end's half level,
      which the edge fits need inside the line).
    - ``tail_fraction``, ``tail_min_px``: past a bound the line keeps, unmoved, a faint tail
      (points above ``tail_fraction`` of the lit level contiguous with it) where it reaches
      more than ``tail_min_px`` further. A dot that speeds up during the exposure draws a
      bright start and a tail fading towards its end (``hard`` seed 4 frame 3: isolated streaks
      cut 10-20 px short); shorter runs are the end cap's own blur, left to the edge fits.
      ``hard`` seeds 1-5, recall / precision: 97.87 / 98.77, 92.58 / 94.92, 91.03 / 93.63,
      91.46 / 96.07, 97.72 / 99.10 % against 97.87 / 98.77, 92.27 / 95.21, 89.96 / 92.75,
      84.60 / 91.08, 97.72 / 99.10 % without. ``tail_min_px: .inf`` turns tails off.
    - ``median_floor``: where a line's lit level is a multiple of its median profile (the gyro
      pass's ``lit_median_factor``), that median is taken over the points above this fraction
      of the line's peak (not the unlit extensions past its ends).
    - ``gap_level``, ``long_factor``: a line longer than ``long_factor`` times the frame's
      median lit extent whose profile falls below ``gap_level`` of its lit level inside is
      cut at the dip (:mod:`~blurtrack.detect.lines.gaps`: two dots' streaks touching end to
      end on a dense grid; their facing erf edges meet below a third of the plateau, and a
      fast middle of one streak also dims it, hence the length test).
    """

    lit_fraction: float = num_field(0.25, 0.0, 1.0, lo_open=True, hi_open=True)
    tail_fraction: float = num_field(0.1, 0.0, 1.0, lo_open=True, hi_open=True)
    tail_min_px: float = num_field(6.0, 0.0, infinite=True)
    median_floor: float = num_field(0.05, 0.0, 1.0, hi_open=True)
    gap_level: float = num_field(0.3, 0.0, 1.0, lo_open=True, hi_open=True)
    long_factor: float = num_field(1.6, 1.0)

    def __post_init__(self) -> None:
        check_section(self, "lines")
        check_order(self, "lines", "tail_fraction", "lit_fraction")


@dataclass(frozen=True)
class SeparationParams:
    """Template separation of touching and broken streaks (:mod:`blurtrack.detect.separation`;
    YAML ``separation:``). Scores are support-normalised correlations (1: a scaled copy of
    the template), amplitudes relative to the template's.

    Candidates and replacement (:mod:`~blurtrack.detect.separation.separate`):

    - ``residual_max``: a candidate whose light (squared) the placements leave more than
      this fraction of keeps its first-pass lines (half: most of its light explained).
    - ``overlap_fraction``: placements whose supports share more than this fraction of the
      smaller one are flagged ``crossing``.
    - ``area_factor``, ``neighbours``: a component larger than ``area_factor`` times the
      median area of its ``neighbours`` nearest references is a candidate (a chain of two
      streaks has about twice a reference's area; 1.6 leaves the spread of single streaks).
    - ``halo_max``: the most light (squared, relative to that under the template) that a
      placed template's halo ring may hold: a placement whose surroundings are bright sits
      on a larger light, not on one dot's streak.
    - ``halo_max_whole``: the same with whole-component references: real lights on a string
      touch their neighbours, whose light then lies in the halo (``night2``).
    - ``stub_fraction``, ``stub_min_px``: a plain line shorter than ``stub_fraction`` of the
      consensus length (where that is at least ``stub_min_px``: short streaks vary more) is
      no measurement of its component (a collapsed line): the component is a candidate.
      0 turns the rule off.

    Matching pursuit (:mod:`~blurtrack.detect.separation.pursuit`):

    - ``score_min``, ``amp_min``: the lowest score and amplitude of an accepted placement
      (a collinear neighbour overlapping a fraction ``f`` scores about ``sqrt(f)``: 0.8
      refuses overlaps of less than 64 %).
    - ``suppress``: a round takes every good placement that keeps this fraction of the
      template's size from a better one.
    - ``left_min``: a further round needs this fraction of a weakest placement's light left.

    Joint refit (:mod:`~blurtrack.detect.separation.refit`):

    - ``amp_keep``: a step whose amplitude would fall below this keeps the placement where
      it was.
    - ``reach_fraction``, ``reach_min_px``, ``reach_max_px``: how far one step may move a
      placement: this fraction of the template's larger side, within the two bounds.

    Templates and whole-component references (:mod:`~blurtrack.detect.separation.templates`,
    :mod:`~blurtrack.detect.separation.modal`):

    - ``inside_min``: a placement reaching past the frame's border needs this fraction of its
      template (in squares) inside the frame.
    - ``modal_min_area_px``: the smallest component that can be a whole streak of the modal
      cluster.
    - ``modal_cluster_log``: the largest difference of log area, log width and log height
      within the modal cluster (0.25: sizes within about 28 % of each other).

    Anchored placements on fragments (:mod:`~blurtrack.detect.separation.anchored`):

    - ``fragment_fraction``, ``fragment_min_px``: a streak whose chord is under this
      fraction of the local consensus length (where that is at least ``fragment_min_px``)
      is a fragment.
    - ``anchor_amp_min``, ``anchor_score_min``: the lowest amplitude and score of an
      anchored placement (a faint light on a string is above the threshold only at its
      hook, far fainter than the reference).
    - ``anchor_cover_min``: the fraction of the fragment's centre-line points that the
      placed support must hold (the placement stays on the fragment's own light).
    - ``same_light_fraction``: accepted placements closer than this fraction of the
      consensus length are one light.

    Remnants (:func:`blurtrack.detect.frame.detect_frame`, and the gyro pass against its
    predicted curves):

    - ``spot_fraction``, ``spot_min_px``: unclipped streaks shorter than ``spot_fraction``
      of the local consensus length (where that is at least ``spot_min_px``) are dropped:
      every dot draws about the same curve, so they are remnants of chains or blobs.
    """

    residual_max: float = num_field(0.5, 0.0, 1.0, lo_open=True)
    overlap_fraction: float = num_field(0.1, 0.0, 1.0)
    area_factor: float = num_field(1.6, 1.0)
    neighbours: int = int_field(6, 1)
    halo_max: float = num_field(0.25, 0.0)
    halo_max_whole: float = num_field(1.0, 0.0)
    stub_fraction: float = num_field(0.5, 0.0, 1.0)
    stub_min_px: float = num_field(20.0, 0.0)
    score_min: float = num_field(0.8, 0.0, 1.0, lo_open=True)
    amp_min: float = num_field(0.6, 0.0, lo_open=True)
    suppress: float = num_field(0.4, 0.0)
    left_min: float = num_field(0.5, 0.0, 1.0)
    amp_keep: float = num_field(0.4, 0.0)
    reach_fraction: float = num_field(0.2, 0.0, lo_open=True)
    reach_min_px: int = int_field(3, 1)
    reach_max_px: int = int_field(8, 1)
    inside_min: float = num_field(0.3, 0.0, 1.0, lo_open=True)
    modal_min_area_px: int = int_field(40, 1)
    modal_cluster_log: float = num_field(0.25, 0.0, lo_open=True)
    fragment_fraction: float = num_field(0.75, 0.0, 1.0, lo_open=True)
    fragment_min_px: float = num_field(20.0, 0.0)
    anchor_amp_min: float = num_field(0.05, 0.0, lo_open=True)
    anchor_score_min: float = num_field(0.65, 0.0, 1.0, lo_open=True)
    anchor_cover_min: float = num_field(0.75, 0.0, 1.0, lo_open=True)
    same_light_fraction: float = num_field(0.3, 0.0, lo_open=True)
    spot_fraction: float = num_field(0.2, 0.0, 1.0)
    spot_min_px: float = num_field(20.0, 0.0)

    def __post_init__(self) -> None:
        check_section(self, "separation")
        check_order(self, "separation", "reach_min_px", "reach_max_px")


@dataclass(frozen=True)
class QualityParams:
    """The frame's shape consensus and the per-streak quality flag
    (:mod:`blurtrack.detect.separation.quality`; YAML ``quality:``).

    - ``shape_tol_px``, ``shape_tol_rel``: a streak's start-to-end vector may deviate from
      the frame's consensus by ``max(shape_tol_px, shape_tol_rel * |consensus|)`` and be
      ``quality_ok``; separation takes the same tolerance for its candidates and references.
    - ``min_reference``: the fewest unflagged streaks for a consensus, both to fit it and,
      for ``quality_ok``, within the shape tolerance of the fitted field (an affine field has
      6 unknowns, 2 per vector: at least 3; 5 leave redundancy for the robust fit).
    - ``thick_width_ratio``: saturated streaks wider than this times the frame's median width
      are ``thick_saturated``.
    - ``merged_width``: streaks wider than this times the frame's cross-section sigma are
      ``merged`` (two dots overlapping side by side measure about 1.5x; a single dot's width
      scatters ~10 % around the median).
    - ``overexposed_fraction``: a frame with more than this fraction of its pixels saturated
      is listed as over-exposed in the summary (a laser-dot frame lights a few % of its
      pixels; a quarter saturated is a lit scene or an exposure far too long).
    """

    shape_tol_px: float = num_field(3.0, 0.0, lo_open=True)
    shape_tol_rel: float = num_field(0.25, 0.0)
    min_reference: int = int_field(5, 3)
    thick_width_ratio: float = num_field(2.0, 1.0)
    merged_width: float = num_field(1.5, 1.0)
    overexposed_fraction: float = num_field(0.25, 0.0, 1.0, hi_open=True)

    def __post_init__(self) -> None:
        check_section(self, "quality")


@dataclass(frozen=True)
class GyroPassParams:
    """The gyro-template second pass (:mod:`blurtrack.detect.gyro`; YAML ``gyro_pass:``). Its
    pursuit and replacement also read ``separation.score_min``, ``amp_min``, ``halo_max``,
    ``residual_max`` and the remnant rule ``separation.spot_*``.

    Which frames and components (:func:`~blurtrack.detect.gyro.gyrogate.gate`):

    - ``hairpin_chord``: frames whose median predicted chord is under this fraction of the
      arc are hairpin frames (every component a candidate).
    - ``min_arc_px``: predicted curves shorter than this are left to the first pass (12
      until 2026-12-07: frames of short streaks that turn within the exposure were then left
      to the first pass, whose ends are the turns, and the gyro's check refused them;
      held-out ``dense`` / ``realistic`` seeds 6, 9, 10, ok-coverage %: 93.04 / 87.21 / 94.50
      and 92.67 / 86.99 / 93.95 at 12, 93.17 / 87.86 / 96.00 and 93.04 / 87.62 / 95.34 at 8,
      96.57 / 92.24 / 96.00 and 96.27 / 89.86 / 95.34 at 4, the same at 2; precision
      unchanged, ``hard`` seeds 1-4 within 0.1 point).
    - ``tol_px``, ``tol_rel``: endpoint tolerance between a line and its prediction,
      ``tol_px + tol_rel * arc``.
    - ``bad_fraction``: other frames are refined where more than this fraction of the long
      first-pass streaks miss their prediction (0: any).
    - ``hook_fraction``: ... or where more than this fraction of them hook or double back
      within the exposure, by more than ``source.hairpin_depth_px`` (the gyro check's own
      test, :func:`~blurtrack.detect.gyro.framecheck.hairpin_depth`): their visible ends are
      the turns, which the check refuses; the pass measures them along their curves. Not 0: a
      frame's one or two hooks cost the pass over the whole frame for a few streaks
      (``dense`` seed 1, 20 frames: 0 refines 3 frames for +0.02 point of coverage at +40 %
      CPU; 0.05 none). With ``time_law``, where the session's calibration was corrected,
      also where more than this fraction of them have start-to-end vectors more than
      ``source.gyro_vector_tol_px`` off the corrected prediction (the check's test;
      ``vectors``: the components of those lines are the candidates).
    - ``border_candidates``: components touching the border are candidates too: on frames of
      long streaks the chains run into the border (``hard`` seed 3 frame 7: 50 of 65
      components, 88 % of the light).
    - ``clip_at_border``: border candidates' placements may reach past the border (the images
      padded with zeros, each placement scored and scaled by its template's part inside the
      frame, its placed curve cut at the border): chains into the border hold streaks
      leaving the frame, which no template wholly inside explains.

    Placing and accepting (:mod:`~blurtrack.detect.gyro.gyropass`,
    :mod:`~blurtrack.detect.gyro.gyroconfirm`):

    - ``shape_score_min``: the lowest score of a candidate's best predicted shape (with
      ``shape_search``; a session-corrected curve is left to the pursuit's floors).
    - ``light_quantile``: without first-pass lines inside the frame, the typical dot's light
      is this quantile of the components' light (chains are brighter).
    - ``measured_min``: a component is replaced where at least this fraction of its
      placements was measured.
    - ``accept_min``: a frame keeps its first pass unless this fraction of its measured
      placements is confirmed in components replaced whole (0.5 until 2026-12-03).
    - ``shape_shift_factor``: a line whose shape matches its placed curve's is confirmed
      where its position lies within this times the tolerance (along a collinear chain a
      placement may slip by part of a streak).
    - ``old_lines_margin``: a replaced component's first-pass lines stay where they fit its
      placed curves this many times better than the new lines (summed end mismatch). The
      placed curves' ends are 2 px from the measured ones at the median, 14 px at the 90th
      percentile, so a comparison at par kept worse old lines (1.0 until 2026-12-03: ``hard``
      seed 3 endpoint median 0.304 px; at 1.5 0.286 px, precision 92.00 -> 92.51 %; seed 2
      recall -0.27 %).
    - ``chain_factor``: in a refined frame, first-pass lines longer than this times their
      predicted arc are dropped (chains; 1.6 until 2026-12-03, 1.15 cost ``hard`` seed 1
      0.27 % of recall).

    - ``shape_search``: each candidate's predicted curve is rotated and scaled about its
      centroid to the shape its light fits best
      (:func:`~blurtrack.detect.gyro.gyroshape.best_shape`), standing in for a nominal
      calibration; the session does not search where it corrected its calibration first
      (``session_calibration``).
    - ``session_calibration``: before the pass, the session's calibration error (focal
      length, principal point, axes, time offset, readout, gyro bias) is fitted from the
      first pass's ``quality_ok`` streaks (:mod:`~blurtrack.detect.gyro.sessioncalib`) and
      the pass, the orientation cues and the gyro's check predict with the corrected model.

    Measuring the placements (:mod:`~blurtrack.detect.gyro.gyromeasure`):

    - ``lit_median_factor``: a placement's line is kept from its first to its last point
      above a quarter of its peak profile, but at most this times its median (2 and 4
      measured worse): the curve runs along the whole streak, whose bright hook can be
      several times its tail. (The first pass keeps the peak: the same factor there moved
      ``phone``'s ends into the blooming, 1.43 -> 1.55 px on its optics test frame.)
    - ``arms_chord``: placements whose curve's chord is under this fraction of its arc are
      measured as two arms joined at the turn.
    - ``clip_choice``: each placement is measured with the neighbours' templates subtracted
      as they are and clipped at zero, keeping the line nearer its placed curve; false: as
      they are only. ``hard`` seeds 1-5, recall / precision %: clipped alone 97.51 / 98.68,
      91.33 / 94.85, 89.12 / 93.21, 84.88 / 91.48, 97.68 / 99.10; as they are 97.73 / 98.86,
      92.14 / 94.85, 89.16 / 92.52, 84.17 / 90.85, 97.72 / 99.19; the choice 97.87 / 98.77,
      92.27 / 95.21, 89.96 / 92.75, 84.60 / 91.08, 97.72 / 99.10.
    - ``time_law``: a placement's short streak (no plateau at its ends), and a longer one,
      unsaturated and not crossing, whose dot rests near an end, is fitted under its
      predicted curve's time law (:mod:`~blurtrack.detect.lines.lawfit`: where along the chord
      the dot is at each time; the start, length and light stay the image's) instead of a
      density the blur lets it fit (linear below 5 sigmas): a dot slowing towards both ends
      piles light there, which a linear density reads as a longer streak (``dense`` seed 9:
      the right streaks the check refused were 1.4 px too long at the median). Held-out
      ``dense`` seeds 6 / 9 / 12 ok-coverage %: 96.57 / 92.24 / 96.30 without, 97.08 / 94.42 /
      96.47 with (and ``min_arm_px`` 0).
    - ``min_arm_px``: with ``time_law``, a hairpin placement (``arms_chord``) is measured as
      two arms only where both arms run at least this far; a shorter return is a hook, one
      line whose law runs past the end and back (an arm of 0.7 px has no edge to fit: its
      end landed 1-2 px off). ``dense`` seeds 9 / 8 / 6 / 12 ok-coverage %: 0 (arms as
      before) 94.42 / 94.04 / 97.08 / 96.47; 1: 95.44 / 94.43 / 97.39 / 96.64; 1.5: 96.70 /
      94.67 / 97.79 / 96.74; 2: 96.46 / 94.63 / 97.66 / 96.71; 2.5: 96.12 / 94.63 / 95.96 /
      96.54; 3: 96.05 / 94.63 / 95.76 / 96.47; 6: 95.99 / 94.63 / 96.74 / 96.47; precision
      within one streak at each.
    """

    hairpin_chord: float = num_field(0.8, 0.0, 1.0, lo_open=True)
    min_arc_px: float = num_field(4.0, 0.0)
    tol_px: float = num_field(2.5, 0.0)
    tol_rel: float = num_field(0.1, 0.0)
    bad_fraction: float = num_field(0.0, 0.0, 1.0, hi_open=True)
    hook_fraction: float = num_field(0.05, 0.0, 1.0)
    border_candidates: bool = switch_field(True)
    clip_at_border: bool = switch_field(True)
    shape_score_min: float = num_field(0.8, 0.0, 1.0)
    light_quantile: float = num_field(0.4, 0.0, 1.0)
    measured_min: float = num_field(0.5, 0.0, 1.0)
    accept_min: float = num_field(0.35, 0.0, 1.0)
    shape_shift_factor: float = num_field(2.0, 1.0)
    old_lines_margin: float = num_field(1.5, 0.0, lo_open=True)
    chain_factor: float = num_field(1.25, 1.0)
    lit_median_factor: float = num_field(3.0, 0.0, lo_open=True)
    arms_chord: float = num_field(0.8, 0.0, 1.0, lo_open=True)
    clip_choice: bool = switch_field(True)
    time_law: bool = switch_field(True)
    min_arm_px: float = num_field(2.0, 0.0)
    shape_search: bool = switch_field(True)
    session_calibration: bool = switch_field(True)

    def __post_init__(self) -> None:
        check_section(self, "gyro_pass")


@dataclass(frozen=True)
class OrientationParams:
    """The start/end cues' error model (:mod:`blurtrack.detect.session.orientation`; YAML
    ``orientation:``). Each cue is a log-likelihood ratio (LLR) that end A is the start.

    - ``gyro_sigma_px``, ``gyro_sigma_rel``: the gyro's predicted ends scatter about the
      measured ones by ``gyro_sigma_px + gyro_sigma_rel * length`` (a time shift off by a
      few ms moves a streak's ends by a fraction of its length; the measured ends' own error
      is ~0.2-0.4 px on ``realistic``, 1-1.5 px on saturated ``hard`` streaks).
    - ``gyro_sigma_rel_refined``: the relative part once the time-shift scan found the shift
      (the remaining error is the calibration's, about half).
    - ``profile_sigma_log``: the scatter of the log ratio of the two ends' plateau brightness
      about the log ratio of the gyro's predicted speeds there (brightness is 1 / speed;
      speckle and noise leave ~0.3).
    - ``max_cue_llr``: every cue's LLR is clipped to +-this, so that no single cue drowns the
      others (25: odds of ~7e10, beyond any error model's validity).
    - ``continuity_present``: the chance that a dot's own end lies near where its streak's end,
      extrapolated through the gap, says it should in a neighbouring frame: found there, and
      the motion through the gap as extrapolated (a turn in the gap, a dot leaving the view
      or missed; :func:`~blurtrack.detect.session.orientation.continuity_llr`). It bounds what a
      missing end says against an orientation (``ln(1 - p)``). 0.75: the log-loss of the
      continuity-only orientation against the truth on ``hard`` seeds 1, 2, 5, 6 was lowest
      among 0.7-0.9.
    - ``continuity_radius``: other dots' ends about an extrapolated end are counted within
      this many extrapolation uncertainties (each at least 2 px), their density bounding what a
      near end says for an orientation (a stranger's end may lie as near).
    - ``direction_check``: before using the gyro, check its direction of motion against the
      frames' own continuity (:mod:`~blurtrack.detect.gyro.direction`); where it runs the
      other way (wrong camera-IMU axes) detection goes on from the images alone.
    - ``direction_llr``: a cue is decisive in that check from this |LLR| (2: odds of 7.4).
    - ``direction_frame_agree``, ``direction_session_agree``: the gyro is contradicted where
      a sampled frame's decisive gyro and continuity cues agree on less than the first
      fraction of its streaks, or all sampled frames' on less than the second by more than
      chance explains (:data:`~blurtrack.detect.gyro.direction.DECIDE_SIGMAS`; right axes:
      0.47 on the worst ``hard`` frame, 0.87-1.0 per session; a half turn: 0.004).
    """

    gyro_sigma_px: float = num_field(1.5, 0.0, lo_open=True)
    gyro_sigma_rel: float = num_field(0.25, 0.0)
    gyro_sigma_rel_refined: float = num_field(0.12, 0.0)
    profile_sigma_log: float = num_field(0.35, 0.0, lo_open=True)
    max_cue_llr: float = num_field(25.0, 0.0, lo_open=True)
    continuity_present: float = num_field(0.75, 0.0, 1.0, lo_open=True, hi_open=True)
    continuity_radius: float = num_field(10.0, 1.0)
    direction_check: bool = switch_field(True)
    direction_llr: float = num_field(2.0, 0.0, lo_open=True)
    direction_frame_agree: float = num_field(0.2, 0.0, 1.0)
    direction_session_agree: float = num_field(0.5, 0.0, 1.0)

    def __post_init__(self) -> None:
        check_section(self, "orientation")
        check_order(self, "orientation", "direction_frame_agree", "direction_session_agree")
        check_order(self, "orientation", "gyro_sigma_rel_refined", "gyro_sigma_rel")


@dataclass(frozen=True)
class TimeshiftParams:
    """The camera-IMU time shift found from the streaks (:mod:`blurtrack.detect.gyro.timeshift`,
    the scan of measured ends; :mod:`blurtrack.detect.gyro.shiftfit`, the refinement by the
    predicted templates; YAML ``timeshift:``).

    - ``scan_min_length_px``: the scan uses streaks longer than this (a shorter one's ends
      move by less than their own error over the scan's steps).
    - ``scan_sigma_rel``: the scan weighs each streak's squared end distances by
      ``(orientation.gyro_sigma_px + scan_sigma_rel * length)^2``.
    - ``scan_min_contrast``: least drop of the scan's cost from its median to its minimum
      (a chi-square-like sum: 9 is three sigmas for one parameter) for the minimum to mean
      anything; a gyro that reads zero, or a motion too small to blur, gives a flat cost.
    - ``refit_min_length_px``: the refinement uses streaks at least this long (shorter ones
      say little about the curve's shape).
    - ``refit_min_streaks``: fewer usable streaks over the sampled frames keep the scan's
      shift.
    - ``readout_rel``: the readout is refitted within this fraction of the session's.
    - ``min_row_spread``: ... only where the streaks' row fractions spread at least this
      much (standard deviation; a uniform spread is 0.29).
    - ``readout_order_check``: decide from the frames which row a rolling shutter reads
      first (:mod:`~blurtrack.detect.gyro.readout`: the scan again on the frames turned by
      180 degrees); where the bottom row is first, detect in the turned frames.
    - ``readout_order_llr``: ... where one order's least scan cost is the lower by twice
      this (a log-likelihood ratio; 20: odds of 5e8). Measured: 106-768 for the top row
      first on every simulator preset's seeds 3 and 4 and ``hard`` 1-11, -222 and -718 with
      the frames turned.
    """

    scan_min_length_px: float = num_field(5.0, 0.0)
    scan_sigma_rel: float = num_field(0.1, 0.0)
    scan_min_contrast: float = num_field(9.0, 0.0)
    refit_min_length_px: float = num_field(15.0, 0.0)
    refit_min_streaks: int = int_field(20, 1)
    readout_rel: float = num_field(0.15, 0.0, 1.0, hi_open=True)
    min_row_spread: float = num_field(0.15, 0.0, infinite=True)
    readout_order_check: bool = switch_field(True)
    readout_order_llr: float = num_field(20.0, 0.0, lo_open=True)

    def __post_init__(self) -> None:
        check_section(self, "timeshift")
