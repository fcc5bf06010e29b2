"""Training-run configuration: three sections whose keys are constructor arguments.

```yaml
model: {name: gamd, preset: tiny}          # + any constructor argument, e.g. num_res: 2
data: {root: DATASET, split: train, crop: 64, heat_scale_px: 16.0, augment: true}
train: {out_dir: runs/gamd, steps: 200, batch_size: 4, lr: 1.0e-4, milestones: [100],
        gamma: 0.5, seed: 0, loss: auto}
```
``model`` keys (besides ``name`` and ``preset``) go to the network's constructor, ``data``
keys to :class:`gamd.data.DeblurDataset`, ``train`` keys to :class:`TrainConfig`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from blurtrack.io.atomic import write_text_atomic
from blurtrack.io.yamlio import dump_yaml, parse_yaml, yaml_error_line
from gamd.errors import GamdConfigError
from gamd.heat import DEFAULT_HEAT_SCALE_PX
from gamd.losses import LOSSES
from gamd.nets import NETWORKS, model_kwargs
from gamd.restorer import RestoreOptions, check_restore_options


@dataclass(frozen=True)
class ModelConfig:
    """Which network and its constructor arguments (``kwargs`` override the preset)."""

    name: str
    preset: str | None = "tiny"
    kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in NETWORKS:
            raise GamdConfigError(f"unknown network {self.name!r} (known: {sorted(NETWORKS)})")
        model_kwargs(self.name, self.preset, **self.kwargs)  # validates the preset name

    def resolved_kwargs(self) -> dict[str, Any]:
        return model_kwargs(self.name, self.preset, **self.kwargs)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "preset": self.preset, **self.kwargs}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        d = dict(d)
        if "name" not in d:
            raise GamdConfigError("model section needs a 'name'")
        return cls(name=d.pop("name"), preset=d.pop("preset", "tiny"), kwargs=d)


@dataclass(frozen=True)
class DataConfig:
    """Arguments of :class:`gamd.data.DeblurDataset` for the training split."""

    root: str
    split: str = "train"
    crop: int | None = 64
    augment: bool = True
    heat_scale_px: float = DEFAULT_HEAT_SCALE_PX
    #: Restore at a working resolution where the blur is about this long (px); None: full size.
    work_blur_px: float | None = None
    #: Do-no-harm gate [lo, hi] (px of blur length): output = input below lo; None: no gate.
    gate_px: tuple[float, float] | None = None
    #: Resample off-centre (rolling-shutter) blur to the reference view (gamd.restorer.recentre).
    recentre: bool = True
    #: Inference only: self-ensemble size (1, 2, 4, 8; gamd.restorer.ensemble_forward).
    ensemble: int = 1

    def __post_init__(self) -> None:
        if not self.root:
            raise GamdConfigError("data.root is required")
        try:
            check_restore_options(
                self.heat_scale_px, self.work_blur_px, self.gate_px, self.ensemble
            )
        except GamdConfigError as exc:
            raise GamdConfigError(f"data.{exc}") from None
        if self.gate_px is not None:
            object.__setattr__(self, "gate_px", tuple(float(v) for v in self.gate_px))
        if not isinstance(self.recentre, bool):
            raise GamdConfigError(f"data.recentre must be true or false, got {self.recentre!r}")
        if self.crop is not None and (
            not isinstance(self.crop, int) or self.crop < 8 or self.crop % 4
        ):
            raise GamdConfigError(f"data.crop must be a multiple of 4 >= 8, got {self.crop!r}")

    def restore_options(self) -> RestoreOptions:
        """How inference must present images to a network trained on this data."""
        return RestoreOptions(
            self.heat_scale_px, self.work_blur_px, self.gate_px, self.recentre, self.ensemble
        )


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings: Adam, a multi-step or cosine learning rate, logging and
    checkpoints."""

    out_dir: str
    steps: int = 1000
    batch_size: int = 4
    lr: float = 1e-4
    milestones: tuple[int, ...] = ()
    gamma: float = 0.5
    #: Learning-rate schedule: "step" (x gamma at each milestone) or "cosine" (from lr down to
    #: lr_min over the run's steps; milestones must then be empty).
    schedule: str = "step"
    lr_min: float = 0.0
    seed: int = 0
    loss: str = "auto"
    omega: float = 0.6
    fft_weight: float = 0.1
    checkpoint_every: int = 500
    log_every: int = 10
    num_workers: int = 0
    threads: int | None = None
    device: str = "auto"
    progress: bool = True
    tensorboard: bool = True
    #: Mixed precision: "off" or "bf16" (autocast on CUDA and CPU; weights stay float32).
    amp: str = "off"
    #: channels_last memory format for the network and its inputs (faster convs on GPUs).
    channels_last: bool = False
    #: Start from the weights of this checkpoint (fine-tuning; optimiser and step start fresh).
    init_from: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "milestones", tuple(int(m) for m in self.milestones))
        for name in ("steps", "batch_size", "checkpoint_every", "log_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise GamdConfigError(f"train.{name} must be a positive int, got {value!r}")
        if not self.lr > 0 or not 0 < self.gamma <= 1:
            raise GamdConfigError("train.lr must be > 0 and train.gamma in (0, 1]")
        if list(self.milestones) != sorted(self.milestones) or any(m < 1 for m in self.milestones):
            raise GamdConfigError(
                f"train.milestones must be increasing steps >= 1, got {list(self.milestones)}"
            )
        if self.schedule not in ("step", "cosine"):
            raise GamdConfigError(f"train.schedule must be step or cosine, got {self.schedule!r}")
        if self.schedule == "cosine" and self.milestones:
            raise GamdConfigError("train.milestones must be empty with schedule cosine")
        if not 0 <= self.lr_min < self.lr:
            raise GamdConfigError(f"train.lr_min must be in [0, lr), got {self.lr_min!r}")
        if self.loss != "auto" and self.loss not in LOSSES:
            raise GamdConfigError(f"train.loss must be auto or one of {sorted(LOSSES)}")
        if self.num_workers < 0:
            raise GamdConfigError("train.num_workers must be >= 0")
        if self.amp not in ("off", "bf16"):
            raise GamdConfigError(f"train.amp must be off or bf16, got {self.amp!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise GamdConfigError(f"train.device must be auto, cpu or cuda, got {self.device!r}")


def _build(cls: type, section: str, d: Any) -> Any:
    if not isinstance(d, dict):
        raise GamdConfigError(f"config section {section!r} must be a mapping")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise GamdConfigError(f"unknown keys in {section}: {unknown} (known: {sorted(known)})")
    try:
        return cls(**d)
    except TypeError as exc:
        raise GamdConfigError(f"{section}: {exc}") from exc


@dataclass(frozen=True)
class RunConfig:
    """A whole training run."""

    model: ModelConfig
    data: DataConfig
    train: TrainConfig

    @property
    def loss_name(self) -> str:
        if self.train.loss != "auto":
            return self.train.loss
        return "mimo" if self.model.name.startswith("mimo") else "gamd"

    def to_dict(self) -> dict[str, Any]:
        train = asdict(self.train)
        train["milestones"] = list(self.train.milestones)
        data = asdict(self.data)
        if data["gate_px"] is not None:
            data["gate_px"] = list(data["gate_px"])
        return {"model": self.model.to_dict(), "data": data, "train": train}

    @classmethod
    def from_dict(cls, d: Any) -> RunConfig:
        if not isinstance(d, dict) or set(d) - {"model", "data", "train"}:
            raise GamdConfigError("a config is a mapping with sections model, data, train")
        for s in ("model", "data", "train"):
            if not isinstance(d.get(s), dict):
                raise GamdConfigError(f"config section {s!r} is missing or not a mapping")
        return cls(
            model=ModelConfig.from_dict(d["model"]),
            data=_build(DataConfig, "data", d["data"]),
            train=_build(TrainConfig, "train", d["train"]),
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> RunConfig:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise GamdConfigError(f"cannot read config {path}: {exc}") from exc
        try:
            d = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise GamdConfigError(f"{path}: invalid YAML: {yaml_error_line(exc)}") from None
        return cls.from_dict(d)

    def to_yaml(self, path: str | Path) -> None:
        write_text_atomic(path, dump_yaml(self.to_dict(), sort_keys=False))
