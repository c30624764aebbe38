"""Setting up a training session: run folder, scenes, model, optimizer, and what --resume restores."""
from __future__ import annotations

import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import Tensor, nn

from insertnerf_cli.cameras.rays import Rays
from insertnerf_cli.config import config_to_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.files.atomic import WriteError
from insertnerf_cli.files.lock import lock_output
from insertnerf_cli.model import InsertNeRF, LossTerms, SourceViews
from insertnerf_cli.model.checkpoint import Checkpoint, TrainState, load_weights, read_checkpoint, save_checkpoint
from insertnerf_cli.training import distributed
from insertnerf_cli.training.batches import BatchObjective, DrawGenerators, StepStream, check_batch_scenes
from insertnerf_cli.training.config import DATA_FIELDS, TrainConfig, model_differences
from insertnerf_cli.training.data import (
    ImageCache,
    TrainScene,
    ViewDraw,
    check_view_counts,
    find_scenes,
    split_scenes,
    validation_draws,
)
from insertnerf_cli.training.device_data import TrainingSet, load_training_set
from insertnerf_cli.training.distributed import DistContext
from insertnerf_cli.training.feature_prior import FeaturePriors
from insertnerf_cli.training.rng import capture_rng, restore_rng
from insertnerf_cli.training.run_dir import (
    OWNER,
    RunFiles,
    check_run_dir,
    claim_run,
    clear_run,
    read_splits,
    truncate_metrics,
    write_run_config,
    write_splits,
)
from insertnerf_cli.training.warm_start import warm_start

Say = Callable[[str], None]
_BYTES_PER_MB = 1 << 20


@dataclass
class Session:
    """Everything one training session works with; ``step``, ``best_val_psnr`` and ``saved_step`` change."""

    config: TrainConfig
    files: RunFiles
    ctx: DistContext
    model: InsertNeRF
    optimizer: torch.optim.Optimizer
    data_rng: np.random.Generator
    train_scenes: list[TrainScene]
    val_scenes: list[TrainScene]
    val_draws: list[ViewDraw]
    cache: ImageCache
    say: Say
    data: TrainingSet  # the training scenes as tensors (on the device when they fit the budget)
    generators: DrawGenerators  # the step draws (data_rng serves the legacy draw_training_views)
    step: int = 0
    elapsed_before: float = 0.0  # training seconds of earlier sessions of this run
    best_val_psnr: float | None = None
    saved_step: int | None = None  # step of the newest checkpoint on disk
    start_step: int = 0
    objective: nn.Module | None = None  # BatchObjective(model), wrapped in DistributedDataParallel under torchrun
    stream: StepStream | None = None  # the step batches, made after the generators are restored


class Objective(nn.Module):
    """The training loss of one batch, as one module so DistributedDataParallel can wrap all of it."""

    def __init__(self, model: InsertNeRF) -> None:
        super().__init__()
        self.model = model

    def forward(self, views: SourceViews, rays: Rays, target_rgb: Tensor, guide: Tensor | None = None) -> LossTerms:
        """``guide`` [R]: a depth per ray that the fine samples follow (InsertNeRF.forward), or None."""
        encoded = self.model.encode(views)
        output = self.model(encoded, rays, train=True, guide=guide)
        return self.model.losses(output, target_rgb, encoded)


def open_session(dataset_dir: Path, files: RunFiles, config: TrainConfig, ctx: DistContext,
                 resume: bool, overwrite: bool, say: Say) -> Session:
    """Check the run folder, read the scenes, build (or restore) model, optimizer and generators."""
    check_run_dir(files, dataset_dir, resume, overwrite, config.init)  # every rank checks before any rank writes
    if ctx.is_main:  # only rank 0 writes; torchrun stops the other ranks when it is refused
        lock_output(files.root, OWNER)
    distributed.barrier(ctx)
    checkpoint = read_checkpoint(files.last) if resume else None
    if checkpoint is not None:
        check_compatible(checkpoint, config, say)
    scenes = find_scenes(dataset_dir, config.resolution, say, show_progress=ctx.is_main)
    train, val = _split(files, scenes, config, resume, say)
    check_view_counts(train, val, config.model.num_views)
    # Validate on held-out scenes; a dataset too small to hold any out validates on unseen views instead.
    val_source = val or train[: max(1, config.val_scenes)]
    _seed_everything(config.seed)
    model = InsertNeRF(config.model)
    if checkpoint is None and config.init is not None:
        started = warm_start(model, read_checkpoint(config.init))
        say(f"starting from {config.init}: {started.copied} tensors copied, {started.resampled} resampled to "
            "this model's sample counts")
    model = model.to(ctx.device)
    optimizer = torch.optim.Adam(param_groups(model, config))
    data = load_training_set(train, config.data_budget_mb, ctx.device, say, show_progress=ctx.is_main,
                             with_depth=config.model.loss_depth_weight > 0 or config.guide_prior)
    assert config.batch_scenes is not None  # fixed by config.with_device_defaults before the session
    usable = check_batch_scenes(data, config.batch_scenes, config.rays)
    session = Session(config, files, ctx, model, optimizer, np.random.default_rng([config.seed, ctx.rank]),
                      train, val_source, validation_draws(val_source, config.model.num_views, config.val_rays,
                                                          config.seed),
                      ImageCache(config.cache_mb * _BYTES_PER_MB), say, data,
                      DrawGenerators(ctx.device, config.seed, ctx.rank))
    if checkpoint is not None:
        _restore(session, checkpoint)
    if config.compile:
        model.compile_aggregation()
    # After restoring: DDP broadcasts rank 0's weights.
    session.objective = distributed.wrap(BatchObjective(model, config.guide_prior), ctx)
    priors = FeaturePriors(data) if config.guide_prior and config.guide_from == "features" else None
    session.stream = StepStream(data, usable, session.generators, config.batch_scenes, config.model.num_views,
                                config.rays, config.cache_mb * _BYTES_PER_MB, config.views_min, priors)
    if ctx.is_main:
        _prepare_files(session, dataset_dir, resume, overwrite, ([s.name for s in train], [s.name for s in val]))
    distributed.barrier(ctx)
    return session


def check_compatible(checkpoint: Checkpoint, config: TrainConfig, say: Say) -> None:
    """--resume must keep the model config; other changed settings are allowed with a warning."""
    differences = model_differences(checkpoint.model_config, config.model)
    if differences:
        raise UserError(f"{checkpoint.path} was trained with another model config ({'; '.join(differences[:3])}); "
                        "resume without flags that change the model, or start a new run with another --out.")
    if checkpoint.train_state is None:
        raise UserError(f"{checkpoint.path} holds weights only (no optimizer or step); it cannot be resumed.")
    saved = json.loads(checkpoint.train_state.train_config)
    now = config_to_json(config)
    changed = [f"{k} {saved.get(k)!r} -> {now[k]!r}" for k in DATA_FIELDS if saved.get(k) != now[k]]
    if changed:
        say(f"warning: resumed with changed settings ({', '.join(changed)}); the run will not match an "
            "uninterrupted one.")


def param_groups(model: nn.Module, config: TrainConfig) -> list[dict]:
    """Adam groups: the U-Net encoder (its own learning rate, as GNT trains its extractor) and the rest."""
    encoder = [p for n, p in model.named_parameters() if n.startswith("encoder.")]
    rest = [p for n, p in model.named_parameters() if not n.startswith("encoder.")]
    groups = [{"params": rest, "lr": config.lr, "name": "nerf"}]
    if encoder:
        groups.append({"params": encoder, "lr": config.lr_encoder, "name": "encoder"})
    return groups


def set_learning_rates(session: Session) -> float:
    """Decayed learning rates for the current step; returns the NeRF part's rate (for the log)."""
    cfg = session.config
    for group in session.optimizer.param_groups:
        base = cfg.lr_encoder if group.get("name") == "encoder" else cfg.lr
        group["lr"] = cfg.learning_rate(base, session.step)
    return cfg.learning_rate(cfg.lr, session.step)


def save(session: Session, path: Path, elapsed_s: float) -> None:
    """A checkpoint of the session at its current (completed) step, after ``elapsed_s`` of training in total."""
    state = TrainState(step=session.step, elapsed_s=elapsed_s, optimizer=session.optimizer.state_dict(),
                       rng={**capture_rng(session.data_rng, session.ctx.device), **draw_state(session)},
                       train_config=json.dumps(config_to_json(session.config)), best_val_psnr=session.best_val_psnr)
    try:
        save_checkpoint(path, session.model, session.config.model, state)
    except WriteError as err:
        # One short line: the path once, then what survived and how to go on.
        kept = (f"last.pt of step {session.saved_step} is kept" if session.saved_step is not None
                else "no checkpoint of this run had been written yet")
        raise WriteError(f"{err.problem} while saving {path} at step {session.step}; training stopped and {kept}: "
                         "free space, then continue with --resume.", err.problem) from None


def draw_state(session: Session) -> dict[str, Tensor]:
    """The draw generators' state that reproduces the session's next step (a streamed set draws ahead)."""
    return session.stream.state() if session.stream is not None else session.generators.state()


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (1 << 32))
    torch.manual_seed(seed)


def _restore(session: Session, checkpoint: Checkpoint) -> None:
    """Weights, optimizer, step, time, best PSNR and generators of the checkpoint."""
    state = checkpoint.train_state
    assert state is not None  # check_compatible refused weight-only checkpoints
    load_weights(session.model, checkpoint)
    try:
        session.optimizer.load_state_dict(state.optimizer)
    except (ValueError, KeyError) as err:
        raise UserError(f"{checkpoint.path}: optimizer state does not fit the model ({err}); "
                        "start a new run.") from None
    session.step = session.start_step = session.saved_step = state.step
    session.elapsed_before = state.elapsed_s
    session.best_val_psnr = state.best_val_psnr
    restore_rng(state.rng, session.data_rng, session.ctx.device)
    if not session.generators.load_state(state.rng):
        session.say("warning: the checkpoint has no state of the step-draw generator (an older run); the "
                    "draws continue on a fresh stream.")
        session.generators.reseed(session.config.seed, session.ctx.rank, state.step)
    if session.ctx.rank > 0:
        # Only rank 0's generators are saved; the others continue on a stream of their own.
        session.data_rng = np.random.default_rng([session.config.seed, session.ctx.rank, state.step])
        session.generators.reseed(session.config.seed, session.ctx.rank, state.step)


def _split(files: RunFiles, scenes: list[TrainScene], config: TrainConfig, resume: bool,
           say: Say) -> tuple[list[TrainScene], list[TrainScene]]:
    """Training and held-out scenes: new for a new run, the run's own (splits.json) when resuming."""
    if not resume:
        return split_scenes(scenes, config.val_scenes, config.seed)
    train_names, val_names = read_splits(files)
    by_name = {s.name: s for s in scenes}
    missing = [n for n in train_names + val_names if n not in by_name]
    if missing:
        raise UserError(f"scene {missing[0]} of this run is not in the dataset any more ({len(missing)} missing); "
                        "resume with the dataset the run started with.")
    extra = len(scenes) - len(train_names) - len(val_names)
    if extra:
        say(f"ignoring {extra} scene(s) added to the dataset since the run started.")
    return [by_name[n] for n in train_names], [by_name[n] for n in val_names]


def _prepare_files(session: Session, dataset_dir: Path, resume: bool, overwrite: bool,
                   names: tuple[list[str], list[str]]) -> None:
    files = session.files
    if overwrite or (not resume and files.has_run()):
        if not overwrite:  # check_run_dir let it through: a run killed before its first checkpoint
            session.say(f"{files.root} holds a run stopped before its first checkpoint: starting it afresh.")
        clear_run(files)
    claim_run(files)
    files.checkpoints.mkdir(parents=True, exist_ok=True)
    if resume:
        truncate_metrics(files, session.step)
    else:
        write_splits(files, *names)
    write_run_config(files, session.config, dataset_dir)
