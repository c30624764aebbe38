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
from insertnerf_cli.scenes.jsonframes import FrameKeys, frame_intrinsics, frame_pose
from insertnerf_cli.scenes.values import matrix, number, objects, whole

# A rotation whose columns are further than this from orthonormal, or with a determinant below 0, is no camera.
RIGID_TOLERANCE = 1e-4
# The largest frame side a path file may ask for (frames are rendered at it, or scaled down to --resolution).
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
        field = f"camera_path[{i}].camera_to_world"
        c2w_gl = torch.from_numpy(matrix(frame["camera_to_world"], field, source, [(16,), (4, 4)]).reshape(4, 4))
        poses.append(_rigid(opengl_to_opencv(c2w_gl), field, source))
    fps = number(data["fps"], "fps", source, low=0.0) if data.get("fps") is not None else None
    if fps is not None and fps <= 0:
        raise SceneError(f"{source}: fps must be positive, got {fps:g}")
    return Cameras(torch.stack(Ks), torch.stack(poses), height, width), fps


def _transforms(data: dict[str, Any], source: Path) -> tuple[Cameras, float | None]:
    """The frames of a transforms file, read as the scene readers read theirs (no image needs to exist)."""
    frames = objects(data["frames"], "frames", source)
    if not frames:
        raise SceneError(f"{source}: 'frames' holds no camera")
    Ks, poses, sizes = [], [], set()
    for i, frame in enumerate(frames):
        if "transform_matrix" not in frame:
            raise SceneError(f"{source}: frames[{i}] has no 'transform_matrix'")
        keys = FrameKeys(frame, data, i, source)
        K, size = frame_intrinsics(keys, None)
        _check_size(*size, source)
        Ks.append(K)
        sizes.add(size)
        poses.append(_rigid(frame_pose(keys), f"frames[{i}].transform_matrix", source))
    if len(sizes) > 1:
        raise SceneError(f"{source}: the frames give {len(sizes)} image sizes; a path renders one size")
    (height, width), = sizes
    return Cameras(torch.stack(Ks), torch.stack(poses), height, width), None


def _size(keys: dict[str, Any], h_key: str, w_key: str, source: Path) -> tuple[int, int]:
    for key in (h_key, w_key):
        if key not in keys:
            raise SceneError(f"{source}: no '{key}' (the image size of the path's frames)")
    height, width = whole(keys[h_key], h_key, source), whole(keys[w_key], w_key, source)
    _check_size(height, width, source)
    return height, width


def _check_size(height: int, width: int, source: Path) -> None:
    if not (height <= MAX_SIDE and width <= MAX_SIDE):
        raise SceneError(f"{source}: an image of {width}x{height} px; width and height may be at most "
                         f"{MAX_SIDE}")


def _rigid(c2w: torch.Tensor, field: str, source: Path) -> torch.Tensor:
    """``c2w`` [4, 4] itself; refused where it is not a rigid camera pose."""
    rot = c2w[:3, :3]
    finite = bool(torch.isfinite(c2w).all())
    rigid = finite and float((rot.T @ rot - torch.eye(3, dtype=torch.float64)).abs().max()) <= RIGID_TOLERANCE \
        and float(torch.det(rot)) > 0 and bool(torch.equal(c2w[3], torch.tensor([0.0, 0.0, 0.0, 1.0],
                                                                                   dtype=torch.float64)))
    if not rigid:
        raise SceneError(f"{source}: {field} is not a rigid camera pose (its rotation is singular, scaled or "
                         "mirrored, a value is not finite, or its last row is not 0 0 0 1)")
    return c2w
