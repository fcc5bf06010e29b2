"""Shape consistency and the quality flag of the streak table."""

from __future__ import annotations

import numpy as np
import pandas as pd

from blurtrack.detect.separation.quality import add_quality, one_doubt
from blurtrack.io import streaks


def _frame(n: int = 12, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    mid = rng.uniform(50, 600, (n, 2))
    # A roll about the optical axis: the start-to-end vector varies linearly over the frame.
    v = np.array([20.0, 5.0]) + (mid - 300.0) @ np.array([[0.0, 0.02], [-0.02, 0.0]])
    flip = rng.random(n) < 0.4  # start/end swapped on some: not a shape error
    v[flip] *= -1
    start, end = mid - v / 2, mid + v / 2
    return pd.DataFrame(
        {
            "frame": 0,
            "start_x": start[:, 0],
            "start_y": start[:, 1],
            "end_x": end[:, 0],
            "end_y": end[:, 1],
            "mid_x": mid[:, 0],
            "mid_y": mid[:, 1],
            "clipped": False,
            "merged": False,
            "crossing": False,
            "looped": False,
            "saturated": False,
            "width_px": 1.8,
            "source": "point",
        }
    )


def test_consistent_shapes_are_ok_and_an_odd_one_is_not() -> None:
    d = _frame()
    d.loc[3, ["end_x", "end_y"]] = d.loc[3, ["start_x", "start_y"]].to_numpy() + np.array(
        [5.0, 30.0]
    )
    d.loc[5, "saturated"] = True
    d.loc[5, "width_px"] = 5.0
    q = add_quality(d)
    dev = q["shape_deviation_px"].to_numpy()
    assert np.all(np.delete(dev, [3, 5]) < 1e-6)
    assert dev[3] > 20
    assert not q.quality_ok[3] and not q.quality_ok[5] and q.thick_saturated[5]
    assert q.quality_ok.sum() == len(d) - 2
    assert q.reason[3] == "chained" and q.reason[5] == "ends_unsure"
    assert set(q.reason.drop(index=[3, 5])) == {"ok"}


def test_a_saturated_core_alone_is_not_disqualifying() -> None:
    d = _frame()
    d.loc[[2, 4], "saturated"] = True  # as wide as the others: its ends are measured well
    q = add_quality(d)
    assert q.quality_ok.all() and set(q.reason) == {"ok"}


def test_without_image_evidence_nothing_is_ok() -> None:
    """A table without the ``source`` column (built without the image): every streak is
    ``undetermined`` and none ``quality_ok``; an extended one neither (negative control: the
    same frame with point sources is ok, test above)."""
    d = _frame().drop(columns=["source"])
    q = add_quality(d)
    assert not q.quality_ok.any() and set(q.source) == {"undetermined"}
    assert set(q.reason) == {"ends_unsure"}
    e = _frame()
    e.loc[[1, 7], "source"] = "extended"
    q = add_quality(e)
    assert q.reason[1] == q.reason[7] == "extended" and not q.quality_ok[[1, 7]].any()
    assert q.quality_ok.sum() == len(e) - 2


def test_too_few_streaks_give_no_consensus_and_nothing_is_ok() -> None:
    # Three point lights cannot tell a dot's blur from a highlight or an edge: no consensus,
    # so nothing is quality_ok (the unflagged ones' ends are unsure, the gyro may confirm
    # them); with one streak more than the fewest voters, the same frame has its consensus.
    d = _frame(n=3)
    d.loc[1, "clipped"] = True
    q = add_quality(d)
    assert q["shape_deviation_px"].isna().all()
    assert not q.quality_ok.any()
    assert q.reason.tolist() == ["ends_unsure", "clipped", "ends_unsure"]
    d = _frame(n=6)
    d.loc[1, "clipped"] = True
    q = add_quality(d)
    assert q["shape_deviation_px"].notna().sum() == 6
    assert q.quality_ok.tolist() == [True, False, True, True, True, True]


def test_usable_falls_back_to_flags_for_older_tables() -> None:
    d = pd.DataFrame({"clipped": [False, True, False], "merged": [False, False, True]})
    assert streaks.usable(d).tolist() == [True, False, False]
    d["quality_ok"] = [False, False, True]
    assert streaks.usable(d).tolist() == [False, False, True]


def _roll_frame(n: int = 40, seed: int = 1) -> pd.DataFrame:
    """A strong roll about a point inside the frame: the vectors point every way (derived:
    ``v = omega x (mid - centre)``), each start/end swapped at random."""
    d = _frame(n, seed)
    mid = d[["mid_x", "mid_y"]].to_numpy(float)
    r = mid - 320.0
    v = 0.12 * np.column_stack([-r[:, 1], r[:, 0]])
    v[np.random.default_rng(seed).random(n) < 0.5] *= -1
    d[["start_x", "start_y"]] = mid - v / 2
    d[["end_x", "end_y"]] = mid + v / 2
    return d


def test_a_strong_roll_keeps_its_streaks_ok() -> None:
    d = _roll_frame()
    q = add_quality(d)
    assert np.all(q["shape_deviation_px"].to_numpy() < 1e-6)
    assert q.quality_ok.all()
    # Negative control: one end 8 px off along the streak (a neighbour's light): not ok.
    v = d.loc[7, ["end_x", "end_y"]].to_numpy(float) - d.loc[7, ["start_x", "start_y"]].to_numpy(
        float
    )
    d.loc[7, ["end_x", "end_y"]] += 8.0 * v / np.hypot(*v)
    q = add_quality(d)
    assert not q.quality_ok[7] and q.reason[7] == "chained"
    assert q.quality_ok.drop(index=7).all()


def test_one_axis_signs_split_a_strong_roll() -> None:
    # The control for the re-signing: with the dominant axis's signs only (what separation
    # uses) the same field is not found.
    from blurtrack.detect.params import QualityParams
    from blurtrack.detect.separation.quality import consensus_field

    d = _roll_frame()
    v = d[["end_x", "end_y"]].to_numpy(float) - d[["start_x", "start_y"]].to_numpy(float)
    mid = d[["mid_x", "mid_y"]].to_numpy(float)
    voters = np.ones(len(d), bool)
    old = consensus_field(v, mid, voters, QualityParams())
    new = consensus_field(v, mid, voters, QualityParams(), resign=True)
    assert old is not None and new is not None
    assert np.max(old.dev) > 3.0 and np.max(new.dev) < 1e-6


def test_a_saturated_frame_measures_the_dot_width_on_all_its_streaks() -> None:
    # Every streak saturated (width measured on the flanks, 2.0) but two faint ones (1.0):
    # two widths do not say the dot's width, so none is thick.
    d = _frame(14)
    d["saturated"] = True
    d["width_px"] = 2.0
    d.loc[[0, 1], ["saturated", "width_px"]] = [False, 1.0]
    q = add_quality(d)
    assert not q.thick_saturated.any() and q.quality_ok.all()
    # Negative controls: a blown-out core twice as wide as the frame's streaks is thick; and
    # with five unsaturated widths (1.0) to go by, every 2.1 px saturated streak is.
    d.loc[6, "width_px"] = 5.0
    q = add_quality(d)
    assert q.thick_saturated[6] and q.reason[6] == "ends_unsure"
    assert q.thick_saturated.sum() == 1
    d.loc[[0, 1, 2, 3, 4], ["saturated", "width_px"]] = [False, 1.0]
    d.loc[d.saturated, "width_px"] = 2.1
    q = add_quality(d)
    assert q.thick_saturated[d.saturated.to_numpy()].all()


def test_one_doubt_counts_each_doubt_of_an_eligible_streak() -> None:
    eligible = np.array([True, True, True, True, False])
    crossing = np.array([True, False, True, False, True])
    lit = np.array([False, True, True, False, False])
    thick = np.array([False, False, True, False, False])
    # 0: a crossing alone; 1: a lit end; 2: a crossing, a lit end and a blown-out core (two
    # doubts besides the crossing); 3: none; 4: not eligible.
    got = one_doubt(eligible, [lit, thick], crossing)
    assert got.tolist() == [True, True, False, False, False]
    # The crossing does not count against the one doubt: with it, a lit end stays one.
    assert one_doubt(eligible, [lit], crossing).tolist() == [True, True, True, False, False]
    no = np.zeros(5, bool)
    assert not one_doubt(eligible, [no], no).any()  # no doubt: nothing to lift
