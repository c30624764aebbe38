"""Checkpoints: the model's weights, its config as JSON and (for training runs) the state needed to resume.

A checkpoint holds tensors and plain Python types only, so it loads with ``torch.load(weights_only=True)``
and loading one cannot run code. It is written to a temporary file and renamed, so an interrupt never
leaves a half-written checkpoint under the final name. The model is always rebuilt from the config stored
in the checkpoint, never from command-line flags.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from insertnerf_cli import __version__
from insertnerf_cli.config import ModelConfig, config_from_json, config_to_json
from insertnerf_cli.errors import UserError, first_line
from insertnerf_cli.files.atomic import atomic_path
from insertnerf_cli.files.outdir import BUNDLED_WEIGHTS_DIR
from insertnerf_cli.model.insertnerf import InsertNeRF

CHECKPOINT_FORMAT = "insertnerf-checkpoint"
CHECKPOINT_VERSION = 1
# The pretrained generators shipped in the package, by the name `--model` takes (docs/model-card.md). fast is the
# default: 2.5x faster than full and as good on real captures and procedural scenes (docs/benchmarks.md).
BUNDLED_MODELS = {"fast": "insertnerf-fast.pt", "full": "insertnerf.pt"}
DEFAULT_MODEL = "fast"
# The bundled generators of the NeRF++ backbone (ModelConfig.backbone "nerfpp": a foreground field inside a sphere
# and an inverted-sphere background field), by the same --model names. The NeRF backbone stays the default
# everywhere: the NeRF++ one does not yet score higher on 360-degree captures (docs/model-card.md).
BUNDLED_NERFPP_MODELS = {"fast": "insertnerf-fast-nerfpp.pt"}
BUNDLED_BY_BACKBONE = {"nerf": BUNDLED_MODELS, "nerfpp": BUNDLED_NERFPP_MODELS}
DEFAULT_BACKBONE = "nerf"


@dataclass(frozen=True)
class TrainState:
    """What a training run needs besides the weights to continue exactly where it stopped.

    Attributes:
        step: optimisation steps done.
        elapsed_s: wall time spent training so far, summed over resumed sessions.
        optimizer: ``optimizer.state_dict()`` (tensors and plain types).
        rng: random-generator states as tensors (python, numpy, torch, data sampler).
        train_config: the run's TrainConfig as a JSON string.
        best_val_psnr: best validation PSNR so far (dB), or None before the first validation.
    """

    step: int
    elapsed_s: float
    optimizer: dict[str, Any]
    rng: dict[str, Tensor]
    train_config: str
    best_val_psnr: float | None = None


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint read from disk and checked."""

    path: Path
    version: int
    model_config: ModelConfig
    model_state: dict[str, Tensor]
    train_state: TrainState | None


def save_checkpoint(path: str | Path, model: nn.Module, model_config: ModelConfig,
                    train_state: TrainState | None = None) -> Path:
    """Write ``model``'s weights, its config and optionally a TrainState to ``path`` atomically.

    Args:
        model: the InsertNeRF (unwrapped from DistributedDataParallel by the caller).
        model_config: the config the model was built from; stored as JSON.
    Returns:
        the path written.
    Raises:
        WriteError: the disk is full or the folder not writable (a previous file at ``path`` is kept).
    """
    payload: dict[str, Any] = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "insertnerf_version": __version__,
        "model_config": config_to_json(model_config),  # a dict of plain types
        "model": {name: t.detach().cpu() for name, t in model.state_dict().items()},
    }
    if train_state is not None:
        payload["train"] = {
            "step": int(train_state.step),
            "elapsed_s": float(train_state.elapsed_s),
            "optimizer": train_state.optimizer,
            "rng": {name: t.detach().cpu() for name, t in train_state.rng.items()},
            "train_config": train_state.train_config,
            "best_val_psnr": None if train_state.best_val_psnr is None else float(train_state.best_val_psnr),
        }
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        # Through a Python file, a full disk surfaces as an OSError (behind torch's RuntimeError), which
        # atomic_path turns into a one-line WriteError; the previous checkpoint under ``path`` is kept.
        torch.save(payload, handle)
    return path


def read_checkpoint(path: str | Path) -> Checkpoint:
    """Load and check a checkpoint (CPU tensors); anything wrong with it becomes a one-line UserError."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"checkpoint {path} does not exist; pass the .pt file written by `insertnerf train`.")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for truncated, non-zip or unsafe files
        raise UserError(f"checkpoint {path} cannot be read ({first_line(err)}); it is corrupt or not an "
                        "insertnerf checkpoint: pass another one, or retrain.") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{path} is not an insertnerf checkpoint (no '{CHECKPOINT_FORMAT}' marker).")
    version = payload.get("version")
    if not isinstance(version, int) or version > CHECKPOINT_VERSION:
        raise UserError(f"checkpoint {path} has format version {version!r}, this insertnerf {__version__} reads "
                        f"up to {CHECKPOINT_VERSION}: upgrade insertnerf or retrain.")
    try:
        config = config_from_json(ModelConfig, payload["model_config"])
        state = payload["model"]
        train = payload.get("train")
        train_state = None if train is None else TrainState(**train)
    except Exception as err:
        raise UserError(f"checkpoint {path} was written by an incompatible insertnerf version "
                        f"({first_line(err)}); retrain it with this version.") from None
    return Checkpoint(path, version, config, state, train_state)


def build_model(checkpoint: Checkpoint, device: torch.device) -> nn.Module:
    """The InsertNeRF described by the checkpoint's config, with its weights, on ``device``."""
    try:
        model = InsertNeRF(checkpoint.model_config)
    except Exception as err:
        raise UserError(f"checkpoint {checkpoint.path} describes a model this version cannot build "
                        f"({first_line(err)}); retrain it with this version.") from None
    load_weights(model, checkpoint)
    return model.to(device)


def load_weights(model: nn.Module, checkpoint: Checkpoint) -> None:
    """Copy the checkpoint's weights into ``model``; a mismatch in names or shapes becomes a UserError."""
    own = model.state_dict()
    theirs = checkpoint.model_state
    missing = sorted(set(own) - set(theirs))
    unexpected = sorted(set(theirs) - set(own))
    reshaped = sorted(n for n in set(own) & set(theirs) if own[n].shape != theirs[n].shape)
    if missing or unexpected or reshaped:
        example = (missing or unexpected or reshaped)[0]
        raise UserError(f"checkpoint {checkpoint.path} does not fit the model its config describes "
                        f"({len(missing)} missing, {len(unexpected)} unexpected, {len(reshaped)} reshaped "
                        f"tensors, e.g. {example!r}); it comes from an incompatible version: retrain it.")
    model.load_state_dict(theirs)


def load_model(path: str | Path, device: torch.device) -> tuple[nn.Module, ModelConfig]:
    """Rebuild the model from a checkpoint's own config and load its weights, in eval mode on ``device``."""
    checkpoint = read_checkpoint(path)
    model = build_model(checkpoint, device)
    model.eval()
    return model, checkpoint.model_config


def bundled_checkpoint(model: str = DEFAULT_MODEL, backbone: str = DEFAULT_BACKBONE) -> Path:
    """A pretrained generator shipped in the package: "fast" (32+16 samples, the default) or "full" (64+64), of
    the NeRF backbone (the default) or the NeRF++ one."""
    files = BUNDLED_BY_BACKBONE[backbone]
    if model not in files:
        raise UserError(f"no bundled {model} generator has the {backbone} backbone (bundled with it: "
                        f"{', '.join(sorted(files))}); pass --model {sorted(files)[0]}, or a --checkpoint trained "
                        f"with backbone {backbone} in its model config.")
    path = BUNDLED_WEIGHTS_DIR / files[model]
    if not path.is_file():
        raise UserError(f"this install has no bundled {model} weights ({path} is missing); pass "
                        "--checkpoint RUN_DIR/checkpoints/last.pt from `insertnerf train`.")
    return path


def checkpoint_sha256(path: Path) -> str:
    """The SHA-256 of a checkpoint file: what render records to tell whose weights made its frames."""
    if not path.is_file():
        raise UserError(f"checkpoint {path} does not exist; pass --checkpoint with a file from `insertnerf train`")
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# Config fields that change how trained weights render, not what they are: set at export without retraining.
INFERENCE_FIELDS = ("colour_prior_views", "sample_views", "consistency_temperature_coarse",
                    "consistency_temperature_fine", "consistency_views")


def export_weights(source: str | Path, destination: str | Path, **inference: int | float) -> Path:
    """Write the weights and config of a training checkpoint without its optimizer and RNG state.

    This is how the bundled ``weights/insertnerf.pt`` is made from a run's checkpoint: a third of the size,
    and nothing in it but what ``load_model`` needs. ``inference`` overrides INFERENCE_FIELDS of the config
    (e.g. sample_views=12); any other field would no longer match the weights, so it is refused.
    """
    unknown = sorted(set(inference) - set(INFERENCE_FIELDS))
    if unknown:
        raise ValueError(f"only {', '.join(INFERENCE_FIELDS)} can change at export, not {', '.join(unknown)}")
    checkpoint = read_checkpoint(source)
    model = build_model(checkpoint, torch.device("cpu"))
    return save_checkpoint(destination, model, replace(checkpoint.model_config, **inference))


def average_weights(sources: list[str | Path], destination: str | Path, shares: list[float] | None = None) -> Path:
    """Write the weighted mean of generators that share one model config (a "model soup").

    Runs warm-started from one generator and trained on the same data with other seeds stay in one basin, so
    their mean is a model too, at times better than each (Wortsman et al., 2022; here it landed between its
    parts: docs/research-log.md, Training data and the generator). Floating-point tensors are averaged (in
    float64); integer buffers (counters) come from the first source. ``shares``: one non-negative number per
    source (default: equal), normalised to sum to 1.
    """
    shares = [1.0] * len(sources) if shares is None else list(shares)
    if not sources or len(shares) != len(sources) or min(shares) < 0 or sum(shares) <= 0:
        raise UserError("averaging needs one or more checkpoints and one non-negative share each, not all zero.")
    checkpoints = [read_checkpoint(s) for s in sources]
    first = checkpoints[0]
    for other in checkpoints[1:]:
        if other.model_config != first.model_config:
            raise UserError(f"{other.path} has another model config than {first.path}; only generators of one "
                            "config (inference fields included) can be averaged.")
        if {n: t.shape for n, t in other.model_state.items()} != {n: t.shape for n, t in first.model_state.items()}:
            raise UserError(f"{other.path} holds other tensors than {first.path} under the same config; it is "
                            "damaged or from another version: export it again.")
    total = sum(shares)
    state = {}
    for name, tensor in first.model_state.items():
        if tensor.is_floating_point():
            mean = sum(s / total * c.model_state[name].double() for s, c in zip(shares, checkpoints))
            state[name] = mean.to(tensor.dtype)
        else:
            state[name] = tensor
    model = build_model(replace(first, model_state=state), torch.device("cpu"))
    return save_checkpoint(destination, model, first.model_config)
