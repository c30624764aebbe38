"""Frames of ``transforms*.json`` files, shared by the Blender and nerfstudio/instant-ngp readers.

Each frame's keys override the top-level ones: intrinsics ``fl_x fl_y cx cy w h`` (else ``camera_angle_x``/
``camera_angle_y`` with a centred principal point), distortion ``k1 k2 k3 k4 p1 p2`` with ``camera_model``,
and our ``near``/``far``; ``depth_file_path`` per frame with the top-level ``depth_unit_scale_factor``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import intrinsics, opengl_to_opencv
from insertnerf_cli.errors import SceneError, os_error_message
from insertnerf_cli.scenes.common import names_list, safe_path
from insertnerf_cli.scenes.images import Distortion, image_size
from insertnerf_cli.scenes.values import matrix, number, objects, text, whole

# nerfstudio's default for depth_unit_scale_factor: 16-bit PNGs in millimetres of a metre-scale scene.
DEFAULT_DEPTH_SCALE = 1e-3
_RADIAL_TANGENTIAL = ("k1", "k2", "p1", "p2", "k3")  # cv2.undistort order
_FISHEYE = ("k1", "k2", "k3", "k4")


@dataclass(frozen=True)
class Frames:
    """Frames of one or more transforms files. N frames.

    Attributes:
        paths: N image files; K [N, 3, 3] for ``sizes`` (N (height, width)); c2w [N, 4, 4] OpenCV.
        near, far: [N] when every frame has bounds, else None.
        depth_paths: N depth files when every frame has one, else None.
        distortion: N entries (None for pinhole), or None when no frame is distorted.
    """

    paths: list[Path]
    K: Tensor  # [N, 3, 3]
    sizes: list[tuple[int, int]]
    c2w: Tensor  # [N, 4, 4]
    near: Tensor | None
    far: Tensor | None
    depth_paths: list[Path] | None
    distortion: list[Distortion | None] | None


def load_json(path: Path) -> dict[str, Any]:
    """Parse a JSON object, with a one-line SceneError for unreadable or malformed files."""
    try:
        data = json.loads(path.read_text())
    except OSError as err:
        raise SceneError(os_error_message(err)) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SceneError(f"cannot read {path}: {err}") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise SceneError(f"{path} is not a transforms file: it needs a top-level object with a 'frames' list")
    objects(data["frames"], "frames", path)
    return data


@dataclass(frozen=True)
class FrameKeys:
    """One frame's keys, falling back to the file's top-level ones; every value is read through values.py."""

    frame: dict[str, Any]
    meta: dict[str, Any]
    index: int
    source: Path

    def field(self, key: str) -> str:
        """Where a key's value comes from, for messages: 'frames[3].fl_x' or the top-level 'fl_x'."""
        return f"frames[{self.index}].{key}" if key in self.frame else key

    def raw(self, key: str) -> Any:
        return self.frame.get(key, self.meta.get(key))

    def number(self, key: str, default: float | None = None, **limits: Any) -> float | None:
        value = self.raw(key)
        return default if value is None else number(value, self.field(key), self.source, **limits)

    def whole(self, key: str) -> int | None:
        value = self.raw(key)
        return None if value is None else whole(value, self.field(key), self.source)


def _image_path(root: Path, keys: FrameKeys, default_ext: str | None) -> Path:
    if "file_path" not in keys.frame:
        raise SceneError(f"{keys.source}: frames[{keys.index}] has no 'file_path'")
    field = keys.field("file_path")
    path = safe_path(root, text(keys.frame.get("file_path"), field, keys.source), field, keys.source)
    if default_ext and not path.suffix and not path.is_file():
        path = path.with_suffix(default_ext)  # NeRF-Synthetic writes './train/r_0' for './train/r_0.png'
    return path


def _focal(keys: FrameKeys, axis: str, size: int) -> float | None:
    """fl_<axis>, else the focal length of camera_angle_<axis> over ``size`` pixels, else None."""
    focal = keys.number(f"fl_{axis}", low=0.0, unit=" (pixels)")
    if focal is not None:
        return focal
    angle = keys.number(f"camera_angle_{axis}", low=0.0, high=math.pi, unit=" (radians)")
    return None if angle is None else 0.5 * size / math.tan(0.5 * angle)


def frame_intrinsics(keys: FrameKeys, path: Path | None) -> tuple[Tensor, tuple[int, int]]:
    """K [3, 3] and the (height, width) it refers to, from keys (the image ``path``'s size when w/h are absent;
    None: no image to read, w/h are required)."""
    h, w = keys.whole("h"), keys.whole("w")
    if h is None or w is None:
        if path is None:
            raise SceneError(f"{keys.source}: frames[{keys.index}] gives no 'w'/'h' (the image size)")
        if not path.is_file():
            raise SceneError(f"{path}: image is missing and the transforms file gives no 'w'/'h'")
        h, w = image_size(path)
    fx = _focal(keys, "x", w)
    if fx is None:
        raise SceneError(f"{keys.source}: frames[{keys.index}] has no focal length: the transforms file needs "
                         "'fl_x' or 'camera_angle_x'")
    fy = _focal(keys, "y", h) or fx
    cx, cy = keys.number("cx", 0.5 * w), keys.number("cy", 0.5 * h)
    return intrinsics(fx, fy, cx, cy), (h, w)


def _distortion(keys: FrameKeys) -> Distortion | None:
    """The frame's distortion, None when all coefficients are zero; refuses models we cannot undistort exactly."""
    model = str(keys.raw("camera_model") or "OPENCV").upper()
    if model in ("EQUIRECTANGULAR", "OMNIDIRECTIONALSTEREO_L", "OMNIDIRECTIONALSTEREO_R"):
        raise SceneError(f"{keys.source}: camera_model {model} is not a pinhole camera; only OPENCV and "
                         "OPENCV_FISHEYE are supported")
    names = _FISHEYE if model == "OPENCV_FISHEYE" else _RADIAL_TANGENTIAL
    coeffs = tuple(keys.number(k, 0.0) for k in names)
    if model != "OPENCV_FISHEYE" and keys.number("k4", 0.0) != 0.0:
        raise SceneError(f"{keys.source}: k4 is set for an OPENCV camera, which OpenCV cannot undistort; "
                         "undistort the images first (e.g. `insertnerf poses`)")
    if not any(coeffs):
        return None
    return Distortion("fisheye" if model == "OPENCV_FISHEYE" else "opencv", coeffs)


def frame_pose(keys: FrameKeys) -> Tensor:
    """[4, 4] OpenCV camera-to-world of the frame's ``transform_matrix`` (OpenGL in the file)."""
    c2w_gl = matrix(keys.frame.get("transform_matrix"), f"frames[{keys.index}].transform_matrix", keys.source,
                    [(4, 4)])
    return opengl_to_opencv(torch.from_numpy(c2w_gl))


def _all_or_none(values: list[Any], what: str, source: Path) -> list[Any] | None:
    present = [v is not None for v in values]
    if any(present) and not all(present):
        raise SceneError(f"{source}: {sum(present)} of {len(values)} frames have '{what}'; give it for all or none")
    return values if all(present) else None


def read_frames(root: Path, sources: list[tuple[Path, dict[str, Any]]], default_ext: str | None) -> Frames:
    """Frames of the given (json path, parsed json) pairs, in order; all file paths relative to ``root``."""
    paths, Ks, sizes, poses, bounds, depths, dists = [], [], [], [], [], [], []
    for source, meta in sources:
        for index, frame in enumerate(meta["frames"]):
            keys = FrameKeys(frame, meta, index, source)
            path = _image_path(root, keys, default_ext)
            K, size = frame_intrinsics(keys, path)
            paths.append(path)
            Ks.append(K)
            sizes.append(size)
            poses.append(frame_pose(keys))
            near, far = keys.number("near"), keys.number("far")
            bounds.append(None if near is None or far is None else (near, far))
            depth = frame.get("depth_file_path")
            field = keys.field("depth_file_path")
            depths.append(None if depth is None else safe_path(root, text(depth, field, source), field, source))
            dists.append(_distortion(keys))
    if not paths:
        raise SceneError(f"{names_list([s for s, _ in sources])}: no frames")
    bounds_ok = _all_or_none(bounds, "near/far", sources[0][0])
    near_far = torch.tensor(bounds_ok, dtype=torch.float64).T if bounds_ok else None  # [2, N]
    return Frames(paths=paths, K=torch.stack(Ks), sizes=sizes, c2w=torch.stack(poses),
                  near=None if near_far is None else near_far[0], far=None if near_far is None else near_far[1],
                  depth_paths=_all_or_none(depths, "depth_file_path", sources[0][0]),
                  distortion=dists if any(d is not None for d in dists) else None)


def depth_scale(meta: dict[str, Any], frames: Frames, source: Path) -> float:
    """Scene units per stored depth unit: the file's factor, nerfstudio's default with depth files, else 1."""
    default = DEFAULT_DEPTH_SCALE if frames.depth_paths else 1.0
    value = meta.get("depth_unit_scale_factor")
    return default if value is None else number(value, "depth_unit_scale_factor", source, low=0.0)


def layout_key(meta: dict[str, Any], source: Path) -> str | None:
    """Our 'layout' key ("object" | "forward"), None when absent."""
    layout = meta.get("layout")
    if layout not in (None, "object", "forward"):
        raise SceneError(f"{source}: 'layout' must be \"object\" or \"forward\", got {layout!r}")
    return layout
