"""Every real recording and photograph in ``../shared/data/real`` through the commands a user
runs, as one table (issue 44, item 5; docs/real-data.md).

For each item the user's commands run in-process (``blurtrack.cli.main``) in a temporary work
folder outside the data folder; the table gives what was asked, what came out (calibrated, or
refused with the command's one-line error), the figures read from the written summary JSON
files and the pictures written. The phone video is also calibrated from its two halves apart
(frames 100-125 and 126-151, temporary layouts of symlinks) to see whether the time offset and
the readout agree within 2 sigma, and from its frames turned by 180 degrees (rows read bottom
to top) to see which readout direction the images choose. The light-streak photographs have no
gyro: they run ``bench/real_streaks.py``'s measurement.

    PYTHONPATH=$PWD .venv/bin/python bench/real_data.py [--quick] [--out DIR] [--json FILE]

``--quick``: the phone video only (import + calibrate), no halves (the test's form). ``--out``:
where the pictures go (default: a temporary folder, removed at the end). Prints the markdown
table, then the JSON document (also written to ``--json``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from json_out import emit  # noqa: E402

from blurtrack.cli import main as blurtrack_main  # noqa: E402

REAL = REPO.parent / "shared" / "data" / "real"
PHONE_INTRINSICS = "573.85,575.04,406.01,309.01"
PHONE_EXPOSURE_MS = "5.1"
#: The phone video's halves, by frame file number (inclusive).
HALVES = ((100, 125), (126, 151))
OVERLAYS = 2


def run_cli(argv: list[str]) -> dict[str, Any]:
    """``blurtrack ARGV`` in this process: exit code, wall seconds and, when it fails, the
    one-line error it printed (``blurtrack CMD: error: ...``, the prefix dropped)."""
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = blurtrack_main(argv)
        except SystemExit as exc:  # argparse refuses its arguments
            rc = exc.code if isinstance(exc.code, int) else 2
    rec: dict[str, Any] = {
        "command": "blurtrack " + " ".join(argv),
        "rc": rc,
        "wall_s": time.perf_counter() - t0,
    }
    if rc != 0:
        lines = [ln for ln in err.getvalue().splitlines() if ": error: " in ln]
        last = lines[-1] if lines else (err.getvalue().strip().splitlines() or ["?"])[-1]
        rec["error"] = last.split(": error: ", 1)[-1]
    return rec


def shown(argv: list[str], work: Path) -> str:
    """A command as the table shows it: data paths relative to the project, work paths short."""
    text = "blurtrack " + " ".join(argv)
    return text.replace(str(REAL), "../shared/data/real").replace(str(work) + "/", "")


def agree(a: float, sa: float, b: float, sb: float) -> bool:
    """|a - b| <= 2 sqrt(sa^2 + sb^2)."""
    return abs(a - b) <= 2.0 * math.hypot(sa, sb)


def calib_figures(out_yaml: Path) -> dict[str, Any]:
    """Figures of ``calibrate --out out_yaml`` from the summary it wrote (ok or failed)."""
    path = out_yaml.with_name(out_yaml.stem + ".summary.json")
    if not path.is_file():
        path = out_yaml.with_name(out_yaml.stem + ".failed.summary.json")
    if not path.is_file():
        return {}
    d = json.loads(path.read_text())
    v, s = d.get("values", {}), d.get("sigma", {})
    fig: dict[str, Any] = {"summary": path.name, "status": d.get("status")}
    axes = d.get("axes") or {}
    if axes:
        fig["axes_winner"] = (axes.get("winner") or {}).get("R_cam_imu")
        fig["axes_margin"] = axes.get("margin")
        fig["axes_score_px"] = (axes.get("winner") or {}).get("score_px")
    for key in ("timeshift_s", "readout_s"):
        if key in v:
            fig[key.replace("_s", "_ms")] = 1e3 * v[key]
            fig[key.replace("_s", "_sigma_ms")] = 1e3 * s[key] if s.get(key) is not None else None
    for key in ("fx", "fy", "cx", "cy"):
        if key in v:
            fig[key] = v[key]
    hold = d.get("holdout_inliers") or {}
    fig["holdout_median_px"] = hold.get("median_px")
    fig["holdout_n"] = hold.get("n")
    feats = d.get("features") or {}
    fig["tracks"] = feats.get("tracks")
    fig["track_pairs_median"] = feats.get("per_pair_median")
    fig["inliers"] = (d.get("train_inliers") or {}).get("n")
    fig["outliers"] = d.get("n_outliers")
    fig["translation"] = (d.get("translation") or {}).get("mode")
    fig["axes_model"] = ((axes.get("decision") or {}).get("model")) or "rotation"
    fig["translation_starts"] = (d.get("translation") or {}).get("starts_tried")
    err = d.get("error_vs_truth")
    if err:
        fig["error_vs_truth_ms"] = {
            k: 1e3 * err[k] for k in ("timeshift_s", "readout_s") if k in err
        }
    return fig


def import_and_calibrate(
    name: str, kind: str, src: Path, opts: list[str], work: Path, pics: Path | None
) -> dict[str, Any]:
    """``blurtrack import KIND SRC S [OPTS] --overlays N`` then ``blurtrack calibrate S --out
    calib.yaml``, timed together; the import's overlays copied to ``pics``."""
    sess, cal = work / name / "S", work / name / "calib.yaml"
    sess.parent.mkdir(parents=True, exist_ok=True)
    argv_i = ["import", kind, str(src), str(sess), *opts, "--overlays", str(OVERLAYS)]
    argv_c = ["calibrate", str(sess), "--out", str(cal)]
    t0 = time.perf_counter()
    steps = [run_cli(argv_i)]
    if steps[0]["rc"] == 0:
        steps.append(run_cli(argv_c))
    rec: dict[str, Any] = {
        "item": name,
        "commands": [shown(a, work) for a in (argv_i, argv_c)[: len(steps)]],
        "steps": steps,
        "wall_s": time.perf_counter() - t0,
    }
    failed = next((s for s in steps if s["rc"] != 0), None)
    rec["outcome"] = "calibrated" if failed is None else f"refused: {failed.get('error')}"
    summ = sess / "summary.json"
    if summ.is_file():
        imp = json.loads(summ.read_text())
        rec["import"] = {
            "frames": imp.get("frames"),
            "gyro_samples": imp.get("gyro_samples"),
            "overlays_skipped": (imp.get("overlays") or {}).get("skipped"),
        }
        rec["pictures"] = copy_pictures(
            [Path(p) for p in (imp.get("overlays") or {}).get("written", [])], pics, name, work
        )
    if len(steps) == 2:
        rec["figures"] = calib_figures(cal)
    return rec


def copy_pictures(paths: list[Path], pics: Path | None, prefix: str, work: Path) -> list[str]:
    """Copy pictures to ``pics`` as ``<prefix>_<name>``; their new paths (without ``pics``:
    their paths relative to the temporary work folder, which is removed at the end)."""
    if pics is None:
        return [str(p.relative_to(work)) for p in paths]
    pics.mkdir(parents=True, exist_ok=True)
    out = []
    for p in paths:
        dst = pics / f"{prefix}_{p.name}"
        shutil.copyfile(p, dst)
        out.append(str(dst))
    return out


def phone_half_layout(src: Path, dst: Path, first: int, last: int) -> Path:
    """A copy of the phone video's layout holding frames ``first..last`` only: symlinks to the
    images, the same framestamp.txt and gyro.txt (frame k takes line k by its file number)."""
    (dst / "frames").mkdir(parents=True)
    for k in range(first, last + 1):
        name = f"RE_frame-{k}.jpg"
        (dst / "frames" / name).symlink_to(src / "frames" / name)
    for name in ("framestamp.txt", "gyro.txt"):
        (dst / name).symlink_to(src / name)
    return dst


def phone_rotated_layout(src: Path, dst: Path) -> Path:
    """The phone video's layout with every frame turned by 180 degrees (written as PNG): the
    rows are then read bottom to top, which a readout >= 0 cannot describe."""
    (dst / "frames").mkdir(parents=True)
    for img in sorted((src / "frames").glob("*.jpg")):
        turned = cv2.rotate(cv2.imread(str(img), cv2.IMREAD_COLOR), cv2.ROTATE_180)
        cv2.imwrite(str(dst / "frames" / (img.stem + ".png")), turned)
    for name in ("framestamp.txt", "gyro.txt"):
        (dst / name).symlink_to(src / name)
    return dst


def readout_direction(src: Path, work: Path, opts: list[str], upright: dict) -> dict[str, Any]:
    """The readout direction decided by the images: the same fit on the frames turned by 180
    degrees (principal point mirrored). If the sensor reads top to bottom, the turned frames
    are read bottom to top, the readout (bounded at 0) cannot follow and the fit is worse."""
    fx, fy, cx, cy = (float(v) for v in PHONE_INTRINSICS.split(","))
    w, h = 800, 600
    turned_k = f"{fx},{fy},{w - 1 - cx},{h - 1 - cy}"
    lay = phone_rotated_layout(src, work / "turned" / "src")
    sess, cal = lay.parent / "S", lay.parent / "calib.yaml"
    opts = [o if o != PHONE_INTRINSICS else turned_k for o in opts]
    steps = [run_cli(["import", "frames", str(lay), str(sess), *opts])]
    if steps[0]["rc"] == 0:
        steps.append(run_cli(["calibrate", str(sess), "--out", str(cal)]))
    f = calib_figures(cal) if len(steps) == 2 and steps[1]["rc"] == 0 else {}
    up, down = upright.get("holdout_median_px"), f.get("holdout_median_px")
    return {
        "turned_outcome": "calibrated" if f else "refused",
        "turned_readout_ms": f.get("readout_ms"),
        "turned_holdout_median_px": down,
        "upright_holdout_median_px": up,
        "top_to_bottom": bool(up is not None and down is not None and up < down),
    }


def phone_video(work: Path, pics: Path | None, halves: bool) -> dict[str, Any]:
    src = REAL / "phone-video-412hz"
    opts = ["--exposure-ms", PHONE_EXPOSURE_MS, "--intrinsics", PHONE_INTRINSICS]
    rec = import_and_calibrate("phone-video-412hz", "frames", src, opts, work, pics)
    if not halves:
        return rec
    parts = []
    for a, b in HALVES:
        lay = phone_half_layout(src, work / f"half-{a}-{b}" / "src", a, b)
        sess, cal = lay.parent / "S", lay.parent / "calib.yaml"
        steps = [run_cli(["import", "frames", str(lay), str(sess), *opts])]
        if steps[0]["rc"] == 0:
            steps.append(run_cli(["calibrate", str(sess), "--out", str(cal)]))
        bad = next((s for s in steps if s["rc"] != 0), None)
        parts.append(
            {
                "frames": f"{a}-{b}",
                "outcome": "calibrated" if bad is None else f"refused: {bad.get('error')}",
                "wall_s": sum(s["wall_s"] for s in steps),
                "figures": calib_figures(cal) if len(steps) == 2 else {},
            }
        )
    halves_rec: dict[str, Any] = {"parts": parts}
    f0, f1 = parts[0]["figures"], parts[1]["figures"]
    for key in ("timeshift", "readout"):
        vals = [f.get(f"{key}_ms") for f in (f0, f1)] + [f.get(f"{key}_sigma_ms") for f in (f0, f1)]
        if all(isinstance(x, float) for x in vals):
            halves_rec[f"{key}_agree_2sigma"] = agree(vals[0], vals[2], vals[1], vals[3])
            halves_rec[f"{key}_diff_ms"] = vals[1] - vals[0]
            halves_rec[f"{key}_diff_sigma_ms"] = math.hypot(vals[2], vals[3])
    rec["halves"] = halves_rec
    rec["readout_direction"] = readout_direction(src, work, opts, rec.get("figures") or {})
    return rec


def marslogger(work: Path, pics: Path | None) -> dict[str, Any]:
    src = REAL / "marslogger-phone"
    return import_and_calibrate("marslogger-phone", "marslogger", src, [], work, pics)


def deepgyro(work: Path, pics: Path | None) -> dict[str, Any]:
    src = REAL / "deepgyro-shield"
    return import_and_calibrate("deepgyro-shield", "deepgyro", src, [], work, pics)


def shake(work: Path, pics: Path | None) -> dict[str, Any]:
    """The hand-shake traces drive the simulated rig: simulate, validate, detect, calibrate
    (gyro only: no pictures of their own)."""
    trace = REAL / "gyrodeblurnet-shake" / "gyro_train.txt"
    sess, cal = work / "shake" / "S", work / "shake" / "calib.yaml"
    argvs = [
        ["simulate", str(sess), "--motion", "shake", "--shake", str(trace), "--frames", "20"],
        ["validate", str(sess)],
        ["detect", str(sess)],
        ["calibrate", str(sess), "--out", str(cal)],
    ]
    t0 = time.perf_counter()
    steps: list[dict[str, Any]] = []
    for argv in argvs:
        steps.append(run_cli(argv))
        if steps[-1]["rc"] != 0:
            break
    bad = next((s for s in steps if s["rc"] != 0), None)
    rec: dict[str, Any] = {
        "item": "gyrodeblurnet-shake",
        "commands": [shown(a, work) for a in argvs[: len(steps)]],
        "steps": steps,
        "wall_s": time.perf_counter() - t0,
        "outcome": "calibrated (simulated rig driven by the trace)"
        if bad is None
        else f"refused: {bad.get('error')}",
        "pictures": [],
    }
    if len(steps) == 4:
        rec["figures"] = calib_figures(cal)
    return rec


def light_streaks(work: Path, pics: Path | None) -> list[dict[str, Any]]:
    """``bench/real_streaks.py``'s measurement of each photograph (detection, no gyro)."""
    from real_streaks import DATA, measure

    out = []
    for n in ("night1", "night2"):
        t0 = time.perf_counter()
        overlay = (pics or work / "streaks") / f"light-streaks_{n}_overlay.png"
        m = measure(DATA / f"{n}.jpg", overlay)
        pic = m.pop("overlay", None)
        out.append(
            {
                "item": f"light-streaks/{n}.jpg",
                "commands": [f"python bench/real_streaks.py (measure {n}.jpg)"],
                "wall_s": time.perf_counter() - t0,
                "outcome": "detected (no gyro: nothing to calibrate)",
                "figures": m,
                "pictures": [str(overlay if pics else overlay.relative_to(work))] if pic else [],
            }
        )
    return out


def _f(x: Any, fmt: str = ".3g") -> str:
    return "–" if x is None else format(x, fmt)


def matrix(m: list[list[float]] | None) -> str:
    """A signed permutation matrix, compactly: ``[[0,-1,0],[-1,0,0],[0,0,-1]]``."""
    if m is None:
        return "–"
    return "[" + ",".join("[" + ",".join(f"{v:g}" for v in row) + "]" for row in m) + "]"


def figures_text(rec: dict[str, Any]) -> str:
    """The table's key figures of one item."""
    f = rec.get("figures") or {}
    parts = []
    if "image" in f:  # a photograph
        whole = f.get("whole_streaks")
        parts.append(
            f"{f['streaks']} streaks, "
            + ("no whole-streak reference" if whole is None else f"{whole} whole")
        )
        if "vector_deviation_median_px" in f:
            parts.append(f"shape spread median {f['vector_deviation_median_px']:.2f} px")
        return "; ".join(parts)
    imp = rec.get("import") or {}
    if imp:
        parts.append(f"{imp['frames']} frames, {imp['gyro_samples']} gyro samples")
        if imp.get("overlays_skipped"):
            parts.append(
                f"overlays of frames {', '.join(map(str, imp['overlays_skipped']))} not drawn "
                "(gyro does not cover them)"
            )
    if f.get("axes_margin") is not None:
        parts.append(
            f"axes {matrix(f['axes_winner'])} margin {f['axes_margin']:.2f} "
            f"(score {f['axes_score_px']:.3f} px)"
        )
    for key in ("timeshift", "readout"):
        if f.get(f"{key}_ms") is not None:
            parts.append(f"{key} {f[f'{key}_ms']:.2f} ± {_f(f.get(f'{key}_sigma_ms'), '.2f')} ms")
    if f.get("holdout_median_px") is not None:
        parts.append(f"hold-out median {f['holdout_median_px']:.3f} px (n {f['holdout_n']})")
    if f.get("tracks") is not None:
        parts.append(f"{f['tracks']} tracks")
    elif f.get("inliers") is not None:
        parts.append(f"{f['inliers']} inlier streaks")
    if f.get("error_vs_truth_ms"):
        e = f["error_vs_truth_ms"]
        parts.append(
            "error vs truth "
            + ", ".join(f"{k.replace('_s', '')} {v:+.3f} ms" for k, v in e.items())
        )
    h = rec.get("halves")
    if h:
        for p in h["parts"]:
            g = p["figures"]
            parts.append(
                f"half {p['frames']}: {p['outcome']} ({p['wall_s']:.1f} s)"
                + (
                    f", axes margin {g['axes_margin']:.2f}, "
                    f"timeshift {g['timeshift_ms']:.2f} ± {g['timeshift_sigma_ms']:.2f}, "
                    f"readout {g['readout_ms']:.2f} ± {g['readout_sigma_ms']:.2f} ms"
                    if g.get("timeshift_ms") is not None
                    else ""
                )
            )
        for key in ("timeshift", "readout"):
            if f"{key}_agree_2sigma" in h:
                ok = "agree" if h[f"{key}_agree_2sigma"] else "DISAGREE"
                parts.append(
                    f"halves' {key} {ok} within 2σ (diff {h[f'{key}_diff_ms']:+.2f} ms, "
                    f"2σ {2 * h[f'{key}_diff_sigma_ms']:.2f} ms)"
                )
    rd = rec.get("readout_direction")
    if rd:
        parts.append(
            "readout "
            + ("top to bottom" if rd["top_to_bottom"] else "direction NOT decided")
            + f" (frames turned 180°: {rd['turned_outcome']}, readout "
            f"{_f(rd['turned_readout_ms'], '.2f')} ms, hold-out median "
            f"{_f(rd['turned_holdout_median_px'], '.3f')} px against "
            f"{_f(rd['upright_holdout_median_px'], '.3f')} upright)"
        )
    parts.append(f"{rec['wall_s']:.1f} s")
    return "; ".join(parts)


def table(recs: list[dict[str, Any]]) -> str:
    """The markdown table."""
    rows = [
        "| item | command(s) | outcome | key figures | pictures written |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in recs:
        cmds = "<br>".join(f"`{c}`" for c in r["commands"])
        pics = "<br>".join(Path(p).name for p in r.get("pictures", [])) or "–"
        cells = [r["item"], cmds, r["outcome"], figures_text(r), pics]
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


def run_all(quick: bool, pics: Path | None) -> list[dict[str, Any]]:
    """Every item (``quick``: the phone video alone, no halves), in a temporary work folder."""
    with tempfile.TemporaryDirectory(prefix="real_data_") as tmp:
        work = Path(tmp)
        recs = [phone_video(work, pics, halves=not quick)]
        if not quick:
            items: list[Callable[[Path, Path | None], Any]] = [marslogger, deepgyro, shake]
            for item in items:
                recs.append(item(work, pics))
            recs.extend(light_streaks(work, pics))
    return recs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the phone video only, no halves")
    ap.add_argument("--out", type=Path, default=None, help="folder for the pictures")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    if not REAL.is_dir():
        print(f"real data not found at {REAL}", file=sys.stderr)
        return 2
    if args.out is not None:
        args.out = args.out.resolve()
        if args.out.is_relative_to(REAL.parent.resolve()):
            print("--out must not lie inside the data folder", file=sys.stderr)
            return 2
    recs = run_all(args.quick, args.out)
    print(table(recs))
    print()
    return emit(recs, args.json)


if __name__ == "__main__":
    sys.exit(main())
