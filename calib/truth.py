"""A simulated session's true calibration in the fit's parameter terms (what ``calibrate``'s
summary and table compare an estimate with; used by :mod:`calib.cli` and
:mod:`calib.natural.cli`)."""

from __future__ import annotations

from typing import Any


def truth_values(session: Any, initial: Any) -> dict[str, float] | None:
    """The simulator's true parameters in theta terms (rotation relative to the initial one).

    The true rotation is the one the gyro data define, ``R_true Qᵀ`` with ``M = P Q`` the
    polar decomposition of the simulator's gyro scale/cross-axis matrix: a rotation of the
    gyro's own axes cannot be told from the mounting rotation
    (:func:`calib.params.symmetric_scale_form`), so measuring against ``R_true`` would count
    the unobservable ``Q`` (about 0.2° for 0.3 % entries) as error."""
    import numpy as np

    from blurtrack.errors import BlurTrackError
    from blurtrack.io.calibration import calibration_from_dict
    from calib.params import LAYOUT, rotation_error_rad, scale_entries, theta_from
    from calib.result import named

    truth = session.truth
    if not truth or "calibration" not in truth:
        return None
    try:
        cal = calibration_from_dict(truth["calibration"], source="truth.yaml")
    except BlurTrackError:
        return None
    th = theta_from(cal)
    gyro = (truth.get("simulator") or {}).get("gyro") or {}
    try:
        M = np.array(gyro.get("scale_matrix", np.eye(3)), dtype=float).reshape(3, 3)
    except (TypeError, ValueError):
        M = np.eye(3)
    U, _, Vt = np.linalg.svd(M)
    th[LAYOUT["rotation"]] = rotation_error_rad(cal.R_cam_imu @ (U @ Vt).T, initial.R_cam_imu)
    th[LAYOUT["scale"]] = scale_entries(M)
    return named(th)
