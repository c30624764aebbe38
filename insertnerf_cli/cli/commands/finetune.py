"""`insertnerf finetune`: sharpen the generator on one scene's own photos, in minutes."""
from __future__ import annotations

from pathlib import Path

import click

from insertnerf_cli.cli.commands.common import FiniteFloat, device_option, overwrite_option, resolve_device, user_errors
from insertnerf_cli.cli.commands.weights import backbone_option, chosen_weights
from insertnerf_cli.config import DEFAULT_RESOLUTION, DEFAULT_VIEWS
from insertnerf_cli.finetune import FinetuneConfig, FinetuneResult, finetune

_DEFAULT_MINUTES = FinetuneConfig.minutes
_DEFAULTS = FinetuneConfig()


@click.command("finetune")
@click.argument("scene_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Checkpoint to write (e.g. finetuned.pt), outside SCENE_DIR; use it with render/eval --checkpoint.")
@click.option("--minutes", type=FiniteFloat(min=0, min_open=True),
              help="Time budget of the optimisation; longer keeps helping (measured on one CPU core: +0.7 to +1.2 dB "
              "after 5 minutes, +1.5 to +2.0 after 40).  "
              f"[default: {_DEFAULT_MINUTES:g}, or none when --steps is given]")
@click.option("--steps", type=click.IntRange(min=1), help="Stop after this many steps (the first budget reached wins).")
@click.option("--checkpoint", "base", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Weights to start from (default: the bundled pretrained generator).")
@backbone_option
@click.option("--resolution", type=click.IntRange(min=0), default=DEFAULT_RESOLUTION, show_default=True,
              help="Long side of the photos in pixels, as render/eval's --resolution (use the same); 0 = full size.")
@click.option("--views", type=click.IntRange(min=1), default=DEFAULT_VIEWS, show_default=True,
              help="Source views per step, as render/eval's --views.")
@click.option("--rays", type=click.IntRange(min=1), default=_DEFAULTS.rays, show_default=True,
              help="Target pixels per step.")
@click.option("--lr", type=FiniteFloat(min=0, min_open=True), default=_DEFAULTS.lr, show_default=True,
              help="Adam's learning rate (constant).")
@click.option("--train-encoder", is_flag=True,
              help="Also train the image encoder (slower per step; by default it is frozen).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the draws.")
@click.option("--sfm-depth/--no-sfm-depth", default=True, show_default=True,
              help="Place the fine samples as render and eval do, around the depth of the scene's SfM points "
              "(triangulated at its poses first when it has none): after 5 minutes flower +0.24 dB, room level.")
@click.option("--points-cache", type=click.Path(file_okay=False, path_type=Path), metavar="DIR",
              help="Keep the SfM points triangulated at the scene's poses (when it has none) in DIR, outside the "
              "scene, so that a later finetune of the same scene at the same --resolution loads them instead of "
              "triangulating again.")
@device_option
@overwrite_option
@user_errors
def finetune_command(scene_dir: Path, out: Path, minutes: float | None, steps: int | None, base: Path | None,
                     backbone: str | None, resolution: int, views: int, rays: int, lr: float, train_encoder: bool,
                     seed: int, sfm_depth: bool, points_cache: Path | None, device: str, overwrite: bool) -> None:
    """Fine-tune the generator on SCENE_DIR's own photos and write the weights to --out.

    Each step renders pixels of one photo from its nearest other photos and corrects the network, as training
    does. The views that `insertnerf eval` holds out (the test split, else every 8th view) are never used,
    neither as targets nor as sources, so `eval --checkpoint OUT` stays an honest score. Ctrl-C saves what was
    learnt so far.

    \b
    Example:
      insertnerf finetune scene/ --out scene_ft.pt --minutes 5
      insertnerf render scene/ --out video/ --checkpoint scene_ft.pt
    """
    if minutes is None and steps is None:
        minutes = _DEFAULT_MINUTES
    config = FinetuneConfig(minutes=minutes, steps=steps, rays=rays, lr=lr, train_encoder=train_encoder,
                            lr_encoder=lr, views=views, resolution=resolution or None, seed=seed,
                            sfm_depth=sfm_depth)
    result = finetune(scene_dir, out, config, resolve_device(device), base=chosen_weights(None, base, backbone),
                      overwrite=overwrite, points_cache=points_cache)
    interrupted = result.stopped == "interrupted"
    # One line, with what to do next after a Ctrl-C: the triangulation's and Ctrl-C's lines come before it.
    hint = (f". Use it with render or eval --checkpoint {out}; to go on, pass it as --checkpoint to another finetune "
            "with a new --out.") if interrupted and result.checkpoint is not None else ""
    click.echo(summary(result) + hint)
    if interrupted:
        raise SystemExit(130)


def summary(result: FinetuneResult) -> str:
    """One line: why it stopped, steps, time, training PSNR, views used and the file written."""
    psnr = "n/a" if result.train_psnr is None else f"{result.train_psnr:.2f} dB"
    wrote = f"wrote {result.checkpoint}" if result.checkpoint is not None else "nothing written"
    return (f"{result.stopped}: {result.steps} steps in {result.elapsed_s / 60:.1f} min on {result.usable_views} "
            f"views ({result.held_out_views} held out for eval, never used); training PSNR {psnr}; {wrote}")
