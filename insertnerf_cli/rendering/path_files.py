"""Camera paths from a file (`render --path FILE`): nerfstudio's `camera_path.json`, or a `transforms.json` of target
cameras. The file's cameras are in the scene's own units and axes, as its transforms file or COLMAP model states
them; render follows them exactly (docs/commands/render.md).

nerfstudio `camera_path.json` (its viewer's export): ``camera_path`` [F] of {``camera_to_world``: 16 numbers, a
4x4 OpenGL camera-to-world row by row; ``fov``: the vertical field of view in degrees; ``aspect``: width / height},
with ``render_height``, ``render_width`` and ``fps`` at the top. The keyframes it was sampled from are not read:
``camera_path`` already holds every frame. A `transforms.json` gives ``frames`` [F] of {``transform_matrix``: 4x4
OpenGL}, with ``fl_x`` or ``camera_angle_x``, optional ``fl_y``, ``cx``, ``cy``, and ``w``, ``h`` per frame or at the
top; no image needs to exist.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics, opengl_to_opencv
from insertnerf_cli.errors import SceneError, UserError
from insertnerf_cli.scenes.values import matrix, number, objects, whole

# A rotation whose columns are further than this from orthonormal, or with a determinant below 0, is no camera.
RIGID_TOLERANCE = 1e-4
MAX_SIDE = 16384


@dataclass(frozen=True)
class PathFile:
    """The cameras of a path file, in the scene's own (unnormalised) world.

    Attributes:
        source: the file; kind: "nerfstudio-camera-path" or "transforms".
        cameras: F cameras, OpenCV c2w, at the file's image size.
        fps: the file's frame rate, or None where it gives none.
        sha256: of the file's bytes, so that a resumed render knows the path is the same.
    """

    source: Path
    kind: str
    cameras: Cameras
    fps: float | None
    sha256: str


def read_path_file(path: Path) -> PathFile:
    """The cameras of a nerfstudio `camera_path.json` or a `transforms.json` of target cameras.

    Raises:
        UserError: one line naming the file and what is wrong (not JSON, a missing key, a pose that is not rigid,
            a field of view that is not in (0, 180) degrees, sizes that differ between frames).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
        data = json.loads(raw)
    except OSError as err:
        raise UserError(f"cannot read the camera path {path}: {err.strerror or err}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserError(f"the camera path {path} is not JSON ({err}); give nerfstudio's camera_path.json or a "
                        "transforms.json of target cameras") from None
    try:
        if isinstance(data, dict) and "camera_path" in data:
            kind, (cameras, fps) = "nerfstudio-camera-path", _camera_path(data, path)
        elif isinstance(data, dict) and "frames" in data:
            kind, (cameras, fps) = "transforms", _transforms(data, path)
        else:
            raise SceneError(f"{path} holds neither 'camera_path' (nerfstudio's camera_path.json) nor 'frames' (a "
                             "transforms.json of target cameras)")
    except SceneError as err:
        raise UserError(str(err)) from None
    return PathFile(path, kind, cameras, fps, hashlib.sha256(raw).hexdigest())


def _camera_path(data: dict[str, Any], source: Path) -> tuple[Cameras, float | None]:
    height, width = _size(data, "render_height", "render_width", source)
    frames = objects(data["camera_path"], "camera_path", source)
    if not frames:
        raise SceneError(f"{source}: 'camera_path' holds no camera")
    Ks, poses = [], []
    for i, frame in enumerate(frames):
        for key in ("camera_to_world", "fov"):
            if key not in frame:
                raise SceneError(f"{source}: camera_path[{i}] has no '{key}'")
        fov = number(frame["fov"], f"camera_path[{i}].fov", source, low=0.0, high=180.0, unit=" (degrees)")
        if not 0.0 < fov < 180.0:
            raise SceneError(f"{source}: camera_path[{i}].fov is {fov:g} degrees; a field of view lies strictly "
                             "between 0 and 180")
        focal = 0.5 * height / math.tan(math.radians(fov) / 2.0)  # nerfstudio's fov is vertical
        Ks.append(intrinsics(focal, focal, 0.5 * width, 0.5 * height))
        poses.append(_pose(frame["camera_to_world"], f"camera_path[{i}].camera_to_world", source, [(16,), (4, 4)]))
    fps = number(data["fps"], "fps", source, low=0.0) if data.get("fps") is not None else None
    if fps is not None and fps <= 0:
        raise SceneError(f"{source}: fps must be positive, got {fps:g}")
    return Cameras(torch.stack(Ks), torch.stack(poses), height, width), fps


def _transforms(data: dict[str, Any], source: Path) -> tuple[Cameras, float | None]:
    frames = objects(data["frames"], "frames", source)
    if not frames:
        raise SceneError(f"{source}: 'frames' holds no camera")
    Ks, poses, sizes = [], [], set()
    for i, frame in enumerate(frames):
        keys = {**data, **frame}
        if "transform_matrix" not in frame:
            raise SceneError(f"{source}: frames[{i}] has no 'transform_matrix'")
        height, width = _size(keys, "h", "w", source)
        sizes.add((height, width))
        fx = _focal(keys, "x", width, i, source)
        if fx is None:
            raise SceneError(f"{source}: frames[{i}] has no focal length: give 'fl_x' or 'camera_angle_x'")
        fy = _focal(keys, "y", height, i, source) or fx
        cx = number(keys.get("cx", 0.5 * width), "cx", source)
        cy = number(keys.get("cy", 0.5 * height), "cy", source)
        Ks.append(intrinsics(fx, fy, cx, cy))
        poses.append(_pose(frame["transform_matrix"], f"frames[{i}].transform_matrix", source, [(4, 4)]))
    if len(sizes) > 1:
        raise SceneError(f"{source}: the frames give {len(sizes)} image sizes; a path renders one size")
    (height, width), = sizes
    return Cameras(torch.stack(Ks), torch.stack(poses), height, width), None


def _size(keys: dict[str, Any], h_key: str, w_key: str, source: Path) -> tuple[int, int]:
    for key in (h_key, w_key):
        if key not in keys:
            raise SceneError(f"{source}: no '{key}' (the image size of the path's frames)")
    height, width = whole(keys[h_key], h_key, source), whole(keys[w_key], w_key, source)
    if not (0 < height <= MAX_SIDE and 0 < width <= MAX_SIDE):
        raise SceneError(f"{source}: an image of {width}x{height} px; width and height must lie in 1..{MAX_SIDE}")
    return height, width


def _focal(keys: dict[str, Any], axis: str, size: int, index: int, source: Path) -> float | None:
    """fl_<axis> in pixels, else the focal length of camera_angle_<axis> (radians) over ``size`` px, else None."""
    if keys.get(f"fl_{axis}") is not None:
        focal = number(keys[f"fl_{axis}"], f"fl_{axis}", source, low=0.0, unit=" (pixels)")
    elif keys.get(f"camera_angle_{axis}") is not None:
        angle = number(keys[f"camera_angle_{axis}"], f"camera_angle_{axis}", source, low=0.0, high=math.pi,
                       unit=" (radians)")
        focal = 0.5 * size / math.tan(0.5 * angle) if angle > 0 else 0.0
    else:
        return None
    if not focal > 0.0:
        raise SceneError(f"{source}: frames[{index}] has a zero focal length along {axis}")
    return focal


def _pose(value: Any, field: str, source: Path, shapes: list[tuple[int, ...]]) -> torch.Tensor:
    """[4, 4] OpenCV camera-to-world of an OpenGL matrix in the file; refuses one that is not a rigid pose."""
    c2w = torch.from_numpy(matrix(value, field, source, shapes).astype("float64").reshape(4, 4))
    rot = c2w[:3, :3]
    finite = bool(torch.isfinite(c2w).all())
    rigid = finite and float((rot.T @ rot - torch.eye(3, dtype=torch.float64)).abs().max()) <= RIGID_TOLERANCE \
        and float(torch.det(rot)) > 0 and bool(torch.equal(c2w[3], torch.tensor([0.0, 0.0, 0.0, 1.0],
                                                                                   dtype=torch.float64)))
    if not rigid:
        raise SceneError(f"{source}: {field} is not a rigid camera pose (its rotation is singular, scaled or "
                         "mirrored, a value is not finite, or its last row is not 0 0 0 1)")
    return opengl_to_opencv(c2w[None])[0]
