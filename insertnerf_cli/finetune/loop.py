"""Fine-tuning the generator on one scene: draws from the scene's own non-held-out photos, the training loss,
Adam at a constant rate, a step and/or time budget, and one checkpoint written atomically at the end (or on
Ctrl-C)."""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from insertnerf_cli.config import DEFAULT_RESOLUTION, DEFAULT_VIEWS, ModelConfig
from insertnerf_cli.errors import UserError
from insertnerf_cli.files.lock import lock_output, releases_output_locks
from insertnerf_cli.files.outdir import check_output
from insertnerf_cli.finetune.data import FrozenFeatures, TargetPriors, draw, finetune_scene
from insertnerf_cli.metrics import psnr_from_mse
from insertnerf_cli.model import InsertNeRF, LossTerms
from insertnerf_cli.model.checkpoint import build_model, bundled_checkpoint, read_checkpoint, save_checkpoint
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.sfm.points_cache import check_cache_folder
from insertnerf_cli.sfm.triangulate import with_points
from insertnerf_cli.training.data import ImageCache, TrainScene, make_batch

# Training's Ctrl-C rule (finish the step, save; a second Ctrl-C stops at once), shared rather than copied.
from insertnerf_cli.training.loop import _StopRequest
from insertnerf_cli.training.session import Objective

Say = Callable[[str], None]
_CACHE_BYTES = 1 << 30  # uint8 images at the fine-tuning size; a 256-px scene of 100 views needs ~20 MB
_PSNR_WINDOW = 20  # steps averaged into the PSNR on the progress bar


@dataclass(frozen=True)
class FinetuneConfig:
    """One fine-tuning run (defaults chosen by measurement, docs/commands/finetune.md).

    Attributes:
        minutes: wall-time budget of the optimisation steps (None = no limit); steps: step limit (None = none).
            At least one must be set; the first reached stops the run.
        rays: target pixels per step; lr: Adam's (constant) rate of the trained parts.
        train_encoder: also train the U-Net encoder (at lr_encoder); False freezes it and precomputes its features.
        views: source views per step (eval and render use the nearest --views; default the same 10).
        resolution: long side of the images in pixels, as render/eval's --resolution (None = full size).
        seed: seeds the draws and the sample jitter.
        sfm_depth: place the fine samples as render does, by the scene's SfM points (triangulated at its poses
            from the usable views first when it has none); data.TargetPriors.
        colour_scale: look the sources' colours up in the photos at up to this many times the fine-tuning size
            (encoder frozen only). 1, at that size, as the generator was trained: render and eval of the result
            still blend colours at RenderOptions.colours.scale, and a larger scale here gained nothing (measured:
            docs/research-log.md, Colour lookups and render shortcuts).
    """

    minutes: float | None = 5.0
    steps: int | None = None
    rays: int = 128
    lr: float = 5e-4
    train_encoder: bool = False
    lr_encoder: float = 5e-4
    views: int = DEFAULT_VIEWS
    resolution: int | None = DEFAULT_RESOLUTION
    seed: int = 0
    sfm_depth: bool = True
    colour_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.minutes is None and self.steps is None:
            raise UserError("fine-tuning needs a budget: give --minutes or --steps")
        if (self.minutes is not None and self.minutes <= 0) or (self.steps is not None and self.steps < 1):
            raise UserError(f"--minutes and --steps must be positive (got {self.minutes}, {self.steps})")
        if min(self.rays, self.views) < 1 or min(self.lr, self.lr_encoder) <= 0:
            raise UserError("--rays, --views and the learning rates must be positive")


@dataclass(frozen=True)
class Progress:
    """Where a run stands after a step (what a step hook sees): the model being trained and its config."""

    step: int
    elapsed_s: float  # seconds of optimisation so far (hook time excluded)
    model: InsertNeRF
    model_config: ModelConfig


@dataclass(frozen=True)
class FinetuneResult:
    """How a run ended: stopped is "minutes", "steps" or "interrupted" (Ctrl-C; the checkpoint was saved if any
    step was done); checkpoint is None when nothing was written."""

    checkpoint: Path | None
    steps: int
    elapsed_s: float
    stopped: str
    train_psnr: float | None
    usable_views: int
    held_out_views: int

    @property
    def steps_per_minute(self) -> float | None:
        return 60.0 * self.steps / self.elapsed_s if self.elapsed_s > 0 else None


def check_out_file(out: Path, scene_dir: Path, overwrite: bool, base: Path | None = None) -> None:
    """Refuse, before any work, an --out in or around the scene folder or at the base checkpoint, one that cannot
    be written, a folder, or an existing file without overwrite."""
    out = Path(out)
    check_output(out, [scene_dir, base if base is not None else bundled_checkpoint()], is_dir=False,
                 kind="input scene or checkpoint")
    if out.exists() and not overwrite:
        raise UserError(f"{out} exists; pass --overwrite to replace it or choose another --out")


@releases_output_locks
def finetune(scene_dir: str | Path, out: str | Path, config: FinetuneConfig, device: torch.device,
             base: Path | None = None, overwrite: bool = False, on_step: Callable[[Progress], None] | None = None,
             say: Say | None = None, points: ScenePoints | None = None,
             points_cache: Path | None = None) -> FinetuneResult:
    """Fine-tune ``base`` (default: the bundled generator) on the scene in ``scene_dir``; write ``out``.

    Args:
        on_step: called after every step (e.g. to save snapshots); its time is not counted in the budget.
        points: SfM points of the normalised scene that a caller already has (render --finetune triangulates
            once from every view): the prior's rule counts only the usable views' observations (TargetPriors), so
            eval's held-out photos still lend nothing. None: the scene's own, else triangulated here.
        points_cache: a folder outside the scene (--points-cache) where the points triangulated here are kept and
            found again by a later finetune of the same scene, photos and resolution (sfm/points_cache.py).
    Raises:
        UserError: bad --out, unreadable scene or checkpoint, too few usable views, or a diverging loss.
    """
    say = say or _tqdm_say
    scene_dir, out = Path(scene_dir), Path(out)
    check_out_file(out, scene_dir, overwrite, base)
    if points_cache is not None:
        check_cache_folder(points_cache, scene_dir)
    lock_output(out, "finetune", is_dir=False)
    checkpoint = read_checkpoint(base if base is not None else bundled_checkpoint())
    scene = finetune_scene(scene_dir, config.resolution)
    if config.sfm_depth:  # from the usable views only: eval's held-out photos lend nothing, as in eval
        given = scene.scene if points is None else replace(scene.scene, points=points)
        scene = replace(scene, scene=with_points(given, list(scene.train_ids), points_cache))
    torch.manual_seed(config.seed)
    model = build_model(checkpoint, device)
    model.train()
    run = _Run(model, checkpoint.model_config, scene, config)
    steps, elapsed, stopped, psnr = run.loop(on_step, say)
    written = None
    if steps > 0:
        written = save_checkpoint(out, model, checkpoint.model_config)
    else:
        say("no step was done, so nothing was written.")
    return FinetuneResult(written, steps, elapsed, stopped, psnr, len(scene.train_ids), len(scene.test_ids))


class _Run:
    """The optimisation state of one run: model, optimiser, draws, image cache and (encoder frozen) features."""

    def __init__(self, model: InsertNeRF, model_config: ModelConfig, scene: TrainScene, config: FinetuneConfig):
        self.model, self.model_config, self.scene, self.config = model, model_config, scene, config
        self.rng = np.random.default_rng([config.seed, 7])
        self.cache = ImageCache(_CACHE_BYTES)
        self.objective = Objective(model)
        self.optimizer = torch.optim.Adam(_param_groups(model, config))
        self.frozen = None if config.train_encoder else FrozenFeatures(model, scene, self.cache, config.colour_scale)
        self.device = model.background.device
        self.priors = TargetPriors(scene, self.device) if config.sfm_depth else None
        if self.priors is not None:  # each target's samples within the far bound render would give it
            self.scene = replace(scene, far=self.priors.far)
        self.steps_done = 0

    def step(self) -> LossTerms:
        """Draw, render the target's rays from the sources, one Adam step; the loss terms (detached)."""
        d = draw(self.rng, self.scene, self.config.views, self.config.rays)
        batch = make_batch(self.scene, self.cache, d).to(self.device)
        guide = None if self.priors is None else self.priors.guide(d.target, d.pixels)
        self.optimizer.zero_grad(set_to_none=True)
        if self.frozen is None:
            terms = self.objective(batch.views, batch.rays, batch.target_rgb, guide)
        else:
            encoded = self.frozen.select(d.sources)
            terms = self.model.losses(self.model(encoded, batch.rays, train=True, guide=guide), batch.target_rgb,
                                      encoded)
        total = float(terms.total.detach())  # also waits for the GPU, so the time budget counts the real work
        if not math.isfinite(total):
            raise UserError(f"fine-tuning diverged: the loss is {total} at step {self.steps_done + 1}; nothing was "
                            "written. Lower --lr.")
        terms.total.backward()
        self.optimizer.step()
        return terms

    def loop(self, on_step: Callable[[Progress], None] | None, say: Say) -> tuple[int, float, str, float | None]:
        """Steps until the budget is spent or Ctrl-C; (steps, seconds, why it stopped, recent training PSNR)."""
        cfg = self.config
        budget = None if cfg.minutes is None else 60.0 * cfg.minutes
        mses: list[float] = []
        elapsed, stopped = 0.0, ""
        with _StopRequest(say) as ctrl_c, tqdm(total=cfg.steps, unit="step", desc="fine-tuning", file=sys.stderr,
                                         dynamic_ncols=True) as bar:
            while True:
                stopped = _stop_reason(self.steps_done, elapsed, cfg.steps, budget, ctrl_c.requested)
                if stopped:
                    break
                start = time.monotonic()
                terms = self.step()
                self.steps_done += 1
                elapsed += time.monotonic() - start
                mses = (mses + [float(terms.mse_fine)])[-_PSNR_WINDOW:]
                bar.set_postfix_str(_postfix(mses, self.steps_done, elapsed, cfg.steps, budget), refresh=False)
                bar.update(1)
                if on_step is not None:
                    on_step(Progress(self.steps_done, elapsed, self.model, self.model_config))
        return self.steps_done, elapsed, stopped, _psnr(mses)


def _stop_reason(steps: int, elapsed: float, max_steps: int | None, budget_s: float | None,
                 interrupted: bool) -> str:
    if interrupted:
        return "interrupted"
    if max_steps is not None and steps >= max_steps:
        return "steps"
    return "minutes" if budget_s is not None and elapsed >= budget_s else ""


def _param_groups(model: InsertNeRF, config: FinetuneConfig) -> list[dict]:
    """Adam groups: everything but the encoder, plus the encoder when it is trained (else it is frozen)."""
    encoder = [p for n, p in model.named_parameters() if n.startswith("encoder.")]
    rest = [p for n, p in model.named_parameters() if not n.startswith("encoder.")]
    for p in encoder:
        p.requires_grad_(config.train_encoder)
    groups = [{"params": rest, "lr": config.lr}]
    if config.train_encoder:
        groups.append({"params": encoder, "lr": config.lr_encoder})
    return groups


def _psnr(mses: list[float]) -> float | None:
    return psnr_from_mse(sum(mses) / len(mses)) if mses else None


def _postfix(mses: list[float], steps: int, elapsed: float, max_steps: int | None, budget_s: float | None) -> str:
    """Training PSNR of the recent steps and the time left (the nearer of the step and time budgets)."""
    lefts = [] if budget_s is None else [budget_s - elapsed]
    if max_steps is not None:
        lefts.append((max_steps - steps) * elapsed / steps)
    left = max(0.0, min(lefts))
    return f"psnr {_psnr(mses):.2f} dB, {int(left // 60)}:{int(left % 60):02d} left"


def _tqdm_say(message: str) -> None:
    tqdm.write(message, file=sys.stderr)
