"""The firmware's protocol header, compiled on the host, agrees byte for byte with Python."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rigs.decoder import StreamDecoder
from rigs.protocol import encode_binary

FIRMWARE = Path(__file__).resolve().parents[2] / "rigs" / "firmware" / "blurtrack_imu"

PROGRAM = r"""
#include "blurtrack_protocol.h"
#include <stdlib.h>
int main(int argc, char **argv) {
  uint16_t counter = (uint16_t)strtoul(argv[1], 0, 10);
  uint32_t t_us = (uint32_t)strtoul(argv[2], 0, 10);
  int32_t g[3], a[3];
  for (int i = 0; i < 3; ++i) g[i] = (int32_t)strtol(argv[3 + i], 0, 10);
  for (int i = 0; i < 3; ++i) a[i] = (int32_t)strtol(argv[6 + i], 0, 10);
  uint8_t frame[BT_MAX_FRAME];
  size_t n = bt_encode_frame(frame, counter, t_us, g, a);
  for (size_t i = 0; i < n; ++i) printf("%02x", frame[i]);
  n = bt_encode_frame(frame, counter, t_us, g, NULL);
  printf(" ");
  for (size_t i = 0; i < n; ++i) printf("%02x", frame[i]);
  char line[160];
  n = bt_encode_line(line, t_us, g, a);
  printf(" %s", line);
  return 0;
}
"""


@pytest.fixture(scope="module")
def encoder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler on this machine")
    d = tmp_path_factory.mktemp("fw")
    (d / "main.c").write_text(PROGRAM)
    exe = d / "enc"
    subprocess.run(
        [
            cc,
            "-std=c99",
            "-Wall",
            "-Werror",
            "-I",
            str(FIRMWARE),
            str(d / "main.c"),
            "-o",
            str(exe),
        ],
        check=True,
        timeout=120,
    )
    return exe


def test_firmware_frames_and_lines_match_python(encoder: Path) -> None:
    rng = np.random.default_rng(3)
    for _ in range(25):
        counter = int(rng.integers(0, 65536))
        t_us = int(rng.integers(0, 2**32))
        g = [int(v) for v in rng.integers(-(2**31), 2**31, 3)]
        a = [int(v) for v in rng.integers(-(10**8), 10**8, 3)]
        out = subprocess.run(
            [str(encoder), str(counter), str(t_us), *map(str, g + a)],
            check=True,
            capture_output=True,
            text=True,
            timeout=30,
        ).stdout
        full, gyro_only, line = out.split(" ", 2)
        assert bytes.fromhex(full) == encode_binary(counter, t_us, tuple(g), tuple(a))
        assert bytes.fromhex(gyro_only) == encode_binary(counter, t_us, tuple(g))
        (sample,) = StreamDecoder("ascii").feed(line.encode())
        assert sample.t_us == t_us
        assert sample.gyro_radps == tuple(float(f"{v / 1e6:.6f}") for v in g)
