"""The streak table's fast paths give what the plain ones give: the Parquet file built from
flat buffers is byte for byte the one ``DataFrame.to_parquet`` writes from lists, and the
array-based quality columns equal a per-frame DataFrame computation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.detect.params import QualityParams
from blurtrack.detect.separation import consensus, quality
from blurtrack.detect.session.pipeline import detect_session
from blurtrack.detect.session.table import read_table, to_arrow, write_table
from blurtrack.io import streaks
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session


@pytest.fixture(scope="module")
def table(tmp_path_factory: pytest.TempPathFactory) -> pd.DataFrame:
    folder = tmp_path_factory.mktemp("tablefast") / "s"
    write_synthetic_session(folder, n_frames=3, seed=7)
    return detect_session(load_session(folder)).table


def _as_lists(df: pd.DataFrame) -> pd.DataFrame:
    """The table as earlier versions built it: list cells of Python floats."""
    out = df.copy()
    for c in ("centerline", "profile"):
        out[c] = pd.Series([np.asarray(v).tolist() for v in out[c]], dtype=object)
    return out


def test_cells_are_the_rounded_lines(table: pd.DataFrame) -> None:
    assert len(table) > 10
    for cl, pr in zip(table["centerline"], table["profile"], strict=True):
        assert cl.shape == (len(pr), 2) and cl.dtype == pr.dtype == np.float64
        np.testing.assert_array_equal(cl, np.round(cl, 4))
        np.testing.assert_array_equal(pr, np.round(pr, 6))


def test_parquet_bytes_equal_the_pandas_writer(table: pd.DataFrame, tmp_path: Path) -> None:
    fast, plain = tmp_path / "fast.parquet", tmp_path / "plain.parquet"
    write_table(table, fast)
    streaks.write(_as_lists(table), plain)
    assert fast.read_bytes() == plain.read_bytes()
    back = read_table(str(fast))
    assert len(back) == len(table)
    for a, b in zip(back["centerline"], table["centerline"], strict=True):
        np.testing.assert_array_equal(np.stack(list(a)), b)
    # Negative control: one coordinate moved by the last kept decimal changes the file.
    moved = _as_lists(table)
    moved.at[3, "centerline"] = [
        [x + 1e-4 * (i == 0), y] for i, (x, y) in enumerate(moved.at[3, "centerline"])
    ]
    streaks.write(moved, tmp_path / "moved.parquet")
    assert (tmp_path / "moved.parquet").read_bytes() != plain.read_bytes()


def test_only_repeating_columns_are_dictionary_encoded(table: pd.DataFrame, tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    write_table(table, tmp_path / "t.parquet")
    meta = pq.ParquetFile(tmp_path / "t.parquet").metadata.row_group(0)
    enc = {
        meta.column(i).path_in_schema.split(".")[0]: set(meta.column(i).encodings)
        for i in range(meta.num_columns)
    }
    dictionary = {c for c, e in enc.items() if {"PLAIN_DICTIONARY", "RLE_DICTIONARY"} & e}
    assert dictionary == set(streaks.DICTIONARY_COLUMNS)
    assert {"start_x", "centerline", "profile"} <= set(enc) - dictionary
    # Negative control: pyarrow's default tries the float columns too.
    pq.write_table(to_arrow(table), tmp_path / "d.parquet", compression="snappy")
    meta = pq.ParquetFile(tmp_path / "d.parquet").metadata.row_group(0)
    default = {
        meta.column(i).path_in_schema.split(".")[0]
        for i in range(meta.num_columns)
        if {"PLAIN_DICTIONARY", "RLE_DICTIONARY"} & set(meta.column(i).encodings)
    }
    assert {"start_x", "centerline"} <= default
    back = read_table(str(tmp_path / "t.parquet"))
    pd.testing.assert_frame_equal(
        back.drop(columns=["centerline", "profile"]),
        table.drop(columns=["centerline", "profile"]),
    )


def test_list_cells_take_the_general_path(table: pd.DataFrame) -> None:
    lists = _as_lists(streaks.validate(table))
    assert to_arrow(lists).equals(to_arrow(streaks.validate(table)), check_metadata=True)


#: The quality section's defaults (the table's quality columns are computed with them).
Q = QualityParams()


def _quality_reference(table: pd.DataFrame) -> pd.DataFrame:
    """Per frame, from that frame's DataFrame rows (the definition in quality's docstring)."""
    out = table.copy()
    dev = np.full(len(out), np.nan)
    thick = np.zeros(len(out), bool)
    ok = np.zeros(len(out), bool)
    for _, d in out.groupby("frame", sort=False):
        rows = d.index.to_numpy()
        v = d[["end_x", "end_y"]].to_numpy(float) - d[["start_x", "start_y"]].to_numpy(float)
        flagged = (d["clipped"] | d["merged"] | d["crossing"] | d["looped"]).to_numpy(bool)
        width = d["width_px"].to_numpy(float)
        sat = d["saturated"].to_numpy(bool)
        ref = width[~sat & np.isfinite(width)]
        ref = ref if ref.size else width[np.isfinite(width)]
        w0 = float(np.median(ref)) if ref.size else np.nan
        with np.errstate(invalid="ignore"):
            th = sat & (width > Q.thick_width_ratio * w0)
        point = (d["source"] == "point").to_numpy(bool)
        light = d[["end_light_start", "end_light_end"]].to_numpy(float)
        with np.errstate(invalid="ignore"):
            lit = (light > quality.SourceParams().end_light_max).any(axis=1)
        good = ~(flagged | th) & point
        voters = good.copy()
        mid = d[["mid_x", "mid_y"]].to_numpy(float)
        field = consensus.consensus_field(v, mid, voters, Q, resign=True, held_out=True)
        good &= ~(lit | np.isnan(light).any(axis=1))
        if field is not None:
            tol = consensus.shape_tolerance(field.c, Q)
            assert field.dev_held_out is not None
            if np.sum(voters & (field.dev_held_out <= tol)) < Q.min_reference:
                field = None  # too few voters agree with the others' field: no consensus
        if field is not None:
            dev[rows] = field.dev
            good = good & (field.dev <= consensus.shape_tolerance(field.c, Q))
        else:
            good[:] = False
        thick[rows], ok[rows] = th, good
    out["shape_deviation_px"], out["thick_saturated"], out["quality_ok"] = dev, thick, ok
    return out


def test_workers_quality_is_the_tables_whatever_the_orientation(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_synthetic_session(folder, n_frames=3, seed=11)
    res = detect_session(load_session(folder))
    assert all(fs.quality is not None for fs in res.frames)  # the workers' columns were used
    cols = ["shape_deviation_px", "thick_saturated", "quality_ok"]
    ref = quality.add_quality(res.table.drop(columns=cols))
    assert np.isfinite(ref["shape_deviation_px"]).sum() > 10
    for c in cols:
        np.testing.assert_array_equal(res.table[c].to_numpy(), ref[c].to_numpy())
    # The frame's columns do not depend on which end is A (half the streaks reversed) ...
    fs = res.frames[0]
    before, single = quality.frame_quality(fs)
    fs.reverse(np.arange(len(fs)) % 2 == 0)
    after, single_after = quality.frame_quality(fs)
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(single, single_after)
    # ... but on its shapes (negative control: one streak's end moved).
    fs.end_b[1] += [25.0, 0.0]
    assert quality.frame_quality(fs)[0][0][1] > before[0][1] + 10


def test_quality_columns_equal_the_per_frame_definition(table: pd.DataFrame) -> None:
    base = table.drop(columns=["shape_deviation_px", "thick_saturated", "quality_ok", "reason"])
    fast = quality.add_quality(base)
    ref = _quality_reference(base)
    assert np.isfinite(fast["shape_deviation_px"]).sum() > 10
    for c in ("shape_deviation_px", "thick_saturated", "quality_ok"):
        np.testing.assert_array_equal(fast[c].to_numpy(), ref[c].to_numpy())
    # Negative control: a streak bent far from its frame's consensus changes its columns.
    bent = base.copy()
    k = int(np.flatnonzero(fast["quality_ok"].to_numpy())[0])
    bent.loc[k, "end_x"] += 25.0
    moved = quality.add_quality(bent)
    assert moved.loc[k, "shape_deviation_px"] > fast.loc[k, "shape_deviation_px"] + 10
    assert not moved.loc[k, "quality_ok"]
