"""What `insertnerf render` writes, each file through a temporary name and a rename (atomic.py), each path
recorded in OUT/.insertnerf-outputs.json before it is made (outdir.py: what --overwrite may remove):

    OUT/frames/00000.png      RGB, 8 bit
    OUT/depth/00000.png       uint16 millimetres in the user's scene units (value / 1000 = depth), 0 = invalid
                              (opacity below 0.5, or not finite)
    OUT/depth_vis/00000.png   the depth as a turbo colour map (near = red, far = blue, invalid = black)
    OUT/video.mp4, depth.mp4  H.264 yuv420p through imageio-ffmpeg, assembled from the PNGs
    OUT/cameras.json          nerfstudio-style transforms of the rendered path (OpenGL c2w) with the depth scale
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from torch import Tensor

from .atomic import atomic_path, write_bytes, write_json
from .cameras import Cameras
from .errors import UserError
from .outdir import OutputRecord, check_output, foreign_entries, holds_files, remove_if_empty
from .poses_io import LEGACY_OUTPUTS as POSES_LEGACY_OUTPUTS, OWNER as POSES_OWNER

FRAME_DIRS = ("frames", "depth", "depth_vis")
VIDEOS = ("video.mp4", "depth.mp4")
CAMERAS_JSON = "cameras.json"
OWNER = "render"  # the name of its list in an output record (outdir.py)
STATE_FILE = "render_config.json"  # the settings the frames depend on: equal settings may resume
POSES_DIR = "poses"  # poses pycolmap estimated for a folder of photos
# What renders of versions without an output record wrote: the only names --overwrite removes from such a folder.
_FRAME_GLOB = "[0-9][0-9][0-9][0-9][0-9].png"
LEGACY_OUTPUTS = (*(f"{d}/{_FRAME_GLOB}" for d in FRAME_DIRS), *(f"{d}/" for d in FRAME_DIRS), *VIDEOS,
                  CAMERAS_JSON, STATE_FILE)
# A PNG ends with this IEND chunk; a file cut short by a crash or power loss lacks it.
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
# Depth PNGs store millimetres of the user's unit, as nerfstudio's depth files do.
DEPTH_UNIT_SCALE = 1e-3
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
        """Whether all three files are complete PNGs (a zero-byte or truncated one means: render again)."""
        return all(is_complete_png(p) for p in (self.frame, self.depth, self.depth_vis))


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


def frame_name(index: int) -> str:
    """File name of frame ``index``: 00000.png, 00001.png, ..."""
    return f"{index:05d}.png"


def frame_paths(out_dir: Path, index: int) -> FramePaths:
    name = frame_name(index)
    return FramePaths(*(out_dir / sub / name for sub in FRAME_DIRS))


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
    """Write a uint8 [H, W, 3] or uint16 [H, W] PNG atomically (imageio keeps uint16 unchanged)."""
    import imageio.v3 as iio

    # Encoded in memory, so a full disk fails in one plain write (atomic.py makes it a one-line error).
    write_bytes(path, iio.imwrite("<bytes>", image, extension=".png"))


def depth_to_uint16(depth: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, int]:
    """Depth [H, W] in user units -> (uint16 millimetres [H, W], number of pixels clipped at the maximum).

    Invalid or non-finite pixels become 0; valid depths round to at least 1 mm so they never read as invalid.
    """
    mm = depth / DEPTH_UNIT_SCALE
    ok = valid & np.isfinite(mm) & (mm > 0)
    clipped = int((ok & (mm > _UINT16_MAX)).sum())
    out = np.where(ok, np.clip(np.rint(mm), 1, _UINT16_MAX), 0).astype(np.uint16)
    return out, clipped


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


def write_frame(paths: FramePaths, rgb: np.ndarray, depth_mm: np.ndarray, depth_vis: np.ndarray) -> None:
    """Write one frame's three files; the colour frame last, so its presence marks the frame as done."""
    write_png(paths.depth, depth_mm)
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


def video_codec(path: Path) -> str:
    """The codec line ffmpeg reports for a video (e.g. "h264 (High) (avc1 / 0x31637661)")."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
    finally:
        reader.close()
    return str(meta["codec"])


def write_cameras_json(path: Path, cameras: Cameras, near: Tensor, far: Tensor, extra: dict | None = None) -> None:
    """Write cameras.json (nerfstudio transforms, OpenGL c2w) for a path of len(cameras) frames, atomically.

    Args:
        cameras: the rendered path in the user's world units; near, far: [F] bounds in the same units.
        extra: top-level keys to add (e.g. the path kind, fps, the similarity to the normalised frame).
    Frames are named frames/00000.png, ...; depth files hold millimetres: depth = value * depth_unit_scale_factor.
    """
    from .scenes.writers import write_nerfstudio_transforms

    names = [frame_name(i) for i in range(len(cameras))]
    write_nerfstudio_transforms(path, cameras, [f"frames/{n}" for n in names], near=near, far=far,
                                extra={"depth_unit_scale_factor": DEPTH_UNIT_SCALE, **(extra or {})},
                                frame_extras=[{"depth_file_path": f"depth/{n}"} for n in names])


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
    OutputRecord(out_dir, OWNER).remove(legacy=LEGACY_OUTPUTS, keep=(POSES_DIR,) if same_photos else ())
    if not same_photos and (out_dir / POSES_DIR).is_dir():
        OutputRecord(out_dir / POSES_DIR, POSES_OWNER).remove(legacy=POSES_LEGACY_OUTPUTS)
        remove_if_empty(out_dir / POSES_DIR)


def state_differences(old: dict, new: dict) -> str:
    """The settings that differ between two render states, e.g. "frames 2 -> 3; resolution 16 -> 8"."""
    names = {"checkpoint_sha256": "checkpoint", "images": "photos (names, sizes or times)"}
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]

    def shown(value: object) -> str:
        text = repr(value)
        return text if len(text) <= 24 else text[:20] + "..."

    parts = [f"{names[k]} changed" if k in names else f"{k} {shown(old.get(k))} -> {shown(new.get(k))}"
             for k in changed]
    return "; ".join(parts) or "unknown"


def claim_render_outputs(out_dir: Path, frames: int) -> None:
    """Record every path the render of ``frames`` frames will create in OUT, before creating any."""
    names = [f"{d}/{frame_name(i)}" for d in FRAME_DIRS for i in range(frames)]
    OutputRecord(out_dir, OWNER).claim(*FRAME_DIRS, *names, *VIDEOS, CAMERAS_JSON, STATE_FILE)


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
    done = any(frame_paths(out_dir, i).frame.exists() for i in range(len(cameras)))
    if done and not same_cameras_as_written(out_dir / CAMERAS_JSON, cameras):
        raise UserError(f"{out_dir} holds frames of a different camera path (the scene's poses or insertnerf "
                        "changed since); pass --overwrite to render them again, or choose another --out")


# ------------------------------------------------------------------------------------------ eval outputs
# Side-by-sides that eval versions without an output record wrote (what --overwrite removes from such a folder).
_EVAL_LEGACY_OUTPUTS = (_FRAME_GLOB,)


def check_eval_outputs(scene_dir: Path, checkpoint: Path | None, json_path: Path | None, out_dir: Path | None,
                       overwrite: bool) -> None:
    """Refuse, before any work, eval outputs inside the inputs or not writable, and replacing an existing report
    or side-by-sides without overwrite."""
    inputs = [scene_dir, checkpoint]
    if json_path is not None:
        check_output(Path(json_path), inputs, is_dir=False, what="--json", kind="input scene or checkpoint")
    if out_dir is not None:
        check_output(Path(out_dir), inputs, kind="input scene or checkpoint")
    if overwrite:
        return
    if json_path is not None and Path(json_path).exists():
        raise UserError(f"{json_path} exists; pass --overwrite to replace it or choose another --json")
    if out_dir is not None and holds_files(Path(out_dir)):
        raise UserError(f"{out_dir} is not empty; pass --overwrite to replace the images insertnerf wrote "
                        "there (other files are kept) or choose another --out")


def prepare_side_by_sides(out_dir: Path | None, held: list[int]) -> None:
    """Remove the side-by-sides of an earlier eval (only ours) and record the ones this run writes."""
    if out_dir is None:
        return
    record = OutputRecord(out_dir, "eval")
    record.remove(legacy=_EVAL_LEGACY_OUTPUTS)
    record.claim(*(frame_name(i) for i in held))


# Absolute colour error that maps to the top of the colour map in eval's side-by-sides: errors past a quarter of
# the range are already glaring, and a fixed scale keeps images of different views comparable.
ERROR_VIS_MAX = 0.25


def side_by_side(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """[H, 3W, 3] uint8: render | truth | per-pixel mean absolute error (turbo, 0 to ERROR_VIS_MAX)."""
    import cv2

    error = np.abs(render.astype(np.float64) - truth).mean(-1) / ERROR_VIS_MAX
    error_rgb = cv2.applyColorMap(to_uint8(np.clip(error, 0, 1)[..., None])[..., 0], cv2.COLORMAP_TURBO)[..., ::-1]
    return np.concatenate([to_uint8(render), to_uint8(truth), error_rgb], axis=1)
