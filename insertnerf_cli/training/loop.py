"""The training loop: draw -> encode -> render -> losses -> Adam step, with logs, validation and checkpoints."""
from __future__ import annotations

import signal
import sys
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

import torch
from torch import Tensor
from tqdm import tqdm

from insertnerf_cli.errors import UserError
from insertnerf_cli.files.lock import releases_output_locks
from insertnerf_cli.metrics import psnr_from_mse
from insertnerf_cli.model import LossTerms
from insertnerf_cli.training import distributed
from insertnerf_cli.training.config import TrainConfig, with_device_defaults
from insertnerf_cli.training.data import make_batch
from insertnerf_cli.training.run_dir import RunFiles, append_metrics
from insertnerf_cli.training.session import Session, open_session, save, set_learning_rates

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
        processes: the launch's processes (torchrun's world size; 1 without torchrun).
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
    processes: int = 1


class _Meter:
    """Sums of the loss terms (on the training device: no host sync per step) and step times since the last log."""

    def __init__(self, device: torch.device) -> None:
        self.sums = torch.zeros(len(LOSS_NAMES), dtype=torch.float64, device=device)
        self.count = 0
        self.seconds = 0.0

    def add(self, terms: LossTerms, seconds: float) -> None:
        self.sums += torch.stack([getattr(terms, n).detach() for n in LOSS_NAMES]).to(self.sums.dtype)
        self.count += 1
        self.seconds += seconds

    def means(self) -> dict[str, float]:
        return dict(zip(LOSS_NAMES, (self.sums / max(self.count, 1)).tolist()))


class _Divergence:
    """The first step whose loss was not finite, its loss and scenes, kept on the training device and read only
    at log steps and before every save (a non-finite step is never saved)."""

    def __init__(self, device: torch.device, batch_scenes: int) -> None:
        self.step = torch.full((), -1, dtype=torch.int64, device=device)
        self.loss = torch.zeros((), dtype=torch.float64, device=device)
        self.scenes = torch.zeros(batch_scenes, dtype=torch.int64, device=device)

    def record(self, total: Tensor, step: int, scenes: Tensor) -> None:
        first = ~torch.isfinite(total.detach()) & (self.step < 0)
        self.step = torch.where(first, step, self.step)
        self.loss = torch.where(first, total.detach().to(self.loss.dtype), self.loss)
        self.scenes = torch.where(first, scenes, self.scenes)

    def check(self, s: Session) -> None:
        """UserError on every rank when any rank's loss or weights went non-finite; the last checkpoint stays."""
        step = int(self.step)
        weights_bad = step < 0 and not bool(torch.isfinite(
            torch.cat([p.detach().reshape(-1) for p in s.model.parameters()])).all())
        (diverged,) = distributed.any_rank([step >= 0 or weights_bad], s.ctx)
        if not diverged:
            return
        kept = (f"{s.files.last} (step {s.saved_step}) is kept" if s.saved_step is not None
                else "no checkpoint had been written yet")
        if step < 0:
            raise UserError(f"training diverged: the weights are not finite after step {s.step} (on another rank "
                            f"or from the last update); {kept}. Lower --lr, or check the scenes' images and bounds.")
        names = [s.train_scenes[i].name for i in self.scenes.tolist()]
        scenes = f"scene {names[0]}" if len(names) == 1 else f"scenes {', '.join(names)}"
        raise UserError(f"training diverged: the loss is {float(self.loss)} at step {step} ({scenes}); {kept}. "
                        "Lower --lr, or check that scene's images and bounds.")


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


@releases_output_locks
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
        config = with_device_defaults(config, ctx.device)
        session = open_session(Path(dataset_dir), RunFiles(Path(run_dir)), config, ctx, resume, overwrite, say)
        try:
            return _run(session)
        finally:
            if session.stream is not None:
                session.stream.close()
    finally:
        distributed.stop(ctx)


def _run(s: Session) -> TrainResult:
    cfg = s.config
    t0 = time.monotonic()
    meter, last = _Meter(s.ctx.device), {"train_psnr": None, "val_psnr": None, "rays_per_s": None, "val_step": None}
    session_rays, session_seconds = 0, 0.0
    divergence = _Divergence(s.ctx.device, cfg.batch_scenes or 1)
    with _StopRequest(s.say) as stop, _progress_bar(s) as bar:
        while True:
            elapsed = s.elapsed_before + time.monotonic() - t0
            reason = _stop_reason(s, elapsed, stop.requested)
            if reason:
                break
            step_start = time.monotonic()
            terms = _train_step(s, divergence)
            s.step += 1
            seconds = time.monotonic() - step_start
            meter.add(terms, seconds)
            session_rays += cfg.rays * s.ctx.world_size
            if s.step % cfg.log_every == 0 or s.step == cfg.steps:
                last.update(_log(s, meter, elapsed + seconds, bar, divergence))
                session_seconds += meter.seconds  # step times plus the wait for the device at the log
                meter = _Meter(s.ctx.device)
            if s.step % cfg.val_every == 0:
                last.update(val_psnr=_validate_and_keep_best(s, elapsed + seconds, divergence), val_step=s.step)
            if s.step % cfg.ckpt_every == 0:
                _checkpoint(s, elapsed + seconds, divergence)
            bar.update(1)
        if meter.count:  # steps since the last log line (a time budget or Ctrl-C ended the run between logs)
            last.update(_log(s, meter, elapsed, bar, divergence))
            session_seconds += meter.seconds
    if s.step > s.start_step:
        if last["val_step"] != s.step and reason != "interrupted":
            last["val_psnr"] = _validate_and_keep_best(s, elapsed, divergence)
        _checkpoint(s, elapsed, divergence)
    elif reason == "steps":
        s.say(f"the run is already at step {s.step} of --steps {cfg.steps}; pass a larger --steps to go on.")
    elif reason == "minutes":
        s.say(f"the run has used its --minutes {cfg.minutes} budget; pass a larger --minutes to go on.")
    return TrainResult(s.files.root, s.files.last, s.step, s.step - s.start_step, elapsed, reason,
                       last["train_psnr"], last["val_psnr"], s.best_val_psnr,
                       session_rays / session_seconds if session_seconds > 0 else None, s.ctx.is_main,
                       s.ctx.world_size)


def _stop_reason(s: Session, elapsed: float, interrupted: bool) -> str | None:
    """Why the loop should stop now, agreed by every rank (None = go on).

    Under torchrun the ranks agree at log steps only (and at the first step): agreeing is a collective, a host
    sync, so a time budget or Ctrl-C there takes effect within --log-every steps.
    """
    over_time = s.config.minutes is not None and elapsed >= 60.0 * s.config.minutes
    if s.ctx.distributed and s.step % s.config.log_every and s.step != s.start_step:
        over_time = interrupted = False
    over_time, interrupted = distributed.any_rank([over_time, interrupted], s.ctx)
    if interrupted:
        return "interrupted"
    if s.step >= s.config.steps:
        return "steps"
    return "minutes" if over_time else None


def _train_step(s: Session, divergence: _Divergence) -> LossTerms:
    """One optimisation step on B scenes, with no host sync: the loss terms stay on the device."""
    assert s.stream is not None
    scenes = s.config.batch_scenes or 1
    draw, batch = s.stream.next()
    set_learning_rates(s)
    s.optimizer.zero_grad(set_to_none=True)
    try:
        with torch.autocast(s.ctx.device.type, dtype=torch.bfloat16, enabled=s.config.precision == "bf16"):
            terms = s.objective(batch.views, batch.rays, batch.target_rgb, scenes, batch.target_depth, batch.guide)
    except Exception as err:  # --compile is opt-in: torch's compiler failing is one line, not its stack
        if not (s.config.compile and type(err).__module__.startswith(("torch._dynamo", "torch._inductor"))):
            raise
        first = (str(err).strip().splitlines() or [""])[-1][:200]
        raise UserError(f"torch.compile failed at step {s.step + 1} ({type(err).__name__}: {first}); train "
                        "without --compile (checkpoints already written are kept; --resume goes on from them)."
                        ) from None
    divergence.record(terms.total, s.step + 1, s.data.groups[draw.group].scene_index[draw.scenes])
    terms.total.backward()
    s.optimizer.step()
    return terms


def _log(s: Session, meter: _Meter, elapsed: float, bar: tqdm, divergence: _Divergence) -> dict[str, float]:
    """Append the averages since the last log to metrics.jsonl and show them on the progress bar (the one host
    sync of the steps in between); a non-finite loss since the last check stops training here."""
    divergence.check(s)
    synced = time.monotonic()
    means = meter.means()  # waits for the queued steps: their device time joins the window's
    meter.seconds += time.monotonic() - synced
    psnr = psnr_from_mse(means["mse_fine"])
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
                psnrs.append(psnr_from_mse(mse))
    finally:
        s.model.train()
    return sum(psnrs) / len(psnrs)


def _validate_and_keep_best(s: Session, elapsed: float, divergence: _Divergence) -> float | None:
    """Validate on rank 0, log it, and save best.pt when it is the best so far (never from diverged weights)."""
    divergence.check(s)
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


def _checkpoint(s: Session, elapsed: float, divergence: _Divergence) -> None:
    divergence.check(s)
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
