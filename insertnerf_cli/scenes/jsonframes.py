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

from ..cameras import check_shape, intrinsics, opengl_to_opencv
from .base import Distortion, SceneError
from .common import names_list, safe_path
from .images import image_size

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
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SceneError(f"cannot read {path}: {err}") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise SceneError(f"{path} is not a transforms file: it needs a top-level object with a 'frames' list")
    return data


def _image_path(root: Path, frame: dict[str, Any], default_ext: str | None, source: Path) -> Path:
    if "file_path" not in frame:
        raise SceneError(f"{source}: a frame has no 'file_path'")
    path = safe_path(root, frame["file_path"], "file_path")
    if default_ext and not path.suffix and not path.is_file():
        path = path.with_suffix(default_ext)  # NeRF-Synthetic writes './train/r_0' for './train/r_0.png'
    return path


def _intrinsics(get: Any, path: Path) -> tuple[Tensor, tuple[int, int]]:
    """K [3, 3] and the (height, width) it refers to, from keys (file size when w/h are absent)."""
    if get("w") is not None and get("h") is not None:
        h, w = int(get("h")), int(get("w"))
    else:
        h, w = image_size(path) if path.is_file() else (0, 0)
        if h == 0:
            raise SceneError(f"{path}: image is missing and the transforms file gives no 'w'/'h'")
    if get("fl_x") is not None:
        fx = float(get("fl_x"))
        fy = float(get("fl_y")) if get("fl_y") is not None else fx
    elif get("camera_angle_x") is not None:
        fx = 0.5 * w / math.tan(0.5 * float(get("camera_angle_x")))
        fy = 0.5 * h / math.tan(0.5 * float(get("camera_angle_y"))) if get("camera_angle_y") is not None else fx
    else:
        raise SceneError(f"{path}: no focal length: the transforms file needs 'fl_x' or 'camera_angle_x'")
    cx = float(get("cx")) if get("cx") is not None else 0.5 * w
    cy = float(get("cy")) if get("cy") is not None else 0.5 * h
    return intrinsics(fx, fy, cx, cy), (h, w)


def _distortion(get: Any, source: Path) -> Distortion | None:
    """The frame's distortion, None when all coefficients are zero; refuses models we cannot undistort exactly."""
    model = str(get("camera_model") or "OPENCV").upper()
    if model in ("EQUIRECTANGULAR", "OMNIDIRECTIONALSTEREO_L", "OMNIDIRECTIONALSTEREO_R"):
        raise SceneError(f"{source}: camera_model {model} is not a pinhole camera; only OPENCV and "
                         "OPENCV_FISHEYE are supported")
    names = _FISHEYE if model == "OPENCV_FISHEYE" else _RADIAL_TANGENTIAL
    coeffs = tuple(float(get(k) or 0.0) for k in names)
    if model != "OPENCV_FISHEYE" and float(get("k4") or 0.0) != 0.0:
        raise SceneError(f"{source}: k4 is set for an OPENCV camera, which OpenCV cannot undistort; "
                         "undistort the images first (e.g. `insertnerf poses`)")
    if not any(coeffs):
        return None
    return Distortion("fisheye" if model == "OPENCV_FISHEYE" else "opencv", coeffs)


def _pose(frame: dict[str, Any], source: Path) -> Tensor:
    try:
        c2w_gl = torch.tensor(frame["transform_matrix"], dtype=torch.float64)
        check_shape("transform_matrix", c2w_gl, (4, 4))
    except (KeyError, TypeError, ValueError, RuntimeError):
        raise SceneError(f"{source}: a frame has no valid 4x4 'transform_matrix'") from None
    return opengl_to_opencv(c2w_gl)


def _all_or_none(values: list[Any], what: str, source: Path) -> list[Any] | None:
    present = [v is not None for v in values]
    if any(present) and not all(present):
        raise SceneError(f"{source}: {sum(present)} of {len(values)} frames have '{what}'; give it for all or none")
    return values if all(present) else None


def read_frames(root: Path, sources: list[tuple[Path, dict[str, Any]]], default_ext: str | None) -> Frames:
    """Frames of the given (json path, parsed json) pairs, in order; all file paths relative to ``root``."""
    paths, Ks, sizes, poses, bounds, depths, dists = [], [], [], [], [], [], []
    for source, meta in sources:
        for frame in meta["frames"]:
            get = lambda key, f=frame: f.get(key, meta.get(key))  # noqa: E731 - per-frame key, else top level
            path = _image_path(root, frame, default_ext, source)
            K, size = _intrinsics(get, path)
            paths.append(path)
            Ks.append(K)
            sizes.append(size)
            poses.append(_pose(frame, source))
            near, far = get("near"), get("far")
            bounds.append(None if near is None or far is None else (float(near), float(far)))
            depth = frame.get("depth_file_path")
            depths.append(None if depth is None else safe_path(root, depth, "depth_file_path"))
            dists.append(_distortion(get, source))
    if not paths:
        raise SceneError(f"{names_list([s for s, _ in sources])}: no frames")
    bounds_ok = _all_or_none(bounds, "near/far", sources[0][0])
    near_far = torch.tensor(bounds_ok, dtype=torch.float64).T if bounds_ok else None  # [2, N]
    return Frames(paths=paths, K=torch.stack(Ks), sizes=sizes, c2w=torch.stack(poses),
                  near=None if near_far is None else near_far[0], far=None if near_far is None else near_far[1],
                  depth_paths=_all_or_none(depths, "depth_file_path", sources[0][0]),
                  distortion=dists if any(d is not None for d in dists) else None)


def depth_scale(meta: dict[str, Any], frames: Frames) -> float:
    """Scene units per stored depth unit: the file's factor, nerfstudio's default with depth files, else 1."""
    return float(meta.get("depth_unit_scale_factor", DEFAULT_DEPTH_SCALE if frames.depth_paths else 1.0))


def layout_key(meta: dict[str, Any], source: Path) -> str | None:
    """Our 'layout' key ("object" | "forward"), None when absent."""
    layout = meta.get("layout")
    if layout not in (None, "object", "forward"):
        raise SceneError(f"{source}: 'layout' must be \"object\" or \"forward\", got {layout!r}")
    return layout
