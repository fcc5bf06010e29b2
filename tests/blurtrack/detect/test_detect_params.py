"""The stage sections of DetectParams (blurtrack.detect.paramsections): YAML round trip,
unknown keys and out-of-range values refused with one line naming ``detect <section>.<field>``,
every field documented, and moved values really read by the stages they govern."""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.params import (
    GyroPassParams,
    LinesParams,
    OrientationParams,
    QualityParams,
    SeparationParams,
    SourceParams,
    TimeshiftParams,
)
from blurtrack.detect.separation.quality import frame_quality
from blurtrack.detect.session.pipeline import detect_session
from blurtrack.errors import ConfigError
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session
from blurtrack.testing.streak_frames import line, line_grid, quantise, render_streaks

DOCS = Path(__file__).resolve().parents[3] / "docs" / "detection.md"

#: YAML key -> section class.
SECTIONS: dict[str, type] = {
    "source": SourceParams,
    "lines": LinesParams,
    "separation": SeparationParams,
    "quality": QualityParams,
    "gyro_pass": GyroPassParams,
    "orientation": OrientationParams,
    "timeshift": TimeshiftParams,
}

#: Per section, a valid non-default value of some fields (the round trip must keep them).
CHANGED: dict[str, dict[str, Any]] = {
    "source": {"end_light_max": 0.3, "hairpin_depth_px": 0.75},
    "lines": {"tail_min_px": 8.0, "gap_level": 0.25},
    "separation": {"residual_max": 0.6, "neighbours": 4, "reach_max_px": 10},
    "quality": {"shape_tol_px": 2.5, "min_reference": 6},
    "gyro_pass": {"tol_px": 3.0, "clip_choice": False},
    "orientation": {"gyro_sigma_px": 2.0, "max_cue_llr": 30.0},
    "timeshift": {"scan_min_contrast": 16.0, "refit_min_streaks": 30},
}

#: Per section, values out of range (negative controls): field -> value.
BAD: dict[str, list[tuple[str, Any]]] = {
    "lines": [("lit_fraction", 1.0), ("tail_min_px", -1.0), ("gap_level", float("nan"))],
    "separation": [
        ("score_min", 1.5),
        ("neighbours", 0),
        ("neighbours", 6.0),
        ("halo_max", -0.1),
        ("reach_min_px", True),
    ],
    "quality": [("min_reference", 2), ("merged_width", 0.5), ("shape_tol_px", float("inf"))],
    "gyro_pass": [("clip_at_border", 1), ("bad_fraction", 1.0), ("accept_min", "0.3")],
    "orientation": [("gyro_sigma_px", 0.0), ("profile_sigma_log", -0.1)],
    "timeshift": [("readout_rel", 1.0), ("refit_min_streaks", 0), ("scan_min_contrast", -1.0)],
}


def test_every_section_round_trips_through_yaml(tmp_path: Path) -> None:
    p = DetectParams(**{name: SECTIONS[name](**vals) for name, vals in CHANGED.items()})
    assert p != DetectParams()
    p.to_yaml(tmp_path / "p.yaml")
    back = DetectParams.from_yaml(tmp_path / "p.yaml")
    assert back == p
    for name, vals in CHANGED.items():
        for key, v in vals.items():
            assert getattr(getattr(back, name), key) == v
    # Sections may be partial in YAML: the rest are defaults.
    (tmp_path / "q.yaml").write_text("lines:\n  tail_min_px: .inf\n")
    q = DetectParams.from_yaml(tmp_path / "q.yaml")
    assert q.lines.tail_min_px == np.inf and q.separation == SeparationParams()


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_unknown_keys_are_refused_per_section(section: str) -> None:
    with pytest.raises(ConfigError, match=f"unknown detect {section} parameter.*: bogus"):
        DetectParams.from_dict({section: {"bogus": 1}})
    with pytest.raises(ConfigError, match=f"detect {section} parameters must be a mapping"):
        DetectParams.from_dict({section: 3})


@pytest.mark.parametrize(
    ("section", "key", "value"), [(s, k, v) for s, bad in BAD.items() for k, v in bad]
)
def test_out_of_range_values_are_refused_in_one_line(section: str, key: str, value: Any) -> None:
    with pytest.raises(ConfigError, match=rf"^detect {section}\.{key} must be ") as err:
        DetectParams.from_dict({section: {key: value}})
    assert "\n" not in str(err.value)


def test_ordered_pairs_are_checked() -> None:
    with pytest.raises(ConfigError, match="lines.tail_fraction must not exceed"):
        LinesParams(tail_fraction=0.3, lit_fraction=0.25)
    with pytest.raises(ConfigError, match="separation.reach_min_px must not exceed"):
        SeparationParams(reach_min_px=9)
    with pytest.raises(ConfigError, match="source.gyro_confirm_tol_px must not exceed"):
        SourceParams(gyro_confirm_tol_px=1.6)
    LinesParams(tail_fraction=0.25, lit_fraction=0.25)  # equal is fine
    SourceParams(gyro_confirm_tol_px=1.5)
    with pytest.raises(ConfigError, match="source.gyro_vector_tol_px must not exceed end_gate"):
        SourceParams(end_gate_px=1.4)
    with pytest.raises(ConfigError, match="source.plain_end_px must be less than end_gate"):
        SourceParams(plain_end_px=2.0)


def test_every_field_is_documented_in_its_section_and_in_the_docs() -> None:
    docs = DOCS.read_text(encoding="utf-8")
    for name, cls in SECTIONS.items():
        assert f"`{name}`" in docs
        for f in fields(cls):
            assert f"``{f.name}``" in (cls.__doc__ or ""), f"{name}.{f.name} undocumented"
            assert f"`{name}.{f.name}`" in docs, f"{name}.{f.name} missing in {DOCS.name}"


def _grid_frame(pair_gap_px: float | None = None) -> np.ndarray:
    """Twelve isolated dots' streaks, all the same 18 px line (point lights); with
    ``pair_gap_px`` also two more along one line, that far apart (one component)."""
    d = np.array([16.0, 8.0])
    curves = line_grid(12, 6, (25.0, 60.0), (48.0, 60.0), d)
    if pair_gap_px is not None:
        a = np.array([40.0, 170.0])
        b = a + d + pair_gap_px * d / np.hypot(*d)
        curves += [line(a, a + d), line(b, b + d)]
    return quantise(render_streaks((220, 320), curves, 2.0, 1.5, 0.03, 0.004, 0))


def test_moved_values_are_read_from_the_params() -> None:
    image = _grid_frame()
    p = DetectParams()
    fs = detect_frame(image, p)
    assert len(fs) == 12 and not fs.flags["merged"].any()
    # quality.merged_width (moved from frame.py): at its lower bound some dots are wider.
    tight = detect_frame(image, replace(p, quality=QualityParams(merged_width=1.0)))
    assert tight.flags["merged"].any()
    np.testing.assert_array_equal(tight.end_a, fs.end_a)  # the flag only
    # quality.shape_tol_px/rel (moved from quality.py): every streak agrees with the
    # consensus within the default tolerance, not within a hundredth of a px.
    ok = frame_quality(fs, p)[0][2]
    strict = QualityParams(shape_tol_px=0.01, shape_tol_rel=0.0)
    ok_strict = frame_quality(fs, replace(p, quality=strict))[0][2]
    assert ok.sum() >= 10 and ok_strict.sum() < ok.sum() - 5
    # lines.gap_level (moved from gaps.py): two streaks end to end, 5 px apart (their facing
    # edges dip well under 0.3 of the plateau), are cut apart at the default level and
    # stay one line at 0.05 (the template separation off: it would split them too).
    pair = _grid_frame(pair_gap_px=5.0)
    plain = replace(p, separate=False)
    assert len(detect_frame(pair, plain)) == 14
    low = replace(plain, lines=LinesParams(gap_level=0.05))
    assert len(detect_frame(pair, low)) == 13


@pytest.fixture(scope="module")
def small_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("params") / "s"
    write_synthetic_session(folder, n_frames=4, seed=4, timeshift_s=0.01)
    return folder


def test_the_orientation_and_timeshift_sections_are_read(small_session: Path) -> None:
    session = load_session(small_session)
    p = DetectParams()
    base = detect_session(session, params=p)
    assert base.summary["gyro_timeshift_status"] != "undetermined"
    assert np.abs(base.table.llr_gyro).max() > 2.0
    # Every cue clipped at +-2 instead of +-25.
    capped = replace(p, orientation=replace(p.orientation, max_cue_llr=2.0))
    got = detect_session(session, params=capped).table
    assert np.abs(got[["llr_gyro", "llr_profile", "llr_continuity"]].to_numpy()).max() <= 2.0
    # A scan whose cost must drop by more than any cost can: the shift is undetermined.
    flat = replace(p, timeshift=replace(p.timeshift, scan_min_contrast=1e12))
    assert detect_session(session, params=flat).summary["gyro_timeshift_status"] == "undetermined"


def test_the_refined_gyro_sigma_may_not_exceed_the_unrefined() -> None:
    with pytest.raises(ConfigError, match="orientation.gyro_sigma_rel_refined must not exceed"):
        DetectParams.from_dict({"orientation": {"gyro_sigma_rel_refined": 0.5}})


def test_numbers_with_an_exponent_are_read_and_text_is_refused_by_name(tmp_path: Path) -> None:
    # YAML 1.1 reads 1e-2 as text; the parameters read it as the number it is.
    (tmp_path / "p.yaml").write_text("min_threshold: 1e-2\nsource:\n  gyro_vector_tol_px: 2e0\n")
    p = DetectParams.from_yaml(tmp_path / "p.yaml")
    assert p.min_threshold == 0.01 and p.source.gyro_vector_tol_px == 2.0
    # Text where a number belongs is refused in one line naming the parameter.
    for name in ("min_threshold", "smooth_sigma_px", "max_streaks", "psf_sigma_px"):
        with pytest.raises(ConfigError, match=rf"^detect parameter {name} must be a number") as e:
            DetectParams.from_dict({name: "1e-2x"})
        assert "\n" not in str(e.value)
    # None stays allowed where the parameter is measured instead (negative control).
    assert DetectParams.from_dict({"psf_sigma_px": None, "saturation_level": None})
