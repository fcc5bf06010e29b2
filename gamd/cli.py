"""The ``gamd`` command line: ``train``, ``eval``, ``deblur``.

Only this module prints and chooses exit codes; errors from the library
(:class:`blurtrack.errors.BlurTrackError`) become ``gamd CMD: error: <message>`` and exit 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.guard import add_force_arg, check_output, output_lock


def _train(args: argparse.Namespace) -> int:
    from gamd.config import RunConfig
    from gamd.train import check_training_size, train

    config = RunConfig.from_yaml(args.config)
    overrides = {}
    if args.data is not None:
        config = replace(config, data=replace(config.data, root=args.data))
    if args.steps is not None:
        overrides["steps"] = args.steps
    if args.out is not None:
        overrides["out_dir"] = args.out
    if args.no_progress:
        overrides["progress"] = False
    if args.device is not None:
        overrides["device"] = args.device
    if overrides:
        config = replace(config, train=replace(config.train, **overrides))
    out_dir = config.train.out_dir
    check_output(
        out_dir,
        folder=True,
        force=True,  # train itself refuses an earlier run without --resume or --force
        inputs=[args.config, None if args.resume in (None, "auto") else args.resume],
        input_folders=[config.data.root],
    )
    check_training_size(config)
    try:
        with output_lock(out_dir):  # two runs never train into one folder
            res = train(config, resume=args.resume, force=args.force)
    finally:
        import torch.distributed as dist

        if dist.is_initialized():  # joined under torchrun: leave the group cleanly
            dist.destroy_process_group()
    if res.broken_checkpoints:
        names = ", ".join(p.name for p in res.broken_checkpoints)
        print(
            f"gamd train: passed over {len(res.broken_checkpoints)} zero-byte, truncated or "
            f"undecodable checkpoint(s) ({names}); resumed from {res.resumed_from} and "
            "trained the steps after it again"
        )
    if res.checkpoint is not None:
        tail = res.losses[-10:]
        mean = sum(tail) / len(tail) if tail else float("nan")
        print(
            f"gamd train: {config.model.name} steps {res.start_step}->{res.end_step} "
            f"in {res.seconds:.1f} s, last-10 mean loss {mean:.4f}, "
            f"checkpoint {res.checkpoint}"
        )
        summary = {
            "model": config.model.name,
            "start_step": res.start_step,
            "end_step": res.end_step,
            "seconds": res.seconds,
            "final_loss_mean10": mean,
            "checkpoint": str(res.checkpoint),
        }
        write_json_atomic(Path(config.train.out_dir) / "summary.json", summary)
    return 0


def _checkpoint(args: argparse.Namespace) -> Path:
    from gamd.weights import shipped_weights

    return Path(args.checkpoint) if args.checkpoint else shipped_weights(args.net)


def _check_limit(limit: int | None) -> None:
    """Refuse a ``--limit`` that is not a positive number of images (before any work)."""
    from gamd.errors import GamdError

    if limit is not None and limit < 1:
        raise GamdError(f"--limit must be a positive number of images, got {limit}")


def _eval(args: argparse.Namespace) -> int:
    from gamd.checkpoint import load_model
    from gamd.data import DeblurDataset
    from gamd.evaluate import evaluate, gain_table, summary_table

    _check_limit(args.limit)
    check_output(args.out, folder=True, force=args.force, input_folders=[args.data, args.heat_root])
    ckpt = _checkpoint(args)
    model, config, step = load_model(ckpt)
    options = config.data.restore_options()
    if args.ensemble is not None:
        options = replace(options, ensemble=args.ensemble)
    dataset = DeblurDataset(
        args.data,
        args.split,
        crop=None,
        augment=False,
        heat_scale_px=config.data.heat_scale_px,
        require_heat=model.uses_heat or options.needs_heat,
        heat_root=args.heat_root,
    )
    lengths = None
    if args.heat_root is not None:  # bins by the true blur, not the perturbed heat maps
        lengths = DeblurDataset(args.data, args.split, crop=None, augment=False, require_heat=False)
    res = evaluate(
        model,
        dataset,
        out_dir=args.out,
        limit=args.limit,
        progress=not args.no_progress,
        options=options,
        length_dataset=lengths,
    )
    print(f"weights: {ckpt} ({config.model.name}, step {step}, self-ensemble {options.ensemble})")
    print(summary_table({f"{config.model.name}@{step}": res}))
    print("gain over the blurred input by median blur length (near-still: < 0.5 px):")
    print(gain_table(res))
    print(f"conventions: {res.conventions}")
    print(f"gamd eval: per-image CSV and summary.json in {args.out}")
    return 0


def _deblur(args: argparse.Namespace) -> int:
    from gamd.infer import deblur_session

    _check_limit(args.limit)
    check_output(args.out, folder=True, force=args.force, input_folders=[args.heat])
    s = deblur_session(
        _checkpoint(args),
        args.session,
        args.heat,
        args.out,
        limit=args.limit,
        skip_missing=args.skip_missing,
        ensemble=args.ensemble,
    )
    skipped = f", {len(s.skipped)} skipped (no heat map)" if s.skipped else ""
    print(
        f"gamd deblur: {len(s.frames)} frames of {args.session} restored by {s.model} "
        f"into {s.out_dir}{skipped}"
    )
    return 0


def _weights_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--checkpoint", default=None, help="checkpoint to use (default: the shipped weights)"
    )
    p.add_argument(
        "--net",
        choices=("gamd", "gamd_only"),
        default="gamd",
        help="which shipped weights without --checkpoint (default gamd)",
    )
    p.add_argument(
        "--ensemble",
        type=int,
        choices=(1, 2, 4, 8),
        default=None,
        help="self-ensemble: average over this many flips/quarter turns (1: off; default: "
        "the weights' own setting, 4 for the shipped ones)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gamd",
        description="Train, evaluate and apply GAMD "
        "and its baselines (MIMO-UNet, MIMO-Pro, Only Net).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    p = sub.add_parser("train", help="train a network from a YAML config")
    p.add_argument("--config", required=True, help="YAML with model, data, train sections")
    p.add_argument(
        "--data",
        default=None,
        help="dataset root (a blurtrack synth dataset); overrides data.root of the config",
    )
    p.add_argument(
        "--resume",
        default=None,
        help="checkpoint to resume from exactly, or 'auto' (OUT/checkpoints/last.pt)",
    )
    p.add_argument("--steps", type=int, default=None, help="override train.steps")
    p.add_argument("--out", default=None, help="override train.out_dir")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--device", choices=("auto", "cpu", "cuda"), default=None, help="override train.device"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="start over in an OUT that already holds a run (replaces it); default: refuse",
    )
    p.set_defaults(func=_train)
    p = sub.add_parser("eval", help="PSNR/SSIM gains of a checkpoint on a dataset split")
    _weights_options(p)
    p.add_argument("--data", required=True, help="dataset root (blurtrack synth or GoPro layout)")
    p.add_argument("--split", default="test")
    p.add_argument(
        "--heat-root",
        default=None,
        help="take heat maps from this dataset root instead (e.g. perturbed calib)",
    )
    p.add_argument("--out", required=True, help="folder for per_image.csv and summary.json")
    p.add_argument("--limit", type=int, default=None, help="only the first N images")
    p.add_argument("--no-progress", action="store_true")
    add_force_arg(p)
    p.set_defaults(func=_eval)
    p = sub.add_parser("deblur", help="deblur a recorded session with predicted heat maps")
    p.add_argument("session", help="session folder")
    _weights_options(p)
    p.add_argument("--heat", default=None, help="output folder of blurtrack predict")
    p.add_argument("--out", required=True)
    p.add_argument("--limit", type=int, default=None)
    p.add_argument(
        "--skip-missing",
        action="store_true",
        help="skip frames without a heat map (predict --skip-uncovered)",
    )
    add_force_arg(p)
    p.set_defaults(func=_deblur)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from blurtrack.cli import run_command

    return run_command("gamd", build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
