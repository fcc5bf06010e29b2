"""Virtual devices driven by a rigs.sim laser-grid rig through ``rig=...`` URLs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rigs.sim.rig", reason="the rigs.sim simulator is not in this tree")

from blurtrack.cli import main as cli_main
from blurtrack.io.session import load_session
from rigs.protocol import GYRO_SCALE_RADPS
from rigs.reclog import scan_log
from rigs.sim.shared_rig import shared_rig


def test_record_a_simulated_laser_grid_rig(tmp_path: Path) -> None:
    url = "rig=clean&seed=5&frames=6"
    out = tmp_path / "session"
    rc = cli_main(
        [
            "record",
            "--imu",
            f"sim://imu?{url}",
            "--camera",
            f"sim://camera?{url}",
            "--out",
            str(out),
            "--duration",
            "120",
        ]
    )
    assert rc == 0
    s = load_session(out)
    shared = shared_rig("clean", 5, 6)
    rig = shared.rig
    # every frame, none dropped, on the rig's schedule, with the rig's exposure
    assert len(s.frames) == 6
    np.testing.assert_array_equal(
        np.diff(s.frames.timestamp_ns.to_numpy()), np.diff(rig.frame_times_ns)
    )
    assert (s.frames.exposure_ns == rig.exposure_ns).all()
    # the whole board: lead before the first frame to tail after the last, gap-free
    scan = scan_log(tmp_path / "session.mcap")
    np.testing.assert_array_equal(scan.imu_index, np.arange(shared.imu_samples()))
    # the values are the rig's gyro at the board's sample times (quantised to 1e-6 rad/s)
    t_board_s = scan.imu_t_dev_us * 1e-6
    ideal = rig.sample_gyro(shared.imu_clock_s(t_board_s), noise=False)
    tol = 6 * rig.preset.gyro_noise_radps + GYRO_SCALE_RADPS
    np.testing.assert_allclose(s.omega_radps, ideal, atol=tol, rtol=0)
    # the gyro covers every exposure and session.yaml carries the rig's nominal guesses
    assert s.imu_t_ns[0] < s.frames.timestamp_ns.iloc[0]
    assert s.imu_t_ns[-1] > s.frames.timestamp_ns.iloc[-1] + rig.exposure_ns
    nominal = rig.nominal_meta()
    np.testing.assert_allclose(s.meta.imu.T_cam_imu, nominal.imu.T_cam_imu)
    assert s.meta.camera.intrinsics == nominal.camera.intrinsics
    assert s.meta.extra["recording"]["intrinsics_guessed"] is False
