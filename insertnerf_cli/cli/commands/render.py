"""`insertnerf render`: a turntable or spiral video, frames, depth maps and cameras from a scene or a photo folder."""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable

import click

from insertnerf_cli.cli.commands.common import FiniteFloat, device_option, overwrite_option, resolve_device, user_errors
from insertnerf_cli.config import BACKBONES, DEFAULT_RESOLUTION, DEFAULT_VIEWS
from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.outputs import DEFAULT_DEPTH_FORMAT, DEPTH_FORMATS
from insertnerf_cli.exporters.pointcloud import DEFAULT_POINTS
from insertnerf_cli.exporters.records import DEFAULT_FPS, RenderConfig
from insertnerf_cli.model.checkpoint import (BUNDLED_MODELS, DEFAULT_BACKBONE, DEFAULT_MODEL, bundled_checkpoint,
                                             read_checkpoint)
from insertnerf_cli.pipelines.render import render_scene
from insertnerf_cli.rendering.camera_paths import PATH_KINDS


backbone_option = click.option(
    "--backbone", type=click.Choice(BACKBONES),
    help="Structure of space of the bundled generator: nerf, one field from near to far; nerfpp, NeRF++'s "
    "foreground field inside a sphere around the subject and cameras and a background field out to infinity "
    "(docs/method.md; not yet better on 360-degree captures, docs/model-card.md). With --checkpoint it must match "
    f"the checkpoint's.  [default: {DEFAULT_BACKBONE}]")


def model_options(func: Callable[..., Any] | None = None, *, views_option: Callable | None = None) -> Any:
    """--views, --resolution, --model, --checkpoint, --backbone, --chunk, --exact, --sfm-depth: shared by render
    and eval (eval passes its own --views, which takes a list)."""
    if func is None:
        return functools.partial(model_options, views_option=views_option)
    options = [
        views_option or click.option("--views", type=click.IntRange(min=1), default=DEFAULT_VIEWS, show_default=True,
                                     help="Reference views per rendered image (the nearest ones)."),
        click.option("--resolution", type=click.IntRange(min=0), default=DEFAULT_RESOLUTION, show_default=True,
                     help="Long side of the rendered images in pixels; 0 = the photos' own size. Never upsamples: "
                     "a larger value gives the photos' size."),
        click.option("--model", type=click.Choice(sorted(BUNDLED_MODELS)),
                     help="Which bundled pretrained generator renders: fast takes 32+16 samples per ray, full "
                     f"64+64 (about 2x slower, the same picture quality, smoother depth maps; docs/model-card.md).  "
                     f"[default: {DEFAULT_MODEL}]"),
        click.option("--checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                     help="Generator weights from `insertnerf train` or `finetune` instead of a bundled --model."),
        backbone_option,
        click.option("--chunk", type=click.IntRange(min=1),
                     help="Rays per network call; lower it if memory runs out.  [default: 512 on CPU, 4096 on "
                     "CUDA]"),
        click.option("--exact", is_flag=True,
                     help="Give every pixel its own coarse pass and a fine pass (slower). By default the coarse "
                     "pass runs on every 4th pixel, background pixels skip the fine pass, and pixels between "
                     "agreeing neighbours are blended from them (within 0.3 dB)."),
        click.option("--sfm-depth/--no-sfm-depth", default=True, show_default=True,
                     help="Send most fine samples to the depth of the scene's structure-from-motion points seen "
                     "at each pixel, draw a pixel whose reference photos agree better at that depth than at "
                     "the rendered one as their blend there, and leave a photo out of the samples its own points "
                     "show hidden behind a nearer surface (sharper on real photos; docs/model-card.md). The "
                     "points come from the scene's "
                     "COLMAP model (poses from `insertnerf poses` have one); a scene without points gets them "
                     "triangulated at its own poses first (SIFT matched along the epipolar lines, about 40-90 s "
                     "for 30-120 photos on 2 cores)."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def chosen_weights(model: str | None, checkpoint: Path | None, backbone: str | None = None) -> Path | None:
    """The --checkpoint (whose backbone must be --backbone's when both are given), else None for the default bundled
    generator, else the bundled file of --model and --backbone."""
    if checkpoint is not None:
        if model is not None:
            raise UserError(f"--model {model} and --checkpoint {checkpoint} both name weights: pass one of them.")
        theirs = read_checkpoint(checkpoint).model_config.backbone if backbone is not None else None
        if theirs != backbone:
            raise UserError(f"{checkpoint} holds a generator of the {theirs} backbone, not --backbone {backbone}: "
                            "drop --backbone, or pass a checkpoint trained with that backbone.")
        return checkpoint
    if model in (None, DEFAULT_MODEL) and backbone in (None, DEFAULT_BACKBONE):
        return None
    return bundled_checkpoint(model or DEFAULT_MODEL, backbone or DEFAULT_BACKBONE)


@click.command("render")
@click.argument("scene_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Output folder (frames/, depth/, depth_vis/, video.mp4, depth.mp4, cameras.json, index.html); "
                   "not inside SCENE_DIR. --overwrite removes only what render wrote there.")
@click.option("--path", "path_kind", metavar="[orbit|spiral|input|FILE]",
              help="Camera path; default: orbit for object-centric/360 captures, spiral for forward-facing ones; "
                   "input re-renders the input poses; FILE: a nerfstudio camera_path.json (its viewer's export) or a "
                   "transforms.json of target cameras, followed exactly, in the scene's units and axes "
                   "(docs/commands/render.md).")
@click.option("--frames", type=click.IntRange(min=1),
              help="Frames of the path [default: 30; for --path input every input view].")
@click.option("--fps", type=FiniteFloat(min=0, min_open=True),
              help=f"Frame rate of the videos.  [default: a path file's fps, else {DEFAULT_FPS:g}]")
@click.option("--finetune", "finetune_minutes", type=FiniteFloat(min=0, min_open=True),
              help="First fine-tune the weights on SCENE_DIR's own photos for this many minutes (kept in "
                   "OUT/finetune.pt and reused by a re-run; see `insertnerf finetune`).")
@click.option("--depth-format", type=click.Choice(DEPTH_FORMATS), default=DEFAULT_DEPTH_FORMAT, show_default=True,
              help="depth/ files: png16 = uint16 PNGs, depth = value x cameras.json's depth_unit_scale_factor "
                   "(chosen per render so that no depth is clipped); npy = float32 in the scene's units, NaN "
                   "where invalid.")
@click.option("--pointcloud", is_flag=True,
              help="Also write pointcloud.ply: the coloured points of every frame's depth (where opacity >= 0.5), "
                   "in the scene's units and axes.")
@click.option("--pointcloud-points", type=click.IntRange(min=1), default=DEFAULT_POINTS, show_default=True,
              help="At most this many points in pointcloud.ply (a uniform random subset beyond).")
@model_options
@device_option
@overwrite_option
@user_errors
def render(scene_dir: Path, out_dir: Path, path_kind: str | None, frames: int | None, fps: float | None, views: int,
           resolution: int, model: str, checkpoint: Path | None, backbone: str | None, chunk: int, exact: bool,
           sfm_depth: bool, device: str, overwrite: bool, finetune_minutes: float | None, depth_format: str,
           pointcloud: bool, pointcloud_points: int) -> None:
    """Render novel views of SCENE_DIR into --out: frames, depth maps, videos and cameras.

    SCENE_DIR is a scene in any supported format, or a plain folder of photos, or a COLMAP project whose images/
    holds the photos (their poses are then estimated with COLMAP first and cached in OUT/poses/). OUT/index.html
    shows the result. Re-running the same command resumes an interrupted render.

    \b
    Example:
      insertnerf render photos/ --out views/ --frames 60 --resolution 320
    """
    path_file = None
    if path_kind is not None and path_kind not in PATH_KINDS:
        path_file, path_kind = Path(path_kind), None
        if not path_file.is_file():
            raise UserError(f"--path {path_file}: no such file, and not a path kind ({', '.join(PATH_KINDS)}); "
                            "give orbit, spiral, input or a camera path file")
    config = RenderConfig(path=path_kind, path_file=path_file, frames=frames, fps=fps, resolution=resolution or None, views=views,
                          checkpoint=chosen_weights(model, checkpoint, backbone), device=str(resolve_device(device)),
                          chunk=chunk, exact=exact, sfm_depth=sfm_depth, overwrite=overwrite,
                          finetune_minutes=finetune_minutes,
                          depth_format=depth_format, pointcloud_points=pointcloud_points if pointcloud else None)
    click.echo(render_scene(scene_dir, out_dir, config).line())
