"""TrainConfig: every knob of a training run, saved as JSON beside its checkpoints."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from insertnerf_cli.config import ModelConfig, check_field_types, config_from_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.model.checkpoint import read_checkpoint

_SEED_LIMIT = 2 ** 63  # torch.manual_seed takes a signed 64-bit integer


@dataclass(frozen=True)
class TrainConfig:
    """A training run. The number of source views per step is ``model.num_views``, or with ``views_min`` drawn
    per step from views_min..model.num_views.

    Attributes:
        model: the generator's config (stored in every checkpoint).
        steps: total optimisation steps (over all resumed sessions).
        minutes: total wall-time budget in minutes (over all resumed sessions), or None for no limit.
        rays: rays per step, drawn from one target view.
        lr, lr_encoder: Adam learning rates of the NeRF part and of the U-Net encoder (GNT: 5e-4 / 1e-3).
        lr_half_life: steps after which both rates have halved (smooth exponential decay).
        lr_min: floor of the decayed rates.
        resolution: long side in pixels of the training images (aspect ratio kept).
        val_every: steps between validations; val_scenes held-out scenes (at most half of the dataset),
            each validated on val_rays rays of one unseen view.
        ckpt_every: steps between checkpoints (one is also written at the end and on Ctrl-C).
        log_every: steps averaged into one line of metrics.jsonl.
        seed: seeds the model initialisation, the data draws and the hold-out split.
        cache_mb: memory budget of the image cache (validation images, and training images when streamed).
        batch_scenes: scenes per step (B); each gets rays / B rays and its own source views. None: the
            default of the training device (default_batch_scenes), fixed when the run starts.
        data_budget_mb: the training images (uint8) are decoded once and kept on the training device when they
            fit this budget; a larger set is read from disk through the image cache each step (0: always).
        precision: "fp32", or "bf16" for the training step under bf16 autocast (validation stays float32).
            Float32 by default on every device: bf16 was no faster on the CPU (docs/benchmarks.md) and
            is not measured on a GPU yet.
        compile: compile the model's per-scale aggregators with torch.compile (InsertNeRF.compile_aggregation):
            1.3x rays/s on the 2-core CPU (docs/benchmarks.md); off by default, since compiling takes up
            to a minute and needs a C++ compiler.
        views_min: the fewest source views a step draws (None: always model.num_views). Validation uses
            model.num_views.
        guide_prior: place the fine samples as render does with a scene's SfM points, from a sparse prior
            simulated on the true depth of scenes that have it (training/guide.py; needs depth files).
        guide_from: the guide's prior: "depth", each surface ray's own true depth spoilt at random
            (training/guide.py), or "features", the sources' corners lifted by the true depth and splatted into
            the target as render splats SfM points (training/feature_prior.py).
        init: a checkpoint whose weights the run starts from instead of a random initialisation (sample-axis
            tensors resampled when only the sample counts differ: training/warm_start.py); None: random.
    """

    model: ModelConfig = field(default_factory=ModelConfig)
    steps: int = 50_000
    minutes: float | None = None
    rays: int = 512
    lr: float = 5e-4
    lr_encoder: float = 1e-3
    lr_half_life: int = 50_000
    lr_min: float = 1e-5
    resolution: int = 160
    val_every: int = 500
    val_scenes: int = 4
    val_rays: int = 1024
    ckpt_every: int = 1000
    log_every: int = 10
    seed: int = 0
    cache_mb: int = 1024
    batch_scenes: int | None = None
    data_budget_mb: int = 4096
    precision: Literal["fp32", "bf16"] = "fp32"
    compile: bool = False
    init: str | None = None
    views_min: int | None = None
    guide_prior: bool = False
    guide_from: Literal["depth", "features"] = "depth"

    def __post_init__(self) -> None:
        try:
            check_field_types(self)  # e.g. --lr nan, or a string in a hand-edited config.json
        except ValueError as err:
            raise UserError(f"invalid training setting: {err}") from None
        positive = ("steps", "rays", "lr_half_life", "resolution", "val_every", "val_rays", "ckpt_every",
                    "log_every", "cache_mb", "batch_scenes")
        bad = [name for name in positive if getattr(self, name) is not None and getattr(self, name) < 1]
        if bad:
            raise UserError(f"training settings must be positive: {', '.join(f'{n}={getattr(self, n)}' for n in bad)}")
        if self.views_min is not None and not 1 <= self.views_min <= self.model.num_views:
            raise UserError(f"--views-min must be between 1 and the model's num_views ({self.model.num_views}), "
                            f"got {self.views_min}")
        if self.minutes is not None and self.minutes <= 0:
            raise UserError(f"--minutes must be positive, got {self.minutes}")
        if self.data_budget_mb < 0:
            raise UserError(f"--data-budget-mb must be 0 (always read from disk) or more, got {self.data_budget_mb}")
        if min(self.lr, self.lr_encoder) <= 0 or self.lr_min < 0 or self.val_scenes < 0:
            raise UserError(f"learning rates must be positive, lr_min and val_scenes >= 0; got lr={self.lr}, "
                            f"lr_encoder={self.lr_encoder}, lr_min={self.lr_min}, val_scenes={self.val_scenes}")
        if not 0 <= self.seed < _SEED_LIMIT:
            raise UserError(f"--seed must be between 0 and {_SEED_LIMIT - 1} (torch's seed range), got {self.seed}")

    def learning_rate(self, base: float, step: int) -> float:
        """base * 0.5 ** (step / lr_half_life), not below lr_min (docs/method.md, Training)."""
        return max(base * 0.5 ** (step / self.lr_half_life), min(self.lr_min, base))


# Changing these on --resume keeps training valid but the run no longer matches an uninterrupted one.
DATA_FIELDS = ("rays", "resolution", "seed", "lr", "lr_encoder", "lr_half_life", "lr_min", "val_scenes",
               "batch_scenes", "views_min", "guide_prior", "guide_from")

# Scenes per step when --batch-scenes is not given. CPU: measured (docs/benchmarks.md). CUDA: not measured;
# 4 keeps B * V = 32 images per encoder call.
_DEFAULT_BATCH_SCENES = {"cpu": 1, "cuda": 4}


def default_batch_scenes(device: torch.device) -> int:
    return _DEFAULT_BATCH_SCENES.get(device.type, 1)


def with_device_defaults(config: TrainConfig, device: torch.device) -> TrainConfig:
    """``config`` with its per-device defaults fixed (so the saved config says what the run used)."""
    if config.batch_scenes is not None:
        return config
    return dataclasses.replace(config, batch_scenes=default_batch_scenes(device))


def with_overrides(config: TrainConfig, model: dict[str, Any], train: dict[str, Any]) -> TrainConfig:
    """``config`` with the given ModelConfig and TrainConfig fields replaced (None values are ignored).

    A ``train["model"]`` replaces the whole model config before the single ``model`` fields are applied.
    """
    train_changes = {k: v for k, v in train.items() if v is not None}
    base_model = train_changes.pop("model", config.model)
    try:
        new_model = dataclasses.replace(base_model, **{k: v for k, v in model.items() if v is not None})
    except (TypeError, ValueError) as err:
        raise UserError(f"invalid model setting: {err}") from None
    return dataclasses.replace(config, model=new_model, **train_changes)


def model_differences(a: ModelConfig, b: ModelConfig) -> list[str]:
    """'name: a -> b' for every ModelConfig field that differs."""
    return [f"{f.name}: {getattr(a, f.name)!r} -> {getattr(b, f.name)!r}"
            for f in dataclasses.fields(ModelConfig) if getattr(a, f.name) != getattr(b, f.name)]


def read_model_config(path: Path) -> ModelConfig:
    """A ModelConfig from a JSON file: its fields, or a run's checkpoints/config.json (its "model" entry)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise UserError(f"model config {path} cannot be read as JSON ({err}).") from None
    if isinstance(data, dict) and isinstance(data.get("model"), dict):
        data = data["model"]
    try:
        return config_from_json(ModelConfig, data)
    except UserError as err:
        raise UserError(f"model config {path}: {err}; fix the file.") from None


def saved_train_config(checkpoint_path: Path) -> TrainConfig:
    """The TrainConfig stored in a run's checkpoint (the base that --resume overrides with given flags)."""
    if not Path(checkpoint_path).is_file():
        raise UserError(f"nothing to resume: {checkpoint_path} does not exist; start a new run without --resume.")
    state = read_checkpoint(checkpoint_path).train_state
    if state is None:
        raise UserError(f"{checkpoint_path} holds weights only (no optimizer or step); it cannot be resumed.")
    return config_from_json(TrainConfig, json.loads(state.train_config))
