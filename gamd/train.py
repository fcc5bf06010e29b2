"""Training as a plain function: Adam, multi-step or cosine learning rate, exact resume, CSV and
TensorBoard logs, a progress bar, and data-parallel training under ``torchrun``.

Distributed: when ``WORLD_SIZE > 1`` (torchrun sets it), :func:`train` joins the process group
(NCCL on CUDA, gloo on CPU), wraps the network in ``DistributedDataParallel`` and gives each
rank its slice of the global batch (:class:`gamd.data.StepBatchSampler`), so
``batch_size`` is per process and the same config scales out unchanged. Rank 0 writes logs
and checkpoints.
"""

from __future__ import annotations

import csv
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader
from tqdm import tqdm

from gamd.checkpoint import load_checkpoint, load_model, save_checkpoint
from gamd.config import RunConfig, TrainConfig
from gamd.data import DeblurDataset, StepBatchSampler
from gamd.errors import CheckpointError, GamdConfigError, GamdDataError
from gamd.losses import LOSSES
from gamd.nets import DeblurNet, build_model
from gamd.restorer import apply_gate

LOG_FIELDS = ("step", "loss", "lr", "seconds")


@dataclass(frozen=True)
class TrainResult:
    """Outcome of :func:`train`: per-step losses of this invocation (mean over ranks)."""

    out_dir: Path
    start_step: int
    end_step: int
    losses: list[float] = field(default_factory=list)
    checkpoint: Path | None = None
    seconds: float = 0.0
    #: ``--resume auto``: the checkpoint resumed from and the broken ones passed over.
    resumed_from: Path | None = None
    broken_checkpoints: tuple[Path, ...] = ()
    model: DeblurNet | None = field(default=None, repr=False)


def _setup_distributed(device_kind: str) -> tuple[int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device_kind == "cuda" else "gloo")
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _device(kind: str) -> torch.device:
    if kind == "cuda" and not torch.cuda.is_available():
        raise GamdConfigError(
            "train.device is cuda but no CUDA device is available (use --device cpu or auto)"
        )
    if kind == "cuda" or (kind == "auto" and torch.cuda.is_available()):
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return torch.device("cpu")


def _read_log(path: Path, upto_step: int) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return [row for row in csv.DictReader(f) if int(row["step"]) <= upto_step]


def checkpoint_path(out_dir: str | Path, name: str = "last") -> Path:
    return Path(out_dir) / "checkpoints" / f"{name}.pt"


RUN_FILES = ("config.yaml", "train_log.csv", "checkpoints", "tensorboard", "summary.json")


def check_training_size(config: RunConfig) -> None:
    """Refuse absurd network widths/depths, batches and crops before anything is allocated
    (:func:`blurtrack.io.bounds.check_training_size`: above half of this machine's memory)."""
    from blurtrack.io import bounds

    kw = config.model.resolved_kwargs()
    c, r = kw.get("base_channels", 32), kw.get("num_res", 8)
    if isinstance(c, int) and isinstance(r, int) and c > 0 and r >= 0:  # else the net refuses
        bounds.check_training_size(c, r, config.train.batch_size, config.data.crop)


def _auto_resume(out_dir: Path) -> tuple[Path | None, dict | None, tuple[Path, ...]]:
    """``--resume auto``: the newest complete checkpoint of ``out_dir`` (``last.pt``, else the
    newest ``step_*.pt``), its state, and the broken ones passed over (zero-byte, truncated,
    undecodable). No checkpoint at all: ``(None, None, ())``; only broken ones: refused."""
    folder = checkpoint_path(out_dir).parent
    candidates = [checkpoint_path(out_dir), *sorted(folder.glob("step_*.pt"), reverse=True)]
    broken: list[Path] = []
    for path in candidates:
        if not path.is_file():
            continue
        try:
            return path, load_checkpoint(path), tuple(broken)
        except CheckpointError:
            broken.append(path)
    if broken:
        raise CheckpointError(
            f"--resume auto: no complete checkpoint in {folder} ({len(broken)} zero-byte, "
            "truncated or undecodable); --force starts over"
        )
    return None, None, ()


def _refuse_existing_run(out_dir: Path) -> None:
    found = [name for name in RUN_FILES if (out_dir / name).exists()]
    if found:
        raise CheckpointError(
            f"{out_dir} already holds a training run ({', '.join(found)}): pass --resume auto "
            "to continue it, or --force to start over and replace it"
        )


def _restore_state(state: dict, model, optimizer, scheduler, device, path) -> int:
    """Load a resume checkpoint's states; one-line errors for malformed fields."""
    try:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        torch.set_rng_state(state["rng_cpu"])
        if device.type == "cuda" and "rng_cuda" in state:
            torch.cuda.set_rng_state(state["rng_cuda"], device)
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: malformed resume state: {msg}") from None
    return int(state["step"])


def build_scheduler(
    optimizer: torch.optim.Optimizer, tc: TrainConfig
) -> torch.optim.lr_scheduler.LRScheduler:
    """The learning-rate schedule of ``tc``, stepped once per training step."""
    if tc.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, tc.steps, tc.lr_min)
    return torch.optim.lr_scheduler.MultiStepLR(optimizer, list(tc.milestones), tc.gamma)


def train(config: RunConfig, resume: str | Path | None = None, force: bool = False) -> TrainResult:
    """Train ``config``'s network for ``config.train.steps`` steps (total, resume included).

    ``resume``: a checkpoint to continue from exactly (weights, optimiser, scheduler, RNG
    states, step), or ``"auto"`` for ``out_dir/checkpoints/last.pt`` if it exists. Without
    ``resume``, an ``out_dir`` that already holds a run is refused unless ``force``.
    """
    tc = config.train
    if tc.threads:
        torch.set_num_threads(tc.threads)
    device = _device(tc.device)
    if device.type == "cuda":  # before NCCL starts: each rank's collectives on its own GPU
        torch.cuda.set_device(device)
    rank, world = _setup_distributed(device.type)
    out_dir = Path(tc.out_dir)

    if resume is None and not force and rank == 0:
        _refuse_existing_run(out_dir)
    check_training_size(config)
    torch.manual_seed(tc.seed)
    model = build_model(config.model.name, config.model.preset, **config.model.kwargs)
    if tc.init_from is not None:
        init_model, _, _ = load_model(tc.init_from)
        if type(init_model) is not type(model):
            raise CheckpointError(f"{tc.init_from}: holds {type(init_model).__name__}")
        try:
            model.load_state_dict(init_model.state_dict())
        except RuntimeError as exc:
            raise CheckpointError(
                f"{tc.init_from}: weights do not fit: {str(exc).splitlines()[0]}"
            ) from None
    model.to(device)
    if tc.channels_last:
        model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # torch stubs omit memory_format for Module.to
    options = config.data.restore_options()
    dataset = DeblurDataset(
        config.data.root,
        config.data.split,
        crop=config.data.crop,
        augment=config.data.augment,
        heat_scale_px=config.data.heat_scale_px,
        require_heat=model.uses_heat or options.needs_heat,
        work_blur_px=config.data.work_blur_px,
        recentre=config.data.recentre,
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=tc.lr)
    scheduler = build_scheduler(optimizer, tc)

    start = 0
    broken: tuple[Path, ...] = ()
    state = None
    if resume == "auto":
        resume, state, broken = _auto_resume(out_dir)
    if resume is not None:
        state = load_checkpoint(resume) if state is None else state
        if state["config"].get("model") != config.model.to_dict():
            raise CheckpointError(
                f"{resume}: checkpoint was trained with model "
                f"{state['config'].get('model')}, config asks for "
                f"{config.model.to_dict()}"
            )
        start = _restore_state(state, model, optimizer, scheduler, device, resume)
    if start > tc.steps:
        raise CheckpointError(f"checkpoint is at step {start}, beyond train.steps={tc.steps}")

    net: torch.nn.Module = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None
        )
    sampler = StepBatchSampler(
        len(dataset),
        tc.batch_size,
        tc.steps,
        tc.seed,
        start_step=start,
        rank=rank,
        world_size=world,
    )
    loader = DataLoader(
        dataset, batch_sampler=sampler, num_workers=tc.num_workers, pin_memory=device.type == "cuda"
    )
    loss_fn = LOSSES[config.loss_name]
    loss_kw = {"omega": tc.omega} if config.loss_name == "gamd" else {"fft_weight": tc.fft_weight}

    writer = log_file = log_writer = None
    if rank == 0:
        out_dir.mkdir(parents=True, exist_ok=True)
        config.to_yaml(out_dir / "config.yaml")
        log_path = out_dir / "train_log.csv"
        kept = _read_log(log_path, start)
        log_file = log_path.open("w", newline="")
        log_writer = csv.DictWriter(log_file, fieldnames=LOG_FIELDS)
        log_writer.writeheader()
        log_writer.writerows(kept)
        if tc.tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(out_dir / "tensorboard"), purge_step=start + 1)

    def save(step: int) -> Path:
        state = {
            "config": config.to_dict(),
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            "step": step,
            "rng_cpu": torch.get_rng_state(),
        }
        if device.type == "cuda":
            state["rng_cuda"] = torch.cuda.get_rng_state(device)
        path = save_checkpoint(checkpoint_path(out_dir), state)
        save_checkpoint(checkpoint_path(out_dir, f"step_{step:07d}"), state)
        return path

    fmt = torch.channels_last if tc.channels_last else torch.contiguous_format
    losses: list[float] = []
    last_ckpt = None
    t0 = time.perf_counter()
    bar = tqdm(
        total=tc.steps,
        initial=start,
        disable=not tc.progress or rank != 0 or not sys.stderr.isatty(),  # terminals only
        desc=f"train {config.model.name}",
        unit="step",
        dynamic_ncols=True,
    )
    try:
        model.train()
        for step, batch in enumerate(loader, start=start + 1):
            blur = batch["blur"].to(device, non_blocking=True, memory_format=fmt)
            sharp = batch["sharp"].to(device, non_blocking=True, memory_format=fmt)
            heat = batch["heat"].to(device, non_blocking=True, memory_format=fmt)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=tc.amp == "bf16"):
                outputs = net(blur, heat if model.uses_heat else None)
            outputs = [o.float() for o in outputs]
            if options.gate_px is not None:  # the do-no-harm gate inference applies
                heat_px = heat * config.data.heat_scale_px
                outputs[0] = apply_gate(outputs[0], blur, heat_px, options.gate_px)
            loss = loss_fn(outputs, sharp, model.OUTPUT_SCALES, **loss_kw)
            if not torch.isfinite(loss):
                raise GamdDataError(f"loss is {loss.item()} at step {step}")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            lr = optimizer.param_groups[0]["lr"]
            scheduler.step()
            value = loss.detach()
            if world > 1:
                dist.all_reduce(value)
                value = value / world
            losses.append(float(value))
            bar.update(1)
            if rank == 0 and log_writer is not None and log_file is not None:
                log_writer.writerow(
                    {
                        "step": step,
                        "loss": f"{losses[-1]:.8g}",
                        "lr": f"{lr:.6g}",
                        "seconds": f"{time.perf_counter() - t0:.3f}",
                    }
                )
                if step % tc.log_every == 0:
                    log_file.flush()
                    bar.set_postfix(loss=f"{losses[-1]:.4f}")
                    if writer is not None:
                        writer.add_scalar("train/loss", losses[-1], step)
                        writer.add_scalar("train/lr", lr, step)
                if step % tc.checkpoint_every == 0 or step == tc.steps:
                    last_ckpt = save(step)
    finally:
        bar.close()
        if log_file is not None:
            log_file.close()
        if writer is not None:
            writer.close()
    if rank == 0 and start == tc.steps:
        last_ckpt = checkpoint_path(out_dir)
    if world > 1:
        dist.barrier()
    return TrainResult(
        out_dir=out_dir,
        start_step=start,
        end_step=tc.steps,
        losses=losses,
        checkpoint=last_ckpt,
        seconds=time.perf_counter() - t0,
        model=model,
        resumed_from=None if resume is None else Path(resume),
        broken_checkpoints=broken,
    )
