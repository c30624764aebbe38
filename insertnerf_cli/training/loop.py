"""The training loop: draw -> encode -> render -> losses -> Adam step, with logs, validation and checkpoints."""
from __future__ import annotations

import math
import signal
import sys
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

import torch
from tqdm import tqdm

from ..errors import UserError
from ..model import LossTerms
from . import distributed
from .config import TrainConfig
from .data import TrainBatch, draw_training_views, make_batch
from .run_dir import RunFiles, append_metrics
from .session import Session, open_session, save, set_learning_rates

LOSS_NAMES = tuple(f.name for f in fields(LossTerms))


@dataclass(frozen=True)
class TrainResult:
    """How a training session ended.

    Attributes:
        checkpoint: RUN_DIR/checkpoints/last.pt.
        step: steps done in total; steps_this_session of them in this session.
        elapsed_s: training wall time in total (all sessions).
        stopped: "steps", "minutes" or "interrupted" (Ctrl-C; the checkpoint was saved).
        train_psnr: PSNR (dB) of the fine pass over the last logged steps; val_psnr: last validation;
        best_val_psnr: best validation of the run (None when nothing was validated).
        rays_per_s: training throughput of this session (all ranks together).
        main_process: False on the other ranks of a torchrun launch (they should stay quiet).
    """

    run_dir: Path
    checkpoint: Path
    step: int
    steps_this_session: int
    elapsed_s: float
    stopped: str
    train_psnr: float | None
    val_psnr: float | None
    best_val_psnr: float | None
    rays_per_s: float | None
    main_process: bool = True


class _Meter:
    """Sums of the loss terms and step times since the last log line."""

    def __init__(self) -> None:
        self.sums = {name: 0.0 for name in LOSS_NAMES}
        self.count = 0
        self.seconds = 0.0

    def add(self, values: dict[str, float], seconds: float) -> None:
        for name, value in values.items():
            self.sums[name] += value
        self.count += 1
        self.seconds += seconds

    def means(self) -> dict[str, float]:
        return {name: total / max(self.count, 1) for name, total in self.sums.items()}


class _StopRequest:
    """Ctrl-C asks the loop to stop after the current step and save; a second Ctrl-C stops at once."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.requested = False
        self.say = say
        self._previous: Any = None

    def __enter__(self) -> "_StopRequest":
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)

    def _handle(self, signum: int, frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        self.say("Ctrl-C: finishing this step and saving a checkpoint (press Ctrl-C again to stop without saving).")


def train(dataset_dir: str | Path, run_dir: str | Path, config: TrainConfig, device: torch.device,
          resume: bool = False, overwrite: bool = False) -> TrainResult:
    """Train the generator on every scene in ``dataset_dir``; write metrics and checkpoints to ``run_dir``.

    Args:
        dataset_dir: a folder of scene folders (any format load_scene reads) or one scene folder.
        run_dir: the run folder; a used one needs ``resume`` (continue exactly) or ``overwrite``.
        config: the run's settings; on resume its model config must match the checkpoint's.
        device: where to train (under torchrun with CUDA, each rank takes its LOCAL_RANK GPU).
    """
    ctx = distributed.start(device)
    say = _printer(ctx.is_main)
    try:
        session = open_session(Path(dataset_dir), RunFiles(Path(run_dir)), config, ctx, resume, overwrite, say)
        return _run(session)
    finally:
        distributed.stop(ctx)


def _run(s: Session) -> TrainResult:
    cfg = s.config
    t0 = time.monotonic()
    meter, last = _Meter(), {"train_psnr": None, "val_psnr": None, "rays_per_s": None, "val_step": None}
    session_rays, session_seconds = 0, 0.0
    with _StopRequest(s.say) as stop, _progress_bar(s) as bar:
        while True:
            elapsed = s.elapsed_before + time.monotonic() - t0
            reason = _stop_reason(s, elapsed, stop.requested)
            if reason:
                break
            step_start = time.monotonic()
            values = _train_step(s)
            s.step += 1
            seconds = time.monotonic() - step_start
            meter.add(values, seconds)
            session_rays += cfg.rays * s.ctx.world_size
            session_seconds += seconds
            if s.step % cfg.log_every == 0 or s.step == cfg.steps:
                last.update(_log(s, meter, elapsed + seconds, bar))
                meter = _Meter()
            if s.step % cfg.val_every == 0:
                last.update(val_psnr=_validate_and_keep_best(s, elapsed + seconds), val_step=s.step)
            if s.step % cfg.ckpt_every == 0:
                _checkpoint(s, elapsed + seconds)
            bar.update(1)
        if meter.count:  # steps since the last log line (a time budget or Ctrl-C ended the run between logs)
            last.update(_log(s, meter, elapsed, bar))
    if s.step > s.start_step:
        if last["val_step"] != s.step and reason != "interrupted":
            last["val_psnr"] = _validate_and_keep_best(s, elapsed)
        _checkpoint(s, elapsed)
    elif reason == "steps":
        s.say(f"the run is already at step {s.step} of --steps {cfg.steps}; pass a larger --steps to go on.")
    elif reason == "minutes":
        s.say(f"the run has used its --minutes {cfg.minutes} budget; pass a larger --minutes to go on.")
    return TrainResult(s.files.root, s.files.last, s.step, s.step - s.start_step, elapsed, reason,
                       last["train_psnr"], last["val_psnr"], s.best_val_psnr,
                       session_rays / session_seconds if session_seconds > 0 else None, s.ctx.is_main)


def _stop_reason(s: Session, elapsed: float, interrupted: bool) -> str | None:
    """Why the loop should stop now, agreed by every rank (None = go on)."""
    over_time = s.config.minutes is not None and elapsed >= 60.0 * s.config.minutes
    over_time, interrupted = distributed.any_rank([over_time, interrupted], s.ctx)
    if interrupted:
        return "interrupted"
    if s.step >= s.config.steps:
        return "steps"
    return "minutes" if over_time else None


def _train_step(s: Session) -> dict[str, float]:
    """One optimisation step; returns the loss terms as numbers. A non-finite loss stops training cleanly."""
    cfg = s.config
    draw = draw_training_views(s.data_rng, s.train_scenes, cfg.model.num_views, cfg.rays)
    batch: TrainBatch = make_batch(s.train_scenes[draw.scene], s.cache, draw).to(s.ctx.device)
    set_learning_rates(s)
    s.optimizer.zero_grad(set_to_none=True)
    terms = s.objective(batch.views, batch.rays, batch.target_rgb)
    values = dict(zip(LOSS_NAMES, torch.stack([getattr(terms, n).detach().float() for n in LOSS_NAMES]).tolist()))
    (diverged,) = distributed.any_rank([not math.isfinite(values["total"])], s.ctx)
    if diverged:
        kept = (f"{s.files.last} (step {s.saved_step}) is kept" if s.saved_step is not None
                else "no checkpoint had been written yet")
        raise UserError(f"training diverged: the loss is {values['total']} at step {s.step + 1} (scene "
                        f"{s.train_scenes[draw.scene].name}); {kept}. Lower --lr, or check that scene's images "
                        "and bounds.")
    terms.total.backward()
    s.optimizer.step()
    return values


def _log(s: Session, meter: _Meter, elapsed: float, bar: tqdm) -> dict[str, float]:
    """Append the averages since the last log to metrics.jsonl and show them on the progress bar."""
    means = meter.means()
    psnr = -10.0 * math.log10(max(means["mse_fine"], 1e-12))
    rays_per_s = s.config.rays * s.ctx.world_size * meter.count / max(meter.seconds, 1e-9)
    lr = s.config.learning_rate(s.config.lr, s.step)
    if s.ctx.is_main:
        append_metrics(s.files, {"split": "train", "step": s.step, **{k: means[k] for k in LOSS_NAMES if
                                                                      k != "psnr_fine"},
                                 "psnr": psnr, "rays_per_s": rays_per_s, "lr": lr, "elapsed": elapsed})
        bar.set_postfix_str(_postfix(s, means["total"], psnr, rays_per_s, elapsed), refresh=False)
    return {"train_psnr": psnr, "rays_per_s": rays_per_s}


def _postfix(s: Session, loss: float, psnr: float, rays_per_s: float, elapsed: float) -> str:
    text = f"loss {loss:.4f} psnr {psnr:.2f} {rays_per_s:,.0f} rays/s"
    if s.config.minutes is not None:
        left = max(0.0, 60.0 * s.config.minutes - elapsed)
        text += f" budget left {int(left // 60)}:{int(left % 60):02d}"
    return text


@torch.no_grad()
def validate(s: Session) -> float | None:
    """Mean PSNR (dB) of the fine pass over the fixed validation rays (None when there are none).

    Runs in eval mode (deterministic samples) inside a forked torch RNG, so validating never changes the
    training that follows.
    """
    if not s.val_draws:
        return None
    devices = [s.ctx.device] if s.ctx.device.type == "cuda" else []
    s.model.eval()
    psnrs = []
    try:
        with torch.random.fork_rng(devices=devices):
            for draw in s.val_draws:
                batch = make_batch(s.val_scenes[draw.scene], s.cache, draw).to(s.ctx.device)
                encoded = s.model.encode(batch.views)
                errors = []
                for start in range(0, len(batch.rays), s.config.rays):
                    chunk = slice(start, start + s.config.rays)
                    rgb = s.model.render(encoded, batch.rays[chunk]).rgb  # [chunk, 3]
                    errors.append(((rgb - batch.target_rgb[chunk]) ** 2).sum())
                mse = float(torch.stack(errors).sum()) / batch.target_rgb.numel()
                psnrs.append(-10.0 * math.log10(max(mse, 1e-12)))
    finally:
        s.model.train()
    return sum(psnrs) / len(psnrs)


def _validate_and_keep_best(s: Session, elapsed: float) -> float | None:
    """Validate on rank 0, log it, and save best.pt when it is the best so far."""
    if not s.ctx.is_main:
        return None
    value = validate(s)
    if value is None:
        return None
    append_metrics(s.files, {"split": "val", "step": s.step, "psnr": value, "scenes": len(s.val_draws),
                             "rays": s.config.val_rays, "elapsed": elapsed})
    if s.best_val_psnr is None or value > s.best_val_psnr:
        s.best_val_psnr = value
        save(s, s.files.best, elapsed)
    return value


def _checkpoint(s: Session, elapsed: float) -> None:
    if s.ctx.is_main:
        save(s, s.files.last, elapsed)
    s.saved_step = s.step


def _progress_bar(s: Session) -> tqdm:
    # A run already at --steps gets no bar: a finished one prints at creation and again at close (two in a log).
    return tqdm(total=s.config.steps, initial=s.step, unit="step", desc="training", file=sys.stderr,
                disable=not s.ctx.is_main or s.step >= s.config.steps, dynamic_ncols=True, smoothing=0.05)


def _printer(main: bool) -> Callable[[str], None]:
    def say(message: str) -> None:
        if main:
            tqdm.write(message, file=sys.stderr)
    return say
