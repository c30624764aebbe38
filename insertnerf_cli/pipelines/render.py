"""The library behind `insertnerf render` (no click here; `eval` is in evaluate.py; the run's records are in
exporters/records.py).

render: scene folder (or a plain folder of photos, or a COLMAP project whose images/ has no poses yet: posed first
with pycolmap and cached in OUT/poses/) -> normalise -> camera path -> per frame: nearest reference views -> encode
(cached while the views repeat) -> chunked render -> frames/depth/depth_vis files -> videos, cameras.json in the
user's units, index.html, and with --pointcloud a fused pointcloud.ply. A re-run with the same settings resumes:
finished frames are kept, the rest rendered.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import torch
from tqdm import tqdm

from insertnerf_cli.config import config_to_json
from insertnerf_cli.exporters.outputs import (
    CAMERAS_JSON,
    OWNER as RENDER_OWNER,
    POSES_DIR,
    VIDEOS,
    check_resumable,
    check_resumable_scale,
    claim_render_outputs,
    depth_scale_for,
    ffmpeg_exe,
    frame_paths,
    prepare_out_dir,
    write_cameras_json,
    write_state,
    write_video,
)
from insertnerf_cli.exporters.pointcloud import write_pointcloud
from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.records import DEFAULT_FPS, DEFAULT_FRAMES, RenderConfig, RenderSummary
from insertnerf_cli.exporters.report.render_page import RenderPage, render_page
from insertnerf_cli.files.atomic import write_bytes
from insertnerf_cli.files.lock import lock_output, releases_output_locks
from insertnerf_cli.files.outdir import check_output
from insertnerf_cli.model.checkpoint import checkpoint_sha256
from insertnerf_cli.pipelines.frames import FrameWriter, excluded_views
from insertnerf_cli.pipelines.inputs import finetuned, points_cache, posed_photos, unposed_photos
from insertnerf_cli.pipelines.processes import RendererSpec, run_side_by_side, worker_count
from insertnerf_cli.rendering.camera_paths import (CameraPath, default_path_kind, given_path, make_path,
                                                  with_reference_bounds)
from insertnerf_cli.rendering.path_files import PathFile, read_path_file
from insertnerf_cli.rendering.view_renderer import ViewRenderer, checkpoint_path, load_model
from insertnerf_cli.scenes import Scene, Similarity, load_scene, normalize_scene, walk_warning
from insertnerf_cli.scenes.views import view_rule
from insertnerf_cli.sfm.triangulate import with_points

# 2: the depth PNGs' scale is chosen per render (was millimetres): frames of version 1 are not resumed into it.
STATE_VERSION = 2
INDEX_HTML = "index.html"
POINTCLOUD_PLY = "pointcloud.ply"


# ---------------------------------------------------------------------------------------------------- render
def _render_state(scene_dir: Path, checkpoint: Path, config: RenderConfig, images: list | None,
                  path_file: PathFile | None) -> dict:
    """Everything that changes the frames: a re-run with an equal state may resume."""
    path = config.path if path_file is None else "file"
    return {"version": STATE_VERSION, "scene": str(scene_dir.resolve()), "images": images, "path": path,
            **({} if path_file is None else {"path_file_sha256": path_file.sha256}),
            "frames": config.frames, "resolution": config.resolution, "views": config.views, "exact": config.exact,
            "checkpoint_sha256": checkpoint_sha256(checkpoint), "depth_format": config.depth_format,
            **({} if config.sfm_depth else {"sfm_depth": False}),  # states written before the prior stay valid
            **({"finetune_minutes": config.finetune_minutes} if config.finetune_minutes is not None else {}),
            "options": config_to_json(config.options)}


def _plan(scene: Scene, config: RenderConfig,
          path_file: PathFile | None) -> tuple[Scene, Similarity, CameraPath]:
    """(normalised scene, its Similarity, the CameraPath to render: the path file's cameras moved into the
    normalised world, or the kind ``config.path`` names)."""
    if (warning := walk_warning(scene)) is not None:
        print(warning, file=sys.stderr, flush=True)
    scene, similarity = normalize_scene(scene)
    if path_file is not None:
        given = similarity.apply_cameras(path_file.cameras.to(dtype=scene.cameras.dtype))
        path = given_path(scene.cameras, scene.near, scene.far, given, config.resolution)
    else:
        kind = config.path or default_path_kind(scene.layout)
        frames = config.frames if config.frames is not None or kind == "input" else DEFAULT_FRAMES
        path = make_path(kind, scene.cameras, scene.near, scene.far, frames if frames is not None else len(scene),
                         scene.size_for(config.resolution))
    path = with_reference_bounds(path, scene.cameras, scene.near, scene.far, config.views, view_rule(scene.layout))
    return scene, similarity, path


@releases_output_locks
def render_scene(scene_dir: str | Path, out_dir: str | Path, config: RenderConfig) -> RenderSummary:
    """Render a camera path of the scene in ``scene_dir`` into ``out_dir`` (see outputs.py for the files).

    Raises:
        UserError: no ffmpeg, unreadable scene, failed pose estimation, bad checkpoint, an output folder inside
            the scene (or holding it) or not writable, or one holding a different run without ``config.overwrite``.
    """
    started = time.perf_counter()
    scene_dir, out_dir = Path(scene_dir), Path(out_dir)
    path_file = None if config.path_file is None else read_path_file(config.path_file)
    if path_file is not None and (config.path is not None or config.frames is not None):
        raise UserError("--frames does not apply to --path FILE (nor does a path kind): the file gives every frame")
    fps = config.fps if config.fps is not None else (path_file.fps if path_file and path_file.fps else DEFAULT_FPS)
    config = replace(config, fps=fps)
    check_output(out_dir, [scene_dir], kind="input scene")
    cache, claim = points_cache(config.points_cache, scene_dir, out_dir, RENDER_OWNER)
    ffmpeg_exe()  # before any long work: the videos need it
    checkpoint = checkpoint_path(config.checkpoint)
    weights = checkpoint  # what renders: the checkpoint, or its fine-tuned weights
    photos = unposed_photos(scene_dir)
    # A bad scene, path or checkpoint fails here, before OUT is touched.
    planned = _plan(load_scene(scene_dir), config, path_file) if photos is None else None
    model = load_model(checkpoint, config.device)
    state = _render_state(scene_dir, checkpoint, config, photos and photos.fingerprint, path_file)
    created = not out_dir.exists()
    lock_output(out_dir, RENDER_OWNER)  # one writer per folder (lock.py)
    prepare_out_dir(out_dir, state, config.overwrite)
    scene, similarity, path = planned or _plan(posed_photos(photos, out_dir, created), config, path_file)
    user_cams = similarity.inverse().apply_cameras(path.cameras)
    check_resumable(out_dir, user_cams)  # before the long work: triangulating, fine-tuning
    if config.sfm_depth:  # once: the fine-tune's prior takes the same points (it counts its usable views' only)
        scene = with_points(scene, cache=cache, claim=claim)
    if config.finetune_minutes is not None:  # after prepare_out_dir: the weights are cached in OUT
        # Where the render's triangulation found no point, the fine-tune's (from fewer photos) would not either:
        # it trains without the prior instead of trying again and warning twice.
        weights = finetuned(scene_dir if photos is None else out_dir / POSES_DIR, out_dir, checkpoint,
                            config.finetune_minutes, config.views, config.resolution, config.device,
                            config.sfm_depth and scene.points is not None, scene.points)
        model = load_model(weights, config.device)
    extra = [INDEX_HTML] + ([POINTCLOUD_PLY] if config.pointcloud_points is not None else [])
    claim_render_outputs(out_dir, len(path), config.depth_format, *extra)
    write_state(out_dir, state)
    size = (path.cameras.height, path.cameras.width)
    spec = RendererSpec(weights, scene, size, config.views, config.device, config.chunk, config.exact,
                        config.sfm_depth, config.options)
    renderer = spec.build(model)
    path = replace(path, far=torch.tensor([renderer.far_bound(path.cameras.subset([i]), float(path.far[i]),
                                                              excluded_views(path, i)) for i in range(len(path))],
                                          dtype=path.far.dtype))
    near, far = path.near / similarity.scale, path.far / similarity.scale  # [F] in the scene's units
    scale = depth_scale_for(float(far.max())) if config.depth_format == "png16" else 1.0
    check_resumable_scale(out_dir, len(path), scale)
    write_cameras_json(out_dir / CAMERAS_JSON, user_cams, near, far, scale, config.depth_format,
                       extra={"path": path.kind, "fps": config.fps, "scene": str(scene_dir.resolve()),
                              **({} if path_file is None else {"path_file": str(path_file.source.resolve())}),
                              "normalization": similarity.to_json()})
    writer = FrameWriter(path, out_dir, similarity.scale, scale, config.depth_format)
    rendered, resumed, seconds, clipped, workers = _render_frames(renderer, spec, writer, config)
    files = [frame_paths(out_dir, i, config.depth_format) for i in range(len(path))]
    for video, sub in zip(VIDEOS, ("frame", "depth_vis")):
        write_video(out_dir / video, [getattr(f, sub) for f in files], config.fps)
    points = None
    if config.pointcloud_points is not None:
        points = write_pointcloud(out_dir / POINTCLOUD_PLY, user_cams, files, scale, config.pointcloud_points)
    asked = config.resolution if config.resolution is not None and config.resolution > max(size) else None
    summary = RenderSummary(out_dir, path.kind, len(path), rendered, resumed, *size,
                            seconds / rendered if rendered else None, clipped, time.perf_counter() - started, asked,
                            scale if config.depth_format == "png16" else None, points, workers)
    inputs = similarity.inverse().apply_cameras(scene.cameras)
    page = RenderPage(summary, config, scene_dir, user_cams, inputs, tuple(scene.names))
    write_bytes(out_dir / INDEX_HTML, render_page(page).encode("utf-8"))
    return summary


def _render_frames(renderer: ViewRenderer, spec: RendererSpec, writer: FrameWriter,
                   config: RenderConfig) -> tuple[int, int, float, int, int]:
    """Render every frame whose files are missing (side by side on a CPU's cores: processes.py); returns
    (rendered, kept, seconds spent, clipped depth pixels, processes)."""
    frames = len(writer.path)
    todo = [i for i in range(frames) if not writer.done(i)]
    resumed, clipped = frames - len(todo), 0
    if not todo:  # no bar: a finished one printed at start and again at close reads as two in a log
        print(f"all {frames} frames are already rendered in {writer.out_dir}; assembling the videos",
              file=sys.stderr)
        return 0, resumed, 0.0, clipped, 1
    workers = worker_count(config.workers, len(todo), config.device)
    bar = tqdm(total=frames, initial=resumed, unit="frame", desc="rendering", file=sys.stderr, dynamic_ncols=True)
    if workers > 1:
        bar.set_postfix_str(f"{workers} processes", refresh=False)
    start = time.perf_counter()
    with bar:
        for _, n_clipped, _ in run_side_by_side(renderer, spec, writer, todo, workers):
            clipped += n_clipped
            bar.update(1)
    return len(todo), resumed, time.perf_counter() - start, clipped, workers
