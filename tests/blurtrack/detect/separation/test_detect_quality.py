"""Shape consistency and the quality flag of the streak table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from blurtrack.detect.separation.consensus import Consensus
from blurtrack.detect.separation.quality import add_quality, one_doubt
from blurtrack.io import streaks


def _frame(n: int = 12, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    mid = rng.uniform(50, 600, (n, 2))
    # A roll about the optical axis: the start-to-end vector varies linearly over the frame.
    v = np.array([20.0, 5.0]) + (mid - 300.0) @ np.array([[0.0, 0.02], [-0.02, 0.0]])
    flip = rng.random(n) < 0.4  # start/end swapped on some: not a shape error
    v[flip] *= -1
    return _table(mid, v)


def _table(mid: np.ndarray, v: np.ndarray, width_px: float = 1.8) -> pd.DataFrame:
    """One frame's unflagged, unsaturated point-light streaks with time midpoints ``mid`` and
    start-to-end vectors ``v`` (``(N, 2)`` px)."""
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
            "width_px": width_px,
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


def _strokes(n_agree: int, n_other: int, seed: int = 1) -> pd.DataFrame:
    """``n_agree`` streaks drawing one vector, and ``n_other`` of a sign's strokes: lines of
    every direction and length, each a point light's width."""
    d = _frame(n=n_agree + n_other, seed=seed)
    rng = np.random.default_rng(seed)
    ang = np.linspace(0.0, np.pi, n_other, endpoint=False) + 0.3
    length = rng.uniform(15.0, 60.0, n_other)
    v = np.column_stack([np.cos(ang), np.sin(ang)]) * length[:, None]
    rows = np.arange(n_agree, n_agree + n_other)
    mid = d.loc[rows, ["mid_x", "mid_y"]].to_numpy()
    d.loc[rows, ["start_x", "start_y"]] = mid - v / 2
    d.loc[rows, ["end_x", "end_y"]] = mid + v / 2
    return d


def test_a_field_few_streaks_agree_with_is_no_consensus() -> None:
    # A sign of strokes, each drawn as thin as a point light's streak: the robust fit returns
    # a field, but only the streaks that agree with it make a consensus. Four agreeing (one
    # under the fewest voters) among twelve other strokes: nothing is quality_ok, and the
    # shape deviation is not reported.
    q = add_quality(_strokes(n_agree=4, n_other=12))
    assert not q.quality_ok.any()
    assert set(q.reason) == {"ends_unsure"}
    assert q["shape_deviation_px"].isna().all()
    # Negative control: five agreeing (the fewest voters) among the same strokes make one;
    # those five are ok and the strokes are off it.
    q = add_quality(_strokes(n_agree=5, n_other=12))
    assert q.quality_ok.tolist() == [True] * 5 + [False] * 12
    assert set(q.reason[5:]) <= {"chained", "fragment", "ends_unsure"}


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
    from blurtrack.detect.separation.consensus import consensus_field

    d = _roll_frame()
    v = d[["end_x", "end_y"]].to_numpy(float) - d[["start_x", "start_y"]].to_numpy(float)
    mid = d[["mid_x", "mid_y"]].to_numpy(float)
    voters = np.ones(len(d), bool)
    old = consensus_field(v, mid, voters, QualityParams())
    new = consensus_field(v, mid, voters, QualityParams(), resign=True)
    assert old is not None and new is not None
    assert np.max(old.dev) > 3.0 and np.max(new.dev) < 1e-6


def test_later_starts_are_tried_only_where_a_voter_disagrees(monkeypatch) -> None:
    # Where the first start's field holds every voter no later start can win (it must do
    # strictly better): the neighbours' signs are not propagated. The roll frame needs them.
    from blurtrack.detect.params import QualityParams
    from blurtrack.detect.separation import consensus

    calls: list[int] = []
    real = consensus._propagated_signs

    def counted(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(consensus, "_propagated_signs", counted)
    d = _frame(14)
    v = d[["end_x", "end_y"]].to_numpy(float) - d[["start_x", "start_y"]].to_numpy(float)
    mid = d[["mid_x", "mid_y"]].to_numpy(float)
    field = consensus.consensus_field(v, mid, np.ones(len(d), bool), QualityParams(), resign=True)
    assert field is not None and np.max(field.dev) < 1e-6 and not calls
    r = _roll_frame()
    v = r[["end_x", "end_y"]].to_numpy(float) - r[["start_x", "start_y"]].to_numpy(float)
    mid = r[["mid_x", "mid_y"]].to_numpy(float)
    field = consensus.consensus_field(v, mid, np.ones(len(r), bool), QualityParams(), resign=True)
    assert field is not None and np.max(field.dev) < 1e-6 and calls == [1]


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


def _prim_reference(mid: np.ndarray, v: np.ndarray) -> tuple[list[int], list[int]]:
    """Prim's algorithm written out plainly: the order the nodes join from node 0 and each
    one's parent (the cheapest node already in the tree, the first of equals), an edge's
    cost its squared distance over what the pair says of the sign (the shorter vector's
    length times the cosine between them)."""
    n = len(mid)
    d2 = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            says = abs(float(v[i] @ v[j])) / max(np.hypot(*v[i]), np.hypot(*v[j]), 1e-9)
            d2[i, j] = float(np.sum((mid[i] - mid[j]) ** 2)) / max(says, 1e-6)
    inside = [0]
    order, parent = [], []
    while len(inside) < n:
        best = (np.inf, -1, -1)
        for j in range(n):
            if j in inside:
                continue
            for i in inside:
                if d2[i, j] < best[0] or (d2[i, j] == best[0] and j < best[1]):
                    best = (d2[i, j], j, i)
        order.append(best[1])
        parent.append(best[2])
        inside.append(best[1])
    return order, parent


def test_propagated_signs_follow_the_minimum_spanning_tree() -> None:
    from blurtrack.detect.separation.consensus import _propagated_signs

    rng = np.random.default_rng(5)
    for _trial in range(20):
        n = int(rng.integers(2, 40))
        mid = rng.uniform(0, 500, (n, 2))
        v = rng.normal(0, 10, (n, 2))
        voters = np.ones(n, bool)
        order, parent = _prim_reference(mid, v)
        want = np.ones(n)
        for k, j in zip(order, parent, strict=True):
            want[k] = -want[j] if v[k] @ v[j] < 0 else want[j]
        got = _propagated_signs(v, mid, voters)[:, 0]
        np.testing.assert_array_equal(got, want)
    # Known value: a row of vectors alternating in sign, each nearest its neighbours: all
    # turned to the first's direction; a non-voter takes its nearest voter's.
    mid = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0], [21.0, 1.0]])
    v = np.array([[5.0, 1.0], [-5.0, -1.0], [5.0, 1.2], [-4.0, -1.0], [-5.0, -1.0]])
    voters = np.array([True, True, True, True, False])
    signs = _propagated_signs(v, mid, voters)[:, 0]
    assert signs.tolist() == [1.0, -1.0, 1.0, -1.0, -1.0]
    assert np.all((v * signs[:, None]) @ v[0] > 0)


def _turning_frame_with_specks() -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """A strong roll: 10 px streaks on a 60 px grid whose vectors turn by 120 degrees across
    the frame, each drawn A-to-B either way; 4 px beside each a 0.6 px streak of random
    direction (a speck), nearer to it than any other streak. Returns the vectors, the time
    midpoints, the true field (``(N, 2)``, its sign) and the number of long streaks (first)."""
    rng = np.random.default_rng(0)
    xs, ys = np.meshgrid(np.arange(60, 1240, 60.0), np.arange(60, 700, 60.0))
    mid_long = np.column_stack([xs.ravel(), ys.ravel()])
    ang = np.deg2rad(-60 + 120 * (mid_long[:, 0] - 60) / 1180)
    field = 10 * np.column_stack([np.cos(ang), np.sin(ang)])
    v_long = np.where(rng.random(len(field))[:, None] < 0.5, -field, field)
    a = rng.uniform(0, 2 * np.pi, len(field))
    v_speck = 0.6 * np.column_stack([np.cos(a), np.sin(a)])
    mid = np.concatenate([mid_long, mid_long + np.array([4.0, 0.0])])
    return np.concatenate([v_long, v_speck]), mid, np.concatenate([field, field]), len(field)


def test_specks_between_streaks_do_not_carry_the_sign() -> None:
    """``dense`` 6's frame 7 in small (journal "The predicted curves from a tabulated
    orientation": its field's propagated start lost half its voters after a 0.04 ms change of
    the session's time shift). Each streak's nearest voter is a sub-pixel speck of random
    direction, yet the signs propagated agree with the true field on every long streak (one
    sign for the whole field). Negative control: the same tree by distance alone signs some
    long streaks against the field, through their specks."""
    from blurtrack.detect.separation.consensus import _propagated_signs

    v, mid, field, n = _turning_frame_with_specks()
    voters = np.ones(len(v), bool)
    d2 = np.sum((mid[:n, None] - mid[None]) ** 2, axis=2)
    np.fill_diagonal(d2[:, :n], np.inf)
    assert np.all(np.argmin(d2, axis=1) >= n)  # every long streak's nearest is its speck

    def split(signs: np.ndarray) -> int:  # long streaks on the minority side of the field
        agree = np.sum(v[:n] * signs[:n, None] * field[:n], axis=1) > 0
        return int(min(agree.sum(), (~agree).sum()))

    assert split(_propagated_signs(v, mid, voters)[:, 0]) == 0
    # The tree by distance alone (unique for these distances), signs carried from node 0.
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    tree = minimum_spanning_tree(np.sqrt(np.sum((mid[:, None] - mid[None]) ** 2, axis=2)))
    order, parent = breadth_first_order(tree, 0, directed=False)
    by_distance = np.ones(len(v))
    for k in order[1:]:
        j = parent[k]
        by_distance[k] = -by_distance[j] if v[k] @ v[j] < 0 else by_distance[j]
    assert split(by_distance) > 10


def test_robust_affine_stops_at_a_fixed_point_with_the_rounds_result() -> None:
    """Stopping when a round keeps the very voters it started from gives what all five
    rounds give (each later round refits the same voters)."""
    from blurtrack.detect.separation.consensus import _robust_affine

    def all_rounds(X, vs, voters, start, min_reference):
        use = start.copy()
        coef = np.linalg.lstsq(X[use], vs[use], rcond=None)[0]
        for _ in range(5):
            coef = np.linalg.lstsq(X[use], vs[use], rcond=None)[0]
            r = np.hypot(*(vs - X @ coef).T)
            cut = max(3.0 * float(np.median(r[use])), 0.5)
            new = voters & (r <= cut)
            if int(new.sum()) < min_reference:
                break
            use = new
        return coef, use

    rng = np.random.default_rng(11)
    for _trial in range(40):
        n = int(rng.integers(6, 80))
        mid = rng.uniform(0, 1000, (n, 2))
        X = np.column_stack([np.ones(n), (mid - mid.mean(axis=0)) / 100.0])
        vs = X @ rng.normal(0, 5, (3, 2)) + rng.normal(0, 0.3, (n, 2))
        bad = rng.random(n) < 0.2  # chains and strays: far off the field
        vs[bad] += rng.normal(0, 30, (int(bad.sum()), 2))
        voters = rng.random(n) < 0.9
        start = voters & (rng.random(n) < 0.8)
        if start.sum() < 3:
            continue
        want = all_rounds(X, vs, voters, start, 5)
        got = _robust_affine(X, vs, voters, start, 5)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])


#: Start-to-end vectors and time midpoints (px) of the lines that vote in a real shaken night
#: photograph of a facade (LEDNet's ``230_blur_21.png``, not in this repository): lit window
#: bands and lines joining them, no point light. An affine field bends to them.
FACADE_V = np.array(
    [[16.63, 5.4], [16.84, 5.39], [-8.85, 25.38], [0.38, 0.12], [-10.44, 47.97], [15.6, 1.96],
     [14.8, 10.72], [-2.85, -12.14], [25.14, 6.12], [63.06, 1.6], [18.71, 12.22],
     [-13.35, 7.49]]
)  # fmt: skip
FACADE_MID = np.array(
    [[110.8, 7.0], [111.1, 36.6], [651.4, 59.8], [200.8, 65.1], [646.8, 109.7], [282.4, 209.8],
     [232.5, 215.5], [306.7, 229.6], [311.0, 230.6], [586.9, 235.8], [235.1, 248.0],
     [477.1, 273.6]]
)  # fmt: skip


def _field_without(v: np.ndarray, mid: np.ndarray, rows: np.ndarray, i: int) -> np.ndarray:
    """Derived truth: the least-squares affine field over ``rows`` less ``i``, at ``i``."""
    keep = rows[rows != i]
    X = np.column_stack([np.ones(len(mid)), mid])
    return X[i] @ np.linalg.lstsq(X[keep], v[keep], rcond=None)[0]


def _fields_in_and_out(
    n: int, seed: int, noise_px: float
) -> tuple[np.ndarray, np.ndarray, Consensus, Consensus]:
    """``_frame(n, seed)``'s vectors with Gaussian noise of ``noise_px``, their midpoints and
    the consensus fitted to all of them, without and with the held-out deviations."""
    from blurtrack.detect.params import QualityParams
    from blurtrack.detect.separation.consensus import consensus_field

    d = _frame(n, seed=seed)
    v = d[["end_x", "end_y"]].to_numpy(float) - d[["start_x", "start_y"]].to_numpy(float)
    v += np.random.default_rng(seed).normal(0.0, noise_px, v.shape)
    mid = d[["mid_x", "mid_y"]].to_numpy(float)
    voters = np.ones(len(d), bool)
    inside = consensus_field(v, mid, voters, QualityParams(), resign=True)
    held = consensus_field(v, mid, voters, QualityParams(), resign=True, held_out=True)
    assert inside is not None and held is not None
    return v, mid, inside, held


def test_held_out_deviation_is_that_from_the_field_of_the_others() -> None:
    v, mid, inside, held = _fields_in_and_out(9, seed=4, noise_px=0.8)
    assert np.array_equal(inside.use, held.use) and held.use.sum() >= 7
    assert inside.dev_held_out is None and held.dev_held_out is not None
    np.testing.assert_array_equal(held.dev, inside.dev)  # the field itself is as it was
    rows = np.flatnonzero(held.use)
    for i in rows:  # each one's deviation from the others' field, either sign
        g = _field_without(v * np.sign(v @ held.c[i])[:, None], mid, rows, i)
        assert held.dev_held_out[i] == pytest.approx(np.hypot(*(v[i] - g)), abs=1e-9)
    # Left out, each one is further from the field than inside it (the fit pulled towards it).
    assert np.all(held.dev_held_out[rows] > held.dev[rows] * 1.1)


def test_a_facades_lines_make_a_consensus_only_with_their_own_votes() -> None:
    from blurtrack.detect.params import QualityParams
    from blurtrack.detect.separation.consensus import consensus_field, shape_tolerance

    q = QualityParams()
    voters = np.ones(len(FACADE_V), bool)
    held = consensus_field(FACADE_V, FACADE_MID, voters, q, resign=True, held_out=True)
    assert held is not None

    tol = shape_tolerance(held.c, q)
    assert held.dev_held_out is not None
    # Negative control: with their own votes, enough of them agree for a consensus.
    assert int(np.sum(held.dev <= tol)) >= q.min_reference
    assert int(np.sum(held.dev_held_out <= tol)) < q.min_reference
    assert not add_quality(_table(FACADE_MID, FACADE_V, width_px=2.5)).quality_ok.any()


def test_many_voters_see_the_same_field_left_out() -> None:
    _, _, inside, held = _fields_in_and_out(300, seed=5, noise_px=0.5)
    assert held.dev_held_out is not None
    # Leverage ~3/300: the deviations differ by about a percent, never more than a few.
    assert np.all(held.dev_held_out <= inside.dev * 1.06 + 1e-9)
    assert np.median(held.dev_held_out / inside.dev) < 1.02
