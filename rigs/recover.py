"""Salvage of a recorder log cut short (crash, SIGKILL, full disk): every intact message of
the damaged MCAP copied into a new, finished log (``blurtrack recover``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rigs.errors import RecorderLogError
from rigs.reclog import RecLogWriter, walk_log


@dataclass(frozen=True)
class RecoverResult:
    """What :func:`recover_log` kept."""

    out_path: Path
    messages: int
    imu_samples: int
    frames: int
    was_complete: bool
    damage: str


def recover_log(path: str | Path, out_path: str | Path) -> RecoverResult:
    """Copy every intact message of ``path`` into a new, finished log at ``out_path``."""
    path, out_path = Path(path), Path(out_path)
    if out_path.resolve() == path.resolve():
        raise RecorderLogError("the recovered log must not overwrite the damaged one")
    scan_meta: dict[str, str] = {}
    writer: RecLogWriter | None = None
    damage, n, imu_n, frames = "", 0, 0, 0
    for key, rec in walk_log(path):
        if key == "meta":
            scan_meta = {k: v for k, v in rec.metadata.items() if k != "format"}
            writer = RecLogWriter(out_path, scan_meta)
            continue
        if key == "":
            damage = rec
            break
        assert writer is not None  # the metadata record comes first in our logs
        writer.write_message(key, rec.log_time, rec.data, rec.publish_time)
        n += 1
        if key == "/imu":
            imu_n += 1
        elif key.startswith("/cam0:"):
            frames += 1
    if writer is None:
        raise RecorderLogError(f"{path} holds no recording metadata")
    writer.write_event(0, "info", f"recovered from {path.name}: " + (damage or "log was complete"))
    writer.finish()
    return RecoverResult(out_path, n, imu_n, frames, not damage, damage)
