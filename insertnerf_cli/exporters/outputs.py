"""What `insertnerf render` writes, each file through a temporary name and a rename (atomic.py), each path
recorded in OUT/.insertnerf-outputs.json before it is made (outdir.py: what --overwrite may remove):

    OUT/frames/00000.png      RGB, 8 bit
    OUT/depth/00000.png       uint16 steps of depth_unit_scale_factor (cameras.json) in the user's scene units
                              (depth = value * factor), 0 = invalid (opacity below 0.5, or not finite); the
                              factor is chosen per render from the path's far bound, so no valid depth is clipped
    OUT/depth/00000.npy       with --depth-format npy instead: float32 depth in the scene units, NaN = invalid
    OUT/depth_vis/00000.png   the depth as a turbo colour map (near = red, far = blue, invalid = black)
    OUT/video.mp4, depth.mp4  H.264 yuv420p through imageio-ffmpeg, assembled from the PNGs
    OUT/cameras.json          nerfstudio-style transforms of the rendered path (OpenGL c2w) with the depth scale
    OUT/index.html            the page of the render (report/render_page.py); OUT/pointcloud.ply with --pointcloud
"""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import UserError
from insertnerf_cli.files.atomic import atomic_path, write_bytes, write_json
from insertnerf_cli.files.outdir import OutputRecord, foreign_entries, remove_if_empty
from insertnerf_cli.poses.folder import LEGACY_OUTPUTS as POSES_LEGACY_OUTPUTS, OWNER as POSES_OWNER
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms

FRAME_DIRS = ("frames", "depth", "depth_vis")
VIDEOS = ("video.mp4", "depth.mp4")
CAMERAS_JSON = "cameras.json"
OWNER = "render"  # the name of its list in an output record (outdir.py)
STATE_FILE = "render_config.json"  # the settings the frames depend on: equal settings may resume
POSES_DIR = "poses"  # poses pycolmap estimated for a folder of photos
# SfM points triangulated at the scene's poses, kept for later runs (sfm/points_cache.py); kept by --overwrite too:
# each file is keyed by the photos and poses it was made from.
POINTS_DIR = "points"
# What renders of versions without an output record wrote: the only names --overwrite removes from such a folder.
FRAME_GLOB = "[0-9][0-9][0-9][0-9][0-9].png"
LEGACY_OUTPUTS = (*(f"{d}/{FRAME_GLOB}" for d in FRAME_DIRS), *(f"{d}/" for d in FRAME_DIRS), *VIDEOS,
                  CAMERAS_JSON, STATE_FILE)
# A PNG ends with this IEND chunk; a file cut short by a crash or power loss lacks it.
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
DEPTH_FORMATS = ("png16", "npy")
DEFAULT_DEPTH_FORMAT = "png16"
# The depth scale leaves this much room above the path's far bound: a depth is a weighted mean of sample depths
# within [near, far], so only float rounding could reach past far.
_DEPTH_HEADROOM = 1.01
_UINT16_MAX = np.iinfo(np.uint16).max
_UINT8_MAX = np.iinfo(np.uint8).max
# imageio's quality scale is 0-10 (10 best); 8 keeps H.264 artefacts invisible at a few MB per minute.
VIDEO_QUALITY = 8


@dataclass(frozen=True)
class FramePaths:
    """The three per-frame files of frame ``index``."""

    frame: Path
    depth: Path
    depth_vis: Path

    def all_exist(self) -> bool:
        """Whether all three files are complete (a zero-byte or truncated one means: render again)."""
        depth_ok = is_complete_npy(self.depth) if self.depth.suffix == ".npy" else is_complete_png(self.depth)
        return depth_ok and is_complete_png(self.frame) and is_complete_png(self.depth_vis)


def is_complete_png(path: Path) -> bool:
    """A cheap check that ``path`` is a whole PNG: its signature and its closing IEND chunk (16 bytes read)."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(_PNG_SIGNATURE))
            handle.seek(0, 2)
            if handle.tell() < len(_PNG_SIGNATURE) + len(_PNG_END):
                return False
            handle.seek(-len(_PNG_END), 2)
            return head == _PNG_SIGNATURE and handle.read() == _PNG_END
    except OSError:
        return False


def is_complete_npy(path: Path) -> bool:
    """Whether ``path`` is a whole .npy file: a readable header and exactly the data it announces."""
    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(handle)
            return path.stat().st_size - handle.tell() == math.prod(shape) * np.dtype(dtype).itemsize
    except (OSError, ValueError):
        return False


def frame_name(index: int, suffix: str = ".png") -> str:
    """File name of frame ``index``: 00000.png, 00001.png, ..."""
    return f"{index:05d}{suffix}"


def depth_name(index: int, depth_format: str = "png16") -> str:
    """The depth file of frame ``index`` under depth/: 00000.png (png16) or 00000.npy."""
    return frame_name(index, ".npy" if depth_format == "npy" else ".png")


def frame_paths(out_dir: Path, index: int, depth_format: str = "png16") -> FramePaths:
    name = frame_name(index)
    return FramePaths(out_dir / "frames" / name, out_dir / "depth" / depth_name(index, depth_format),
                      out_dir / "depth_vis" / name)


def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary imageio-ffmpeg uses, checked to run and to have the H.264 encoder.

    Called before any rendering, so a missing or unusable ffmpeg costs the user seconds, not a finished render.
    """
    import subprocess

    hint = "`pip install imageio-ffmpeg` (it bundles one) or point IMAGEIO_FFMPEG_EXE at a working ffmpeg"
    try:
        import imageio_ffmpeg

        exe = imageio_ffmpeg.get_ffmpeg_exe()
        encoders = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True, timeout=30)
    except (ImportError, RuntimeError, OSError, subprocess.TimeoutExpired) as err:
        raise UserError(f"no usable ffmpeg for the videos ({err}); {hint}, then re-run") from None
    if encoders.returncode != 0 or "libx264" not in encoders.stdout:
        raise UserError(f"ffmpeg at {exe} cannot encode H.264 (no libx264 encoder); {hint}, then re-run")
    return exe


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Float RGB [H, W, 3] in [0, 1] -> uint8 [H, W, 3] (rounded, clipped)."""
    return np.clip(np.rint(rgb * _UINT8_MAX), 0, _UINT8_MAX).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write a uint8 [H, W, 3] (RGB) or uint16 [H, W] PNG atomically (OpenCV keeps uint16 unchanged)."""
    import cv2

    # Encoded in memory, so a full disk fails in one plain write (atomic.py makes it a one-line error). OpenCV,
    # not imageio: a Ctrl-C inside imageio's Pillow plugin as it opened left an AttributeError in its clean-up
    # instead of the KeyboardInterrupt (a traceback in 1 of 5 interrupted renders, bench/hostile.py).
    ok, data = cv2.imencode(".png", image[..., ::-1] if image.ndim == 3 else image)
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.dtype} image of shape {image.shape} as PNG")
    write_bytes(path, data.tobytes())


def depth_scale_for(far: float) -> float:
    """The depth_unit_scale_factor of a render whose depths reach at most ``far`` (scene units): the smallest
    1, 2 or 5 times a power of ten whose uint16 range holds ``far`` (with _DEPTH_HEADROOM), so no valid depth is
    ever clipped and a step stays below 2.5e-5 * far (1e-3 for far = 50: millimetres)."""
    if not (math.isfinite(far) and far > 0):
        raise ValueError(f"the far bound must be a positive finite number, got {far}")
    step = far * _DEPTH_HEADROOM / _UINT16_MAX
    exponent = math.floor(math.log10(step))
    # Written as decimal text and parsed, so that 2e-05 is the float nearest to 2e-05, not 2 * 10.0 ** -5.
    return next(s for s in (float(f"{m}e{exponent + e}") for e in (0, 1) for m in (1, 2, 5)) if s >= step)


def depth_to_uint16(depth: np.ndarray, valid: np.ndarray, scale: float) -> tuple[np.ndarray, int]:
    """Depth [H, W] in scene units -> (uint16 steps of ``scale`` [H, W], number of pixels clipped at the maximum).

    Invalid or non-finite pixels become 0; valid depths round to at least 1 step so they never read as invalid.
    With the scale of :func:`depth_scale_for` the clipped count is 0.
    """
    steps = depth / scale
    ok = valid & np.isfinite(steps) & (steps > 0)
    clipped = int((ok & (steps > _UINT16_MAX + 0.5)).sum())
    out = np.where(ok, np.clip(np.rint(steps), 1, _UINT16_MAX), 0).astype(np.uint16)
    return out, clipped


def depth_to_float(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Depth [H, W] in scene units -> float32 [H, W] with NaN where invalid (--depth-format npy)."""
    return np.where(valid & np.isfinite(depth), depth, np.nan).astype(np.float32)


def read_depth(path: Path, scale: float) -> np.ndarray:
    """A depth file back in scene units: float64 [H, W], NaN = invalid (.png: value * scale, 0 invalid; .npy)."""
    if path.suffix == ".npy":
        return np.load(path, allow_pickle=False).astype(np.float64)
    import imageio.v3 as iio

    raw = iio.imread(path)
    return np.where(raw > 0, raw.astype(np.float64) * scale, np.nan)


def depth_to_turbo(depth: np.ndarray, valid: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth [H, W] -> turbo colours uint8 [H, W, 3] (RGB).

    Normalised by disparity between 1/far and 1/near, fixed for the whole path, so colours do not flicker
    between frames and nearby structure gets more of the colour range than the far background.
    """
    import cv2

    disparity = 1.0 / np.maximum(depth, 1e-12)
    t = (disparity - 1.0 / far) / (1.0 / near - 1.0 / far)
    u8 = to_uint8(np.clip(t, 0.0, 1.0)[..., None])[..., 0]
    rgb = cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)[..., ::-1]  # OpenCV returns BGR
    return np.where((valid & np.isfinite(depth))[..., None], rgb, 0).astype(np.uint8)


def write_npy(path: Path, array: np.ndarray) -> None:
    """Write an .npy file atomically (encoded in memory, like write_png)."""
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    write_bytes(path, buffer.getvalue())


def write_frame(paths: FramePaths, rgb: np.ndarray, depth: np.ndarray, depth_vis: np.ndarray) -> None:
    """Write one frame's three files (depth: uint16 [H, W] to a .png, float32 to a .npy); the colour frame last,
    so its presence marks the frame as done."""
    (write_npy if paths.depth.suffix == ".npy" else write_png)(paths.depth, depth)
    write_png(paths.depth_vis, depth_vis)
    write_png(paths.frame, to_uint8(rgb))


def _even(image: np.ndarray) -> np.ndarray:
    """Pad [H, W, 3] by one replicated row/column where needed: yuv420p subsamples chroma 2x2."""
    h, w = image.shape[:2]
    return np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def write_video(path: Path, frame_files: Sequence[Path], fps: float) -> None:
    """Assemble PNG frames into an H.264 yuv420p MP4 atomically (odd sizes are padded to even)."""
    import imageio.v2 as iio2
    import imageio.v3 as iio

    if not frame_files:
        raise UserError(f"no frames to assemble into {path}")
    with atomic_path(path) as tmp:
        # macro_block_size=1: keep the true size instead of imageio's resize up to a multiple of 16.
        writer = iio2.get_writer(tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264", quality=VIDEO_QUALITY,
                                 pixelformat="yuv420p", macro_block_size=1)
        try:
            for file in frame_files:
                writer.append_data(_even(iio.imread(file)))
        finally:
            writer.close()


def write_cameras_json(path: Path, cameras: Cameras, near: Tensor, far: Tensor, depth_scale: float,
                       depth_format: str = "png16", extra: dict | None = None) -> None:
    """Write cameras.json (nerfstudio transforms, OpenGL c2w) for a path of len(cameras) frames, atomically.

    Args:
        cameras: the rendered path in the user's world units; near, far: [F] bounds in the same units.
        depth_scale: depth_unit_scale_factor of the depth PNGs (depth = value * factor; 1 for npy files).
        extra: top-level keys to add (e.g. the path kind, fps, the similarity to the normalised frame).
    Frames are named frames/00000.png, ...; depth files depth/00000.png (or .npy).
    """
    write_nerfstudio_transforms(path, cameras, [f"frames/{frame_name(i)}" for i in range(len(cameras))], near=near,
                                far=far, extra={"depth_unit_scale_factor": depth_scale, "depth_format": depth_format,
                                                **(extra or {})},
                                frame_extras=[{"depth_file_path": f"depth/{depth_name(i, depth_format)}"}
                                              for i in range(len(cameras))])


def check_resumable_scale(out_dir: Path, frames: int, depth_scale: float) -> None:
    """Finished depth PNGs may be kept only if cameras.json will read them with the scale they were written at
    (a render's far bounds, and so its scale, follow the scene's points, so an earlier run's frames may have
    another)."""
    if not _frames_done(out_dir, frames):
        return
    try:
        written = json.loads((out_dir / CAMERAS_JSON).read_text()).get("depth_unit_scale_factor")
    except (OSError, ValueError, AttributeError):
        written = None
    if written != depth_scale:
        raise UserError(f"{out_dir} holds depth maps written at another depth scale ({written} against "
                        f"{depth_scale}: the frames' far bounds changed since, e.g. with an insertnerf upgrade); pass "
                        "--overwrite to render them again, or choose another --out")


def same_cameras_as_written(path: Path, cameras: Cameras) -> bool:
    """Whether cameras.json at ``path`` holds exactly ``cameras`` (poses to 1e-6 of the scene size, sizes).

    Resuming must not mix frames of two paths, e.g. after the scene's poses or this program changed.
    """
    try:
        frames = json.loads(path.read_text())["frames"]
        written = np.array([f["transform_matrix"] for f in frames], dtype=np.float64)  # [F, 4, 4]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    ours = cameras.c2w_opengl.double().cpu().numpy()
    if written.shape != ours.shape:
        return False
    size = max(float(np.abs(ours[:, :3, 3]).max()), 1.0)
    return bool(np.allclose(written, ours, rtol=0.0, atol=1e-6 * size))


# ------------------------------------------------------------------------------------------ output folder
def prepare_out_dir(out_dir: Path, state: dict, overwrite: bool) -> None:
    """Check OUT: resume a run with the same state, refuse to mix with a different run or to write among other
    files (unless overwrite), and with overwrite remove the earlier render (only what insertnerf wrote)."""
    old = read_state(out_dir / STATE_FILE)
    if old == state and not overwrite:
        return
    if not overwrite:
        if old is not None:
            raise UserError(f"{out_dir} already holds a render with other settings ({state_differences(old, state)}); "
                            "pass --overwrite to replace its render outputs, or choose another --out")
        others = foreign_entries(out_dir, OWNER)
        if others:
            raise UserError(f"{out_dir} already holds other files ({', '.join(others[:3])}); pass --overwrite to "
                            "write the render beside them (they are kept), or choose another --out")
    # Poses estimated from the very same photos stay valid whatever else changed.
    same_photos = old is not None and old.get("images") == state.get("images")
    OutputRecord(out_dir, OWNER).remove(legacy=LEGACY_OUTPUTS,
                                       keep=(POSES_DIR, POINTS_DIR) if same_photos else (POINTS_DIR,))
    if not same_photos and (out_dir / POSES_DIR).is_dir():
        OutputRecord(out_dir / POSES_DIR, POSES_OWNER).remove(legacy=POSES_LEGACY_OUTPUTS)
        remove_if_empty(out_dir / POSES_DIR)


def state_differences(old: dict, new: dict) -> str:
    """The settings that differ between two render states, e.g. "frames 2 -> 3; resolution 16 -> 8"."""
    names = {"checkpoint_sha256": "checkpoint", "images": "photos (names, sizes or times)"}
    old, new = _flat(old), _flat(new)  # a render option differs as e.g. "options.blend.margin 1.5 -> 2.0"
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]

    def shown(value: object) -> str:
        text = repr(value)
        return text if len(text) <= 24 else text[:20] + "..."

    parts = [f"{names[k]} changed" if k in names else f"{k} {shown(old.get(k))} -> {shown(new.get(k))}"
             for k in changed]
    return "; ".join(parts) or "unknown"


def _flat(state: dict, prefix: str = "") -> dict:
    """The nested dicts of a state flattened to dotted keys."""
    flat: dict = {}
    for key, value in state.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def claim_render_outputs(out_dir: Path, frames: int, depth_format: str, *more: str) -> None:
    """Record every path the render of ``frames`` frames (and ``more``) will create in OUT, before creating any."""
    names = [p.relative_to(out_dir).as_posix() for i in range(frames)
             for p in vars(frame_paths(out_dir, i, depth_format)).values()]
    OutputRecord(out_dir, OWNER).claim(*FRAME_DIRS, *names, *VIDEOS, CAMERAS_JSON, STATE_FILE, *more)


def write_state(out_dir: Path, state: dict) -> None:
    """Record the settings of this render (once its inputs are ready, so a failed start leaves none behind)."""
    write_json(out_dir / STATE_FILE, state)


def read_state(state_file: Path) -> dict | None:
    """The settings an earlier run recorded, or None (no file, or one cut short or edited into non-JSON)."""
    try:
        return json.loads(state_file.read_text())
    except (OSError, ValueError):
        return None


def check_resumable(out_dir: Path, cameras: Cameras) -> None:
    """Finished frames may be kept only if they were rendered along the same cameras (user units)."""
    if _frames_done(out_dir, len(cameras)) and not same_cameras_as_written(out_dir / CAMERAS_JSON, cameras):
        raise UserError(f"{out_dir} holds frames of a different camera path (the scene's poses or insertnerf "
                        "changed since); pass --overwrite to render them again, or choose another --out")


def _frames_done(out_dir: Path, frames: int) -> bool:
    """Whether OUT already holds a finished frame of a ``frames``-frame path (a run to resume)."""
    return any((out_dir / "frames" / frame_name(i)).exists() for i in range(frames))
