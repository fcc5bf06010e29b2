"""How a dataset folder is written and trusted: atomic files, the manifest, the dataset lock,
the confinement of manifest file entries, and the identity of a dataset's inputs.

* **Atomic files**: every file is written to a hidden ``.<name>.<tag>.<uniq>.tmp`` next to its
  final name and renamed into place (``tag`` names the shard, so a shard cleaning up after a
  killed run of itself never touches another shard's temporaries).
* **Manifest**: one JSON object per line, appended and fsynced only after the triplet's files
  are in place; a final line without newline is the trace of a killed writer.
* **Lock**: a build of the whole dataset and ``synth-merge`` hold ``DATASET/.lock``
  exclusively; a shard build holds it shared and its own ``.<manifest>.lock`` exclusively, so
  shards may run side by side in one folder but two runs never make the same triplets. The
  locks are ``flock``s: the kernel drops them when their process dies, so a killed run never
  blocks the next one.
* **Confinement**: a manifest is untrusted input. A record's file entries must be exactly the
  paths its index gives (``{train,test}/<tag>_<index // group>/<kind>/<index:06d>.<ext>``)
  and must be plain files inside the dataset folder, so a record can never name (or move)
  ``dataset.yaml``, another manifest, or anything outside the folder.
* **Identity**: a hash of the spec without its input paths, the gyro data actually read and
  the image list (relative names and sizes). Shards merge, and a build resumes, only with the
  same identity: same calibration and parameters, same photos, same shake.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.io import atomic

KINDS = (("sharp", ".png"), ("blur", ".png"), ("heat", ".npy"))
#: Optional extra files (``extras=True``): validity mask (0/255 PNG) and Bezier fit error (px).
EXTRA_KINDS = (("mask", ".png"), ("fit", ".npy"))
_EXT = dict(KINDS + EXTRA_KINDS)
_NAME = re.compile(r"[a-z]+_[0-9]{4,}")


def write_atomic(path: Path, data: bytes | np.ndarray, tag: str = "x") -> None:
    """Write ``data`` (bytes, or an array as ``.npy``, streamed without an in-memory copy)
    through the project's atomic writer (:mod:`blurtrack.io.atomic`: a hidden
    ``.<name>.<tag>.<random>.tmp`` beside ``path``, fsynced, renamed; removed on every error;
    permissions from the umask). ``tag`` names the shard, so a shard cleaning up after a killed
    run of itself never touches another shard's temporaries."""
    if isinstance(data, np.ndarray):
        atomic.write_atomic(path, lambda f: np.save(f, data, allow_pickle=False), tag)
    else:
        atomic.write_bytes_atomic(path, data, tag)


def remove_temporaries(root: Path, tag: str) -> None:
    """Delete the temporaries that runs of shard ``tag`` left in ``root``'s triplet folders."""
    for tmp in root.glob(f"*/*/*/.*.{tag}.*.tmp"):
        tmp.unlink(missing_ok=True)


def read_manifest(path: Path, repair: bool = False) -> dict[int, dict[str, Any]]:
    """Records by index (a later line wins). A final line without newline is the trace of a
    killed writer: ignored, and cut off when ``repair``. Any other bad line is an error."""
    if not path.is_file():
        return {}
    raw = path.read_bytes()
    end = raw.rfind(b"\n") + 1
    if end < len(raw) and repair:
        with path.open("r+b") as f:
            f.truncate(end)
    records: dict[int, dict[str, Any]] = {}
    for n, line in enumerate(raw[:end].splitlines(), start=1):
        try:
            rec = json.loads(line)
            records[int(rec["index"])] = rec
        except (ValueError, KeyError, TypeError):
            raise SynthesisError(f"{path}: line {n} is not a manifest record") from None
    return records


class ManifestWriter:
    """Appends records to an open manifest, one fsynced line each."""

    def __init__(self, path: Path) -> None:
        self._f = path.open("a", encoding="utf-8")

    def append(self, rec: dict[str, Any]) -> None:
        self._f.write(json.dumps(rec, sort_keys=True) + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


def expected_files(rec: dict[str, Any], count: int, group: int, extras: bool) -> dict[str, str]:
    """The relative paths a record of a dataset with ``count`` triplets must name, or
    ``{}`` when its index, split, name or stem do not fit the layout."""
    try:
        i = int(rec["index"])
        split, name, stem = rec["split"], rec["name"], rec["stem"]
    except (KeyError, TypeError, ValueError):
        return {}
    if not (
        0 <= i < count
        and split in ("train", "test")
        and isinstance(name, str)
        and _NAME.fullmatch(name)
        and int(name.rsplit("_", 1)[1]) == i // group
        and stem == f"{i:06d}"
    ):
        return {}
    kinds = KINDS + (EXTRA_KINDS if extras else ())
    return {k: f"{split}/{name}/{k}/{stem}{ext}" for k, ext in kinds}


#: The last 12 bytes of every complete PNG: the empty IEND chunk and its CRC.
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def intact(path: Path) -> bool:
    """Whether a dataset file is complete: a PNG with its signature and its final IEND chunk,
    an ``.npy`` whose header parses and whose size is exactly header plus data. Zero-byte,
    truncated and undecodable files are not (read: the header and the last bytes only)."""
    try:
        size = os.stat(path).st_size
        if size == 0:
            return False
        with open(path, "rb") as f:
            if path.suffix == ".png":
                head = f.read(8)
                f.seek(max(0, size - 12))
                return head == _PNG_SIGNATURE and f.read(12) == _PNG_END
            if path.suffix == ".npy":
                major, _ = np.lib.format.read_magic(f)
                read_header = (
                    np.lib.format.read_array_header_1_0
                    if major == 1
                    else np.lib.format.read_array_header_2_0
                )
                shape, _, dtype = read_header(f)
                if dtype.hasobject:
                    return False
                return size == f.tell() + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    except (OSError, ValueError, TypeError, SyntaxError):
        return False
    return True


def finished(
    root: Path,
    records: dict[int, dict[str, Any]],
    count: int,
    group: int,
    extras: bool,
    broken: set[int] | None = None,
) -> set[int]:
    """Indices whose record names exactly its own files and whose files exist in ``root`` as
    plain files (not links) in folders that resolve inside ``root``, each complete
    (:func:`intact`). Records whose files exist but are not all complete (zero-byte, truncated,
    undecodable) are added to ``broken`` when given: their triplets are made again."""
    base = root.resolve()
    dir_inside: dict[str, bool] = {}

    def plain_file(rel: str) -> bool:
        folder = rel.rsplit("/", 1)[0]
        if folder not in dir_inside:
            dir_inside[folder] = (root / folder).resolve().is_relative_to(base)
        try:
            return dir_inside[folder] and stat.S_ISREG(os.lstat(root / rel).st_mode)
        except OSError:
            return False

    done = set()
    for i, rec in records.items():
        want = expected_files(rec, count, group, extras)
        if want and rec.get("files") == want and all(plain_file(r) for r in want.values()):
            if all(intact(root / r) for r in want.values()):
                done.add(i)
            elif broken is not None:
                broken.add(i)
    return done


def _flock(path: Path, shared: bool, root: Path) -> int:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except OSError as exc:
        try:
            text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        except OSError:
            text = ""
        os.close(fd)
        if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
            who = f" (pid {text})" if text.isdigit() else ""
            raise SynthesisError(
                f"{root} is being written by another run{who} (synth or synth-merge); wait for "
                "it to end (a killed run releases it) or use another --out"
            ) from None
        raise SynthesisError(f"cannot lock {path}: {exc.strerror}") from None
    if not shared:  # the owner's pid, for the message of a run refused
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


@contextlib.contextmanager
def dataset_lock(root: Path, manifest: str | None = None) -> Iterator[None]:
    """Hold the dataset lock: exclusive without ``manifest`` (a whole build, a merge), else
    shared plus the exclusive lock of that manifest (a shard build)."""
    fds = [_flock(root / ".lock", manifest is not None, root)]
    try:
        if manifest is not None:
            fds.append(_flock(root / f".{manifest}.lock", False, root))
        yield
    finally:
        for k, fd in enumerate(fds):
            if k > 0 or manifest is None:  # an exclusive lock: clear its owner's pid
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
            os.close(fd)


def input_identity(
    spec_dict: dict[str, Any], images_root: Path, images: list[str], gyro_fp: str
) -> str:
    """SHA-256 of the spec without its input paths, the gyro fingerprint and the image list
    (relative names and byte sizes): equal for the same inputs under other mount points."""
    spec = {k: v for k, v in spec_dict.items() if k not in ("images", "gyro")}
    try:
        listed = [[rel, (images_root / rel).stat().st_size] for rel in images]
    except OSError as exc:
        raise SynthesisError(f"image {exc.filename} cannot be read: {exc.strerror}") from None
    blob = json.dumps({"spec": spec, "gyro": gyro_fp, "images": listed}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()
