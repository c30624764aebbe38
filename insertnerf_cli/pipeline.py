"""The library behind `insertnerf render` and `insertnerf eval` (no click here).

render: scene folder (or a plain folder of photos, posed first with pycolmap and cached in OUT/poses/) -> normalise
-> camera path -> per frame: nearest reference views -> encode (cached while the views repeat) -> chunked render
-> frames/depth/depth_vis PNGs -> videos and cameras.json in the user's units. A re-run with the same settings
resumes: finished frames are kept, the rest rendered.
eval: held-out views (the test split, else every 8th) rendered from the nearest of the other views -> PSNR/SSIM.
"""
from __future__ import annotations

import math
import sys
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .atomic import write_json
from .config import DEFAULT_RESOLUTION, DEFAULT_VIEWS
from .cameras import Cameras
from .errors import UserError
from .metrics import SSIM_WINDOW, psnr, ssim
from .lock import lock_output, releases_output_locks
from .outdir import OutputRecord, check_output, remove_if_empty
from .outputs import OWNER as RENDER_OWNER
from .outputs import (CAMERAS_JSON, POSES_DIR, VIDEOS, check_eval_outputs, check_resumable, claim_render_outputs,
                      depth_to_turbo, depth_to_uint16, ffmpeg_exe, frame_name, frame_paths, prepare_out_dir,
                      prepare_side_by_sides, side_by_side, write_cameras_json, write_frame, write_png, write_state,
                      write_video)
from .paths import CameraPath, default_path_kind, make_path
from .views import held_out_views

DEFAULT_FRAMES = 30
DEFAULT_FPS = 15.0
# Rays per network call by device. CPU: small chunks stay in cache (render.render_image, bench/model_speed.py).
# CUDA: a GPU needs far more work per call than 128 rays; 4096 rays of 64+64 samples and 10 views hold about
# 1 GB of per-view tensors. Not measured on a GPU yet (none was lent to issue 11).
DEFAULT_CHUNKS = {"cpu": 128, "cuda": 4096}
STATE_VERSION = 1
# Below half opacity a pixel shows mostly background, so its depth says little: it is written as invalid (0).
MIN_DEPTH_OPACITY = 0.5
# Consecutive frames of a path mostly share their reference views: encodings are kept per view, for this many
# times --views views, so a frame encodes only the views its predecessors did not use.
ENCODED_VIEWS_KEPT = 2


@dataclass(frozen=True)
class RenderConfig:
    """Settings of one `render` run.

    Attributes:
        path: "orbit", "spiral", "input", or None to choose by the scene's layout (orbit for object-centric).
        frames: frames of an orbit/spiral (None = DEFAULT_FRAMES); for "input", None = every input view.
        fps: frame rate of the videos.
        resolution: long side of the frames in pixels (None = the images' size).
        views: reference views per frame.
        checkpoint: generator weights (None = the bundled pretrained ones).
        device: torch device name (cpu or cuda), resolved once by the command.
        chunk: rays per network call (bounds memory); None = DEFAULT_CHUNKS of the device.
        exact: every ray gets its own coarse pass and every pixel a fine pass (render.EXACT), instead of the
            default shortcuts (render.Shortcuts: within 0.3 dB, docs/benchmarks.md).
        overwrite: replace the outputs of a different earlier run in the output folder.
        finetune_minutes: first fine-tune the weights on the scene for this long (cached as OUT/finetune.pt).
    """

    path: str | None = None
    frames: int | None = None
    fps: float = DEFAULT_FPS
    resolution: int | None = DEFAULT_RESOLUTION
    views: int = DEFAULT_VIEWS
    checkpoint: Path | None = None
    device: str = "cpu"
    chunk: int | None = None
    exact: bool = False
    overwrite: bool = False
    finetune_minutes: float | None = None


@dataclass(frozen=True)
class RenderSummary:
    """What `render` produced: ``rendered`` frames this run plus ``resumed`` kept from an interrupted one."""

    out_dir: Path
    path: str
    frames: int
    rendered: int
    resumed: int
    height: int
    width: int
    seconds_per_frame: float | None
    depth_clipped: int
    wall_s: float = 0.0  # the whole command, start-up and videos included
    resolution_asked: int | None = None  # a --resolution above the photos' size (frames never upsample)

    def line(self) -> str:
        speed = "" if self.seconds_per_frame is None else f", {self.seconds_per_frame:.1f} s/frame"
        kept = f" ({self.resumed} kept from the earlier run)" if self.resumed else ""
        clip = f"; {self.depth_clipped} depth pixels beyond 65.5 units were clipped" if self.depth_clipped else ""
        if self.resolution_asked:
            clip += f"; --resolution {self.resolution_asked} is above the photos' size, which was kept (no upsampling)"
        return (f"{self.frames} frames ({self.path}, {self.width}x{self.height}) in {self.out_dir.resolve()}: "
                f"rendered {self.rendered}{kept}{speed}, {_duration(self.wall_s)} in total; see video.mp4, "
                f"depth.mp4, cameras.json{clip}")


def _duration(seconds: float) -> str:
    """"42 s", "3 min 05 s" or "1 h 02 min"."""
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


@dataclass(frozen=True)
class EvalConfig:
    """Settings of one `eval` run (views, resolution, checkpoint, device, chunk, exact as in RenderConfig).

    Attributes:
        out_dir: folder for side-by-side images (render | truth | error), or None for none.
        json_path: file for the report (keys psnr, ssim, views), or None.
        max_views: evaluate at most this many held-out views, evenly spread (None = all).
        overwrite: replace an existing JSON report and side-by-side images.
    """

    views: int = DEFAULT_VIEWS
    resolution: int | None = DEFAULT_RESOLUTION
    checkpoint: Path | None = None
    device: str = "cpu"
    chunk: int | None = None
    exact: bool = False
    out_dir: Path | None = None
    json_path: Path | None = None
    max_views: int | None = None
    overwrite: bool = False


@dataclass(frozen=True)
class ViewScore:
    """One held-out view: its index and file name, scores, and the reference views it was rendered from."""

    index: int
    name: str
    psnr: float
    ssim: float
    references: tuple[int, ...]
    seconds: float


@dataclass(frozen=True)
class EvalReport:
    """Mean PSNR (dB) and SSIM over the held-out views, and each view's record."""

    scene: Path
    height: int
    width: int
    psnr: float
    ssim: float
    views: tuple[ViewScore, ...]

    def to_json(self) -> dict:
        """JSON-ready dict with keys psnr, ssim, views (infinite PSNR of a perfect view is written as null)."""
        def finite(x: float) -> float | None:
            return x if math.isfinite(x) else None

        views = [{**asdict(v), "psnr": finite(v.psnr), "references": list(v.references)} for v in self.views]
        return {"psnr": finite(self.psnr), "ssim": self.ssim, "views": views, "scene": str(self.scene),
                "height": self.height, "width": self.width}


# ---------------------------------------------------------------------------------------------------- scene
def _image_fingerprint(folder: Path) -> list[list] | None:
    """Names, sizes and modification times of a plain image folder (None for a scene folder)."""
    from .scenes import find_images

    try:
        images = find_images(folder)
    except UserError:
        return None
    return [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in images] or None


def _is_scene(folder: Path) -> bool:
    from .scenes import detect_format

    return detect_format(folder) is not None


def _finetuned(scene_dir: Path, out_dir: Path, checkpoint: Path, config: RenderConfig) -> Path:
    """The weights `render --finetune M` renders with: fine-tuned for M minutes at the render's resolution and
    number of reference views, kept in OUT and reused by a later run with the same inputs."""
    from .finetune import FinetuneConfig, cached_finetune
    from .finetune.render_cache import RECORD, WEIGHTS

    OutputRecord(out_dir, RENDER_OWNER).claim(WEIGHTS, RECORD)
    ft = FinetuneConfig(minutes=config.finetune_minutes, views=config.views, resolution=config.resolution)
    return cached_finetune(scene_dir, out_dir, checkpoint, ft, torch.device(config.device))


def _posed_photos(scene_dir: Path, out_dir: Path, created: bool):
    """The scene pycolmap makes of a plain photo folder, estimated once into OUT/poses and reused after.

    A failure leaves no trace in an OUT this run ``created`` (no record, no folder)."""
    from .scenes import load_scene

    poses_dir = out_dir / POSES_DIR
    if not (poses_dir / "transforms.json").is_file():
        from .colmap import PosesOptions, estimate_poses

        print(f"{scene_dir} is a folder of photos without poses: estimating them with COLMAP into {poses_dir} "
              "(once; later runs reuse them)", file=sys.stderr)
        OutputRecord(out_dir, RENDER_OWNER).claim(POSES_DIR)
        try:
            estimate_poses(scene_dir, poses_dir, PosesOptions(overwrite=True))
        except BaseException:
            if created:
                OutputRecord(out_dir, RENDER_OWNER).remove()
                remove_if_empty(out_dir)
            raise
    return load_scene(poses_dir)


def _checkpoint_path(checkpoint: Path | None) -> Path:
    from .checkpoint import bundled_checkpoint

    return Path(checkpoint) if checkpoint is not None else bundled_checkpoint()


def _load_model(checkpoint: Path, device: str) -> torch.nn.Module:
    from .checkpoint import load_model

    return load_model(checkpoint, torch.device(device))[0]


class _Renderer:
    """Renders target cameras of a normalised scene from their nearest reference views, caching encodings."""

    def __init__(self, model: torch.nn.Module, scene, config: RenderConfig | EvalConfig, size: tuple[int, int]) -> None:
        self.model = model
        self.scene, self.size, self.k = scene, size, config.views
        self.chunk = config.chunk or DEFAULT_CHUNKS.get(torch.device(config.device).type, DEFAULT_CHUNKS["cpu"])
        from .render import EXACT, Shortcuts

        self.shortcuts = EXACT if config.exact else Shortcuts()
        self.method = "dist" if scene.layout == "forward" else "vector"
        self.cache: OrderedDict[int, object] = OrderedDict()  # view index -> its EncodedViews (1)

    def references(self, target_c2w: torch.Tensor, exclude: list[int]) -> list[int]:
        from .views import nearest_views

        refs = nearest_views(target_c2w, self.scene.cameras.c2w, self.k, self.method, exclude=exclude)
        if not refs:
            raise UserError(f"{self.scene.root}: no reference views left to render from")
        return refs

    def _encoded(self, refs: list[int]):
        from .model import EncodedViews, SourceViews

        key = sorted(refs)
        missing = [i for i in key if i not in self.cache]
        if missing:
            images, cams = self.scene.load_views(missing, *self.size)
            param = next(self.model.parameters())
            views = SourceViews(images, cams).to(device=param.device, dtype=param.dtype)
            with torch.inference_mode():
                encoded = self.model.encode(views)
            for row, index in enumerate(missing):
                self.cache[index] = encoded.select([row])
        for index in key:
            self.cache.move_to_end(index)
        while len(self.cache) > ENCODED_VIEWS_KEPT * max(self.k, len(key)):
            self.cache.popitem(last=False)
        return EncodedViews.join([self.cache[i] for i in key])

    def render(self, camera: Cameras, near: float, far: float, exclude: list[int]):
        """(ImageOutput of ``camera`` (1), the reference indices used); never uses an index in ``exclude``."""
        from .render import render_image

        refs = self.references(camera.c2w[0], exclude)
        return render_image(self.model, self._encoded(refs), camera, near, far, self.chunk, self.shortcuts), refs


# ---------------------------------------------------------------------------------------------------- render
def _render_state(scene_dir: Path, checkpoint: Path, config: RenderConfig, images: list | None) -> dict:
    """Everything that changes the frames: a re-run with an equal state may resume."""
    from .checkpoint import checkpoint_sha256

    return {"version": STATE_VERSION, "scene": str(scene_dir.resolve()), "images": images, "path": config.path,
            "frames": config.frames, "resolution": config.resolution, "views": config.views, "exact": config.exact,
            "checkpoint_sha256": checkpoint_sha256(checkpoint),
            **({"finetune_minutes": config.finetune_minutes} if config.finetune_minutes is not None else {})}


def _plan(scene, config: RenderConfig):
    """(normalised scene, its Similarity, the CameraPath to render)."""
    from .scenes import normalize_scene

    scene, similarity = normalize_scene(scene)
    kind = config.path or default_path_kind(scene.layout)
    frames = config.frames if config.frames is not None or kind == "input" else DEFAULT_FRAMES
    path = make_path(kind, scene.cameras, scene.near, scene.far, frames if frames is not None else len(scene),
                     scene.size_for(config.resolution))
    return scene, similarity, path


@releases_output_locks
def render_scene(scene_dir: str | Path, out_dir: str | Path, config: RenderConfig) -> RenderSummary:
    """Render a camera path of the scene in ``scene_dir`` into ``out_dir`` (see outputs.py for the files).

    Raises:
        UserError: no ffmpeg, unreadable scene, failed pose estimation, bad checkpoint, an output folder inside
            the scene (or holding it) or not writable, or one holding a different run without ``config.overwrite``.
    """
    from .scenes import load_scene

    started = time.perf_counter()
    scene_dir, out_dir = Path(scene_dir), Path(out_dir)
    check_output(out_dir, [scene_dir], kind="input scene")
    ffmpeg_exe()  # before any long work: the videos need it
    checkpoint = _checkpoint_path(config.checkpoint)
    images = None if _is_scene(scene_dir) else _image_fingerprint(scene_dir)
    # A bad scene, path or checkpoint fails here, before OUT is touched.
    planned = _plan(load_scene(scene_dir), config) if images is None else None
    model = _load_model(checkpoint, config.device)
    state = _render_state(scene_dir, checkpoint, config, images)
    created = not out_dir.exists()
    lock_output(out_dir, RENDER_OWNER)  # one writer per folder (lock.py)
    prepare_out_dir(out_dir, state, config.overwrite)
    scene, similarity, path = planned or _plan(_posed_photos(scene_dir, out_dir, created), config)
    if config.finetune_minutes is not None:  # after prepare_out_dir: the weights are cached in OUT
        model = _load_model(_finetuned(scene_dir if images is None else out_dir / POSES_DIR, out_dir, checkpoint,
                                       config), config.device)
    user_cams = similarity.inverse().apply_cameras(path.cameras)
    check_resumable(out_dir, user_cams)
    claim_render_outputs(out_dir, len(path))
    write_state(out_dir, state)
    write_cameras_json(out_dir / CAMERAS_JSON, user_cams, path.near / similarity.scale, path.far / similarity.scale,
                       extra={"path": path.kind, "fps": config.fps, "scene": str(scene_dir.resolve()),
                              "normalization": similarity.to_json()})
    renderer = _Renderer(model, scene, config, (path.cameras.height, path.cameras.width))
    rendered, resumed, seconds, clipped = _render_frames(renderer, path, out_dir, similarity.scale)
    for video, sub in zip(VIDEOS, ("frame", "depth_vis")):
        write_video(out_dir / video, [getattr(frame_paths(out_dir, i), sub) for i in range(len(path))], config.fps)
    size = (path.cameras.height, path.cameras.width)
    asked = config.resolution if config.resolution is not None and config.resolution > max(size) else None
    return RenderSummary(out_dir, path.kind, len(path), rendered, resumed, *size,
                         seconds / rendered if rendered else None, clipped, time.perf_counter() - started, asked)


def _render_frames(renderer: _Renderer, path: CameraPath, out_dir: Path, scale: float) -> tuple[int, int, float, int]:
    """Render every frame whose files are missing; returns (rendered, kept, seconds spent, clipped depth pixels)."""
    todo = [i for i in range(len(path)) if not frame_paths(out_dir, i).all_exist()]
    resumed, seconds, clipped = len(path) - len(todo), 0.0, 0
    near, far = float(path.near.min()), float(path.far.max())
    if not todo:  # no bar: a finished one printed at start and again at close reads as two in a log
        print(f"all {len(path)} frames are already rendered in {out_dir}; assembling the videos", file=sys.stderr)
        return 0, resumed, seconds, clipped
    bar = tqdm(total=len(path), initial=resumed, unit="frame", desc="rendering", file=sys.stderr, dynamic_ncols=True)
    with bar:
        for i in todo:
            start = time.perf_counter()
            exclude = [path.source_index[i]] if path.source_index is not None else []
            out, _ = renderer.render(path.cameras.subset([i]), float(path.near[i]), float(path.far[i]), exclude)
            depth = out.depth.double().cpu().numpy()
            valid = out.opacity.cpu().numpy() >= MIN_DEPTH_OPACITY
            depth_mm, n_clipped = depth_to_uint16(depth / scale, valid)
            write_frame(frame_paths(out_dir, i), out.rgb.float().cpu().numpy(), depth_mm,
                        depth_to_turbo(depth, valid, near, far))
            clipped += n_clipped
            took = time.perf_counter() - start
            seconds += took
            bar.set_postfix_str(f"last frame {took:.1f} s", refresh=False)
            bar.update(1)
    return len(todo), resumed, seconds, clipped


# ---------------------------------------------------------------------------------------------------- eval
@releases_output_locks
def evaluate_scene(scene_dir: str | Path, config: EvalConfig) -> EvalReport:
    """Render each held-out view from its nearest non-held-out views, score it against the photo, and write the
    side-by-sides and JSON report that ``config`` asks for."""
    from .scenes import load_scene, normalize_scene

    check_eval_outputs(Path(scene_dir), config.checkpoint, config.json_path, config.out_dir, config.overwrite)
    if config.out_dir is not None:
        lock_output(config.out_dir, "eval")
    scene, _ = normalize_scene(load_scene(Path(scene_dir)))
    held = held_out_views(scene, config.max_views)
    size = scene.size_for(config.resolution)
    if min(size) < SSIM_WINDOW:
        raise UserError(f"--resolution gives {size[1]}x{size[0]} images, smaller than SSIM's {SSIM_WINDOW}-px window")
    renderer = _Renderer(_load_model(_checkpoint_path(config.checkpoint), config.device), scene, config, size)
    prepare_side_by_sides(config.out_dir and Path(config.out_dir), held)
    scores = []
    for index in tqdm(held, unit="view", desc="evaluating", file=sys.stderr, dynamic_ncols=True):
        start = time.perf_counter()
        camera = scene.cameras.subset([index]).rescale(*size)
        out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), exclude=held)
        if set(refs) & set(held):  # nearest_views honours exclude; this guards the metric's meaning
            raise RuntimeError(f"held-out views {sorted(set(refs) & set(held))} were chosen as references")
        render, truth = out.rgb.double().cpu().numpy(), scene.load_image(index, *size).astype(np.float64)
        scores.append(ViewScore(index, scene.names[index], psnr(render, truth), ssim(render, truth), tuple(refs),
                                time.perf_counter() - start))
        if config.out_dir is not None:
            write_png(Path(config.out_dir) / frame_name(index), side_by_side(render, truth))
    report = EvalReport(Path(scene_dir), size[0], size[1], float(np.mean([s.psnr for s in scores])),
                        float(np.mean([s.ssim for s in scores])), tuple(scores))
    if config.json_path is not None:
        write_json(config.json_path, report.to_json())
    return report
