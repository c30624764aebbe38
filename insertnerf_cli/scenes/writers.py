"""Writers of Blender (NeRF-Synthetic) and nerfstudio/instant-ngp ``transforms*.json`` files.

Both store OpenGL camera-to-world matrices (``Cameras.c2w_opengl``) and file paths relative to the JSON file.
Our extension keys, read back by :mod:`insertnerf_cli.scenes`: ``near``/``far`` (top level or per frame, world
units along the camera axis), ``layout`` ("object" | "forward"), per-frame ``depth_file_path`` with a top-level
``depth_unit_scale_factor``.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.files.atomic import write_json


def _relative(path: str | os.PathLike, base: Path) -> str:
    """A path as stored in the JSON: posix, relative to the JSON's folder when given as an absolute path."""
    p = Path(path)
    if p.is_absolute():
        p = Path(os.path.relpath(p, base.resolve()))
    return p.as_posix()


def _intrinsics(cameras: Cameras, i: int) -> dict[str, float]:
    """fl_x, fl_y, cx, cy, w, h of camera ``i`` (pixel units, full image)."""
    K = cameras.K[i].detach().to("cpu", torch.float64)
    return {"fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "w": int(cameras.width), "h": int(cameras.height)}


def _bounds(value: Any) -> float | list[float] | None:
    """A bound as given (a number, a 0-d tensor, or N values as a sequence/array/tensor [N]) -> float or list."""
    if value is None:
        return None
    if isinstance(value, (int, float)):
        return float(value)
    values = torch.as_tensor(value, dtype=torch.float64).reshape(-1) if not isinstance(value, torch.Tensor) \
        else value.detach().to("cpu", torch.float64).reshape(-1)
    if getattr(value, "ndim", 1) == 0:
        return float(values[0])
    return values.tolist()


def _json_value(value: Any, base: Path) -> Any:
    """Paths become posix strings relative to the JSON's folder; everything else is kept."""
    return _relative(value, base) if isinstance(value, os.PathLike) else value


def _frames(path: Path, cameras: Cameras, file_paths: Sequence[str | os.PathLike],
            near: Any, far: Any, frame_extras: Sequence[Mapping[str, Any]] | None) -> list[dict[str, Any]]:
    """One dict per camera with file_path, transform_matrix and the extension keys."""
    n = len(cameras)
    if len(file_paths) != n or (frame_extras is not None and len(frame_extras) != n):
        raise ValueError(f"{n} cameras need {n} file paths and frame extras, got {len(file_paths)} and "
                         f"{None if frame_extras is None else len(frame_extras)}")
    c2w = cameras.c2w_opengl.detach().to("cpu", torch.float64)
    frames = []
    for i in range(n):
        frame: dict[str, Any] = {"file_path": _relative(file_paths[i], path.parent),
                                 "transform_matrix": (c2w[i] + 0.0).tolist()}  # +0.0 turns -0.0 into 0.0
        if isinstance(near, list):
            frame["near"], frame["far"] = near[i], far[i]
        extras = frame_extras[i] if frame_extras is not None else {}
        frame.update({k: _json_value(v, path.parent) for k, v in extras.items()})
        frames.append(frame)
    return frames


def _shared_intrinsics(cameras: Cameras) -> bool:
    return bool(torch.allclose(cameras.K, cameras.K[:1].expand_as(cameras.K), rtol=0.0, atol=1e-12))


def _write(path: Path, top: dict[str, Any], cameras: Cameras, file_paths: Sequence[str | os.PathLike],
           bounds: tuple[Any, Any], extra: Mapping[str, Any] | None,
           frame_extras: Sequence[Mapping[str, Any]] | None) -> None:
    """Add frames, intrinsics (top level when shared, per frame otherwise), bounds and extras; write atomically."""
    near, far = _bounds(bounds[0]), _bounds(bounds[1])
    if (near is None) != (far is None) or isinstance(near, list) != isinstance(far, list):
        raise ValueError("near and far must be given together, both scalars or both per view")
    frames = _frames(path, cameras, file_paths, near, far, frame_extras)
    if _shared_intrinsics(cameras):
        top.update(_intrinsics(cameras, 0))
    else:
        for i, frame in enumerate(frames):
            frame.update(_intrinsics(cameras, i))
    if isinstance(near, float):
        top["near"], top["far"] = near, far
    top.update({k: _json_value(v, path.parent) for k, v in (extra or {}).items()})
    top["frames"] = frames
    write_json(path, top)


def write_blender_transforms(path: str | os.PathLike, cameras: Cameras, file_paths: Sequence[str | os.PathLike],
                             near: Any = None, far: Any = None, extra: Mapping[str, Any] | None = None,
                             frame_extras: Sequence[Mapping[str, Any]] | None = None) -> None:
    """Write a NeRF-Synthetic style ``transforms_<split>.json`` atomically.

    Args:
        path: the JSON file to write (its folder is the base of relative file paths).
        cameras: N cameras; ``camera_angle_x`` comes from camera 0, and ``fl_x fl_y cx cy w h`` are written
            too (top level when shared, per frame otherwise) so non-square or off-centre cameras round-trip.
        file_paths: N image paths, relative to the JSON's folder (absolute paths are made relative).
        near, far: a float each (top-level keys) or N values each (per-frame keys), or None.
        extra: keys merged into the top level, e.g. {"layout": "object", "depth_unit_scale_factor": 0.001}.
        frame_extras: N dicts merged into the frames, e.g. {"depth_file_path": "depth/r_0.png"}.
    """
    path = Path(path)
    fx = float(cameras.K[0, 0, 0])
    top: dict[str, Any] = {"camera_angle_x": 2.0 * math.atan(0.5 * cameras.width / fx)}
    _write(path, top, cameras, file_paths, (near, far), extra, frame_extras)


def write_nerfstudio_transforms(path: str | os.PathLike, cameras: Cameras, file_paths: Sequence[str | os.PathLike],
                                near: Any = None, far: Any = None, extra: Mapping[str, Any] | None = None,
                                frame_extras: Sequence[Mapping[str, Any]] | None = None) -> None:
    """Write a nerfstudio / instant-ngp ``transforms.json`` atomically (pinhole: ``camera_model`` OPENCV, no
    distortion). Arguments as :func:`write_blender_transforms`."""
    path = Path(path)
    top: dict[str, Any] = {"camera_model": "OPENCV"}
    _write(path, top, cameras, file_paths, (near, far), extra, frame_extras)
