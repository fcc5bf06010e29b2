"""EuRoC / ASL folders: ``mav0/cam0/{data.csv,data/,sensor.yaml}`` and
``mav0/imu0/{data.csv,sensor.yaml}``.

``sensor.yaml`` is OpenCV FileStorage YAML with ``T_BS`` (sensor to body, 4x4, row-major
``data``), ``resolution``, ``intrinsics`` (fu fv cu cv), ``distortion_model``
(``radial-tangential`` = OpenCV k1 k2 p1 p2) and ``distortion_coefficients``. The camera–IMU
transform is stated by the recording: ``T_cam_imu = T_BS(cam)^-1 · T_BS(imu)``, so the session's
axes are known. The ASL format gives no exposure: it comes from ``--exposure-ms``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np

from blurtrack.errors import BlurTrackError, ImportFormatError
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import is_rotation
from blurtrack.io.cvyaml import matrix, read_cv_yaml
from blurtrack.io.importers.common import (
    MAX_FRAMES,
    check_readout,
    exposure_ns,
    frame_start_ns,
    rate_hz,
    read_image,
    sorted_unique,
    text_lines,
)
from blurtrack.io.rosimage import check_size
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, safe_member

_DISTORTION = {"radial-tangential": "radtan", "radtan": "radtan", "plumb_bob": "radtan"}


def _sensor(path: Path) -> dict[str, Any]:
    try:
        d = read_cv_yaml(path, "sensor.yaml")
    except BlurTrackError as exc:
        raise ImportFormatError(str(exc)) from None
    if not isinstance(d, dict):
        raise ImportFormatError(f"{path}: expected a mapping")
    return d


def _T_BS(d: dict[str, Any], path: Path) -> np.ndarray:
    try:
        T = np.array(matrix(d.get("T_BS", np.eye(4).tolist()), 4, 4, f"{path} T_BS"))
    except BlurTrackError as exc:
        raise ImportFormatError(str(exc)) from None
    if not is_rotation(T[:3, :3], tol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ImportFormatError(f"{path}: T_BS is not a proper rigid transform (det must be +1)")
    return T


def _camera(d: dict[str, Any], path: Path, readout_s: float) -> Camera:
    try:
        w, h = (int(v) for v in d["resolution"])
        check_size(w, h, str(path))
        intr = cast("tuple[float, float, float, float]", tuple(float(v) for v in d["intrinsics"]))
        model = str(d.get("camera_model", "pinhole"))
        dist_name = str(d.get("distortion_model", "none"))
        coeffs = tuple(float(v) for v in d.get("distortion_coefficients") or ())
    except KeyError as exc:
        raise ImportFormatError(f"{path} lacks the key {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise ImportFormatError(f"{path}: resolution/intrinsics must be numbers") from None
    if model != "pinhole":
        raise ImportFormatError(f"{path}: camera_model {model!r} is not supported (pinhole)")
    if dist_name not in (*_DISTORTION, "none"):
        raise ImportFormatError(f"{path}: distortion_model {dist_name!r} is not supported")
    if dist_name != "none" and len(coeffs) != 4:
        raise ImportFormatError(f"{path}: radial-tangential needs 4 coefficients k1 k2 p1 p2")
    try:
        return Camera(
            (w, h),
            intr,
            _DISTORTION.get(dist_name, "none"),
            coeffs if dist_name != "none" else (),
            readout_s=readout_s,
        )
    except BlurTrackError as exc:
        raise ImportFormatError(f"{path}: {exc}") from None


def _imu_rows(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    lines = text_lines(path)
    if not lines or not lines[0].startswith("#") or "w_RS_S_x" not in lines[0]:
        raise ImportFormatError(
            f"{path}: expected the ASL header '#timestamp [ns],w_RS_S_x [rad s^-1],...'"
        )
    t, w, a = [], [], []
    ncol = len(lines[0].split(","))
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) != ncol or ncol not in (4, 7):
            raise ImportFormatError(f"{path} line {n}: expected {ncol} fields (4 or 7)")
        try:
            t.append(int(parts[0]))
            vals = [float(v) for v in parts[1:]]
        except ValueError:
            raise ImportFormatError(f"{path} line {n} is not numeric") from None
        if not np.all(np.isfinite(vals)):
            raise ImportFormatError(f"{path} line {n}: non-finite value")
        w.append(vals[:3])
        a.append(vals[3:6])
    if len(t) < 2:
        raise ImportFormatError(f"{path}: fewer than 2 IMU samples")
    t_ns = np.asarray(t, np.int64)
    return t_ns, np.asarray(w, float), (np.asarray(a, float) if ncol == 7 else None)


def import_euroc(
    src: str | Path,
    out: str | Path,
    *,
    exposure_s: float | None = None,
    readout_s: float = 0.0,
    stamp: str = "start",
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Import an EuRoC/ASL folder (``SRC/mav0/...`` or ``SRC`` = the ``mav0`` folder)."""
    root = Path(src)
    mav = root / "mav0" if (root / "mav0").is_dir() else root
    cam_dir, imu_dir = mav / "cam0", mav / "imu0"
    exp = exposure_ns(exposure_s, "euroc")
    readout = check_readout(readout_s, "euroc")
    cam_yaml = _sensor(cam_dir / "sensor.yaml")
    imu_yaml_path = imu_dir / "sensor.yaml"
    imu_yaml = _sensor(imu_yaml_path) if imu_yaml_path.is_file() else {}
    camera = _camera(cam_yaml, cam_dir / "sensor.yaml", readout)
    T_cam_imu = np.linalg.inv(_T_BS(cam_yaml, cam_dir / "sensor.yaml")) @ _T_BS(
        imu_yaml, imu_yaml_path
    )
    rows = []
    for n, line in enumerate(text_lines(cam_dir / "data.csv"), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 2:
            raise ImportFormatError(f"{cam_dir / 'data.csv'} line {n}: expected 'ts,filename'")
        try:
            rows.append((int(parts[0]), parts[1]))
        except ValueError:
            raise ImportFormatError(f"{cam_dir / 'data.csv'} line {n}: bad timestamp") from None
    limit = MAX_FRAMES if max_frames is None else min(int(max_frames), MAX_FRAMES)
    rows = sorted(rows)[:limit]
    if not rows:
        raise ImportFormatError(f"{cam_dir / 'data.csv'} lists no frames")
    t_imu, w_imu, a_imu = _imu_rows(imu_dir / "data.csv")
    sel = sorted_unique(t_imu)
    assumptions = {
        "exposure_s": f"{exp * 1e-9} (from --exposure-ms; the ASL format does not record it)",
        "readout_s": f"{readout} (from --readout-ms; 0 = global shutter)",
        "timestamps": f"frame stamps taken as the {stamp} of exposure (--stamp)",
        "timeshift_cam_imu_s": "0.0 (to be calibrated)",
    }
    meta = SessionMeta(
        camera=camera,
        imu=ImuConfig(rate_hz=rate_hz(t_imu[sel], str(imu_dir)), T_cam_imu=T_cam_imu.tolist()),
        target_kind="natural",
        extra={
            "import": {
                "source": "euroc",
                "path": str(root),
                "assumptions": assumptions,
                "imu_noise": {
                    k: float(imu_yaml[k])
                    for k in (
                        "gyroscope_noise_density",
                        "gyroscope_random_walk",
                        "accelerometer_noise_density",
                        "accelerometer_random_walk",
                    )
                    if isinstance(imu_yaml.get(k), (int, float))
                },
            }
        },
    )
    data_dir = cam_dir / "data"
    prev = None
    with SessionWriter(out, meta) as wr:
        for ts, name in rows:
            try:
                path = safe_member(data_dir, name)
            except BlurTrackError as exc:
                raise ImportFormatError(str(exc)) from None
            img = read_image(path)
            if img.shape[:2] != (camera.height, camera.width):
                raise ImportFormatError(
                    f"{path} is {img.shape[1]}x{img.shape[0]}, sensor.yaml says "
                    f"{camera.width}x{camera.height}"
                )
            t0 = frame_start_ns(ts, stamp, exp, readout)
            if prev is not None and t0 <= prev:
                raise ImportFormatError(f"{cam_dir / 'data.csv'}: repeated timestamp {ts}")
            wr.add_frame(t0, img, exp)
            prev = t0
        wr.add_imu(t_imu[sel], w_imu[sel], None if a_imu is None else a_imu[sel])
    return {
        "frames": len(rows),
        "gyro_samples": int(sel.size),
        "resolution": [camera.width, camera.height],
        "assumptions": assumptions,
    }
