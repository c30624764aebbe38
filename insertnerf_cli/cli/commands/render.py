"""`insertnerf render`: a turntable or spiral video, frames, depth maps and cameras from a scene or a photo folder."""
from __future__ import annotations

from pathlib import Path

import click

from insertnerf_cli.cli.commands.common import FiniteFloat, device_option, overwrite_option, resolve_device, user_errors
from insertnerf_cli.cli.commands.weights import chosen_weights, model_options
from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.outputs import DEFAULT_DEPTH_FORMAT, DEPTH_FORMATS
from insertnerf_cli.exporters.pointcloud import DEFAULT_POINTS
from insertnerf_cli.exporters.records import DEFAULT_FPS, RenderConfig
from insertnerf_cli.pipelines.render import render_scene
from insertnerf_cli.rendering.camera_paths import PATH_KINDS


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
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Processes that render frames side by side (the picture is the same with any number, up to "
                   "float rounding).  "
                   "[default: on a CPU one per core, each with at least 3 frames (a process holds about 0.6 GB at "
                   "256 px); on a GPU 1]")
@model_options
@device_option
@overwrite_option
@user_errors
def render(scene_dir: Path, out_dir: Path, path_kind: str | None, frames: int | None, fps: float | None, views: int,
           resolution: int, model: str, checkpoint: Path | None, backbone: str | None, chunk: int, exact: bool,
           sfm_depth: bool, device: str, overwrite: bool, finetune_minutes: float | None, depth_format: str,
           pointcloud: bool, pointcloud_points: int, points_cache: Path | None, workers: int | None) -> None:
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
                          depth_format=depth_format, pointcloud_points=pointcloud_points if pointcloud else None,
                          points_cache=points_cache, workers=workers)
    click.echo(render_scene(scene_dir, out_dir, config).line())
