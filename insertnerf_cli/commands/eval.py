"""`insertnerf eval`: PSNR and SSIM of held-out views rendered from the other views."""
from __future__ import annotations

from pathlib import Path

import click

from ..pipeline import EvalConfig, evaluate_scene
from .common import device_option, overwrite_option, resolve_device, user_errors
from .render import chosen_weights, model_options


@click.command("eval")
@click.argument("scene_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the scores to this JSON file (keys psnr, ssim, views).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Write side-by-side images (render | truth | error) to this folder.")
@click.option("--max-views", type=click.IntRange(min=1), help="Score at most this many held-out views, evenly spread.")
@model_options
@device_option
@overwrite_option
@user_errors
def eval_command(scene_dir: Path, json_path: Path | None, out_dir: Path | None, max_views: int | None, views: int,
                 resolution: int, model: str, checkpoint: Path | None, chunk: int, exact: bool, device: str,
                 overwrite: bool) -> None:
    """Score novel-view quality on SCENE_DIR: render each held-out view (the test split, else every 8th view)
    from its nearest other views and compare it with the photo.

    \b
    Example:
      insertnerf eval scene/ --json scores.json --out side_by_side/
    """
    config = EvalConfig(views=views, resolution=resolution or None, checkpoint=chosen_weights(model, checkpoint),
                        device=str(resolve_device(device)), chunk=chunk, exact=exact, out_dir=out_dir,
                        json_path=json_path, max_views=max_views, overwrite=overwrite)
    report = evaluate_scene(scene_dir, config)
    for view in report.views:
        click.echo(f"{view.name}: PSNR {view.psnr:.2f} dB, SSIM {view.ssim:.4f}")
    written = [f"{what} in {path.resolve()}" for what, path in (("report", json_path), ("side-by-sides", out_dir))
               if path is not None]
    click.echo(f"mean over {len(report.views)} held-out views ({report.width}x{report.height}): "
               f"PSNR {report.psnr:.2f} dB, SSIM {report.ssim:.4f}" + "".join(f"; {w}" for w in written))
