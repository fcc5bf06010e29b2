"""``synth-merge``: combine the shards of one dataset into a single sorted manifest.

Shards are built in one folder (``--shard I/N`` side by side) or on separate machines and
copied over; each carries its ``dataset.yaml``. Folders merge only when their identities (a
hash of the spec, calibration, gyro data and image list, :func:`store.input_identity`) are
equal, so shards built from different photo folders or shakes are refused even when the
folders share a name. Every record is confined to the files its index names
(:func:`store.expected_files`). Missing triplets are an error unless ``allow_missing``; every
check runs before anything is moved, so a refused merge changes nothing.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any, cast

from blurtrack.errors import BlurTrackError, SynthesisError
from blurtrack.io import atomic
from blurtrack.io.yamlio import read_yaml, write_text_atomic, write_yaml
from blurtrack.synth.spec import FORMAT, DatasetSpec
from blurtrack.synth.store import dataset_lock, finished, read_manifest


def _meta(folder: Path) -> tuple[dict[str, Any], DatasetSpec]:
    have = read_yaml(folder / "dataset.yaml", "dataset.yaml")
    if not isinstance(have, dict) or have.get("format") != FORMAT:
        raise SynthesisError(f"{folder}/dataset.yaml is not a {FORMAT} file")
    if not isinstance(have.get("identity"), str):
        raise SynthesisError(
            f"{folder}/dataset.yaml has no input identity (made by an older blurtrack); "
            f"rebuild that shard"
        )
    try:
        # a missing spec fails inside from_dict and is caught below
        return have, DatasetSpec.from_dict(cast("dict[str, Any]", have.get("spec")))
    except (BlurTrackError, AttributeError, TypeError, ValueError, KeyError):
        raise SynthesisError(f"{folder}/dataset.yaml has a malformed spec") from None


def _records(folder: Path) -> dict[int, dict[str, Any]]:
    records = read_manifest(folder / "manifest.jsonl")
    for m in sorted(folder.glob("manifest-shard*.jsonl")):
        records.update(read_manifest(m))
    return records


def _move(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(src, dst)
    except OSError:  # another file system: copy to a temporary name, then rename
        with atomic.atomic_path(dst, "merge") as tmp:
            shutil.copy2(src, tmp)


def merge(
    out: str | Path, shard_dirs: Iterable[str | Path] = (), allow_missing: bool = False
) -> dict[str, Any]:
    """Combine the manifests in ``out`` and in ``shard_dirs`` (whose files are moved into
    ``out``) into one sorted ``manifest.jsonl``; returns a summary with missing indices."""
    root = Path(out)
    dirs: list[Path] = []
    for d in map(Path, shard_dirs):
        if not d.is_dir():
            raise SynthesisError(f"shard folder not found: {d}")
        if not (d / "dataset.yaml").is_file():
            raise SynthesisError(f"{d} holds no dataset.yaml (not a synth dataset or shard)")
        if d.resolve() != root.resolve() and all(d.resolve() != e.resolve() for e in dirs):
            dirs.append(d)
    found = [d for d in [root, *dirs] if (d / "dataset.yaml").is_file()]
    if not found:
        raise SynthesisError(f"no dataset.yaml found in {root} or the shard folders")
    metas = {d: _meta(d) for d in found}
    ref, spec = metas[found[0]]
    for d in found[1:]:
        if metas[d][0]["identity"] != ref["identity"]:
            raise SynthesisError(
                f"{d} was built from other inputs or parameters than {found[0]} (their "
                f"dataset identities differ: spec, calibration, gyro data or image list)"
            )
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    try:
        with contextlib.ExitStack() as locks:
            for d in [root, *(d for d in dirs if os.access(d, os.W_OK))]:
                locks.enter_context(dataset_lock(d))
            return _merge_locked(root, dirs, ref, spec, allow_missing)
    except BaseException:
        if created:
            (root / ".lock").unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                root.rmdir()
        raise


def _merge_locked(
    root: Path, dirs: list[Path], ref: dict[str, Any], spec: DatasetSpec, allow_missing: bool
) -> dict[str, Any]:
    count, group, extras = spec.count, spec.group, spec.extras
    records = _records(root)
    done = finished(root, records, count, group, extras)
    seen = set(records)
    moves: dict[int, tuple[Path, dict[str, Any]]] = {}
    for d in dirs:
        recs = _records(d)
        seen |= set(recs)
        for i in sorted(finished(d, recs, count, group, extras) - done - set(moves)):
            moves[i] = (d, recs[i])
    have = done | set(moves)
    missing = sorted(set(range(count)) - have)
    if missing and not allow_missing:
        first = ", ".join(map(str, missing[:10]))
        raise SynthesisError(
            f"{len(missing)} of {count} triplets are missing (indices {first}"
            f"{', ...' if len(missing) > 10 else ''}): build the missing shards, or pass "
            f"--allow-missing to merge the others"
        )
    if not (root / "dataset.yaml").is_file():
        write_yaml(root / "dataset.yaml", ref)
    for i, (d, rec) in moves.items():
        for rel in rec["files"].values():
            _move(d / rel, root / rel)
        records[i] = rec
    lines = "".join(json.dumps(records[i], sort_keys=True) + "\n" for i in sorted(have))
    write_text_atomic(root / "manifest.jsonl", lines)
    for m in root.glob("manifest-shard*.jsonl"):
        m.unlink()
    return {
        "triplets": len(have),
        "count": count,
        "missing": len(missing),
        "missing_first": missing[:20],
        "moved": len(moves),
        "lost_records": len(seen - have),
        "min_blur_px": float(spec.params.min_blur_px),
        "draws_under_min_blur": sum(
            int(records[i].get("draws_under_min_blur", 0)) for i in sorted(have)
        ),
    }
