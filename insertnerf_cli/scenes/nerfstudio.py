"""nerfstudio / instant-ngp scenes: one ``transforms.json``.

Intrinsics global or per frame; distortion (OPENCV k1 k2 k3 p1 p2, OPENCV_FISHEYE k1..k4) removed when images
load (focal lengths zoomed just enough to leave no blank corner); ``applied_transform`` (the rotation nerfstudio
applied to the COLMAP world) is inverted so poses come back in the original world; without near/far, bounds
come from ``ply_file_path`` points (as ns-process-data writes them), which also become the scene's points (with
the views observing each one when ``colmap_model`` names the COLMAP model of `insertnerf poses`; else those of a
COLMAP model beside the file that fits its cameras); ``train_filenames``/``val_filenames``/``test_filenames``
become splits.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.binfiles import check_colmap_binary
from insertnerf_cli.scenes.colmap_model import aligned_model_points, model_points
from insertnerf_cli.scenes.common import ReadViews, assemble, safe_path
from insertnerf_cli.scenes.geometry import point_depths
from insertnerf_cli.scenes.jsonframes import depth_scale, layout_key, load_json, read_frames
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.scenes.values import FIX, listing, matrix, show, text

FILENAME = "transforms.json"
_SINGULAR = 1e-12  # |det| below this: applied_transform cannot be undone


def _applied_transform(meta: dict[str, Any], source: Path) -> Tensor:
    """nerfstudio's ``applied_transform`` A as [4, 4] (3x4 or 4x4 in the file; new = A @ old), else identity."""
    A = torch.eye(4, dtype=torch.float64)
    if "applied_transform" not in meta:
        return A
    given = matrix(meta["applied_transform"], "applied_transform", source, [(3, 4), (4, 4)])
    A[: given.shape[0], :] = torch.from_numpy(given)
    if abs(float(torch.linalg.det(A))) < _SINGULAR:
        raise SceneError(f"{source}: 'applied_transform' must be an invertible matrix, got {show(given)}; {FIX}")
    return A


def _ply_points(root: Path, meta: dict[str, Any], A_inv: Tensor, source: Path) -> ScenePoints | None:
    """The points in ``ply_file_path`` (ns-process-data's sparse_pc.ply, our sparse.ply), None without one."""
    if "ply_file_path" not in meta:
        return None
    path = safe_path(root, text(meta["ply_file_path"], "ply_file_path", source), "ply_file_path", source)
    try:
        import trimesh

        xyz = torch.as_tensor(np.asarray(trimesh.load(path, process=False).vertices), dtype=torch.float64)
    except Exception as err:  # noqa: BLE001 - trimesh raises many types for a bad or missing file
        raise SceneError(f"cannot read the point cloud {path}: {err}") from None
    if xyz.ndim != 2 or xyz.shape[-1] != 3 or not len(xyz):
        return None
    return ScenePoints(xyz @ A_inv[:3, :3].T + A_inv[:3, 3])  # the points were rotated with the poses


def _tracked_points(root: Path, meta: dict[str, Any], A_inv: Tensor) -> ScenePoints | None:
    """`insertnerf poses` output: the COLMAP model that ``colmap_model`` names, with the views that observe each
    point (every frame's ``colmap_im_id``); None when the file does not say or the model cannot be read."""
    ids = [frame.get("colmap_im_id") for frame in meta["frames"]]
    folder = meta.get("colmap_model")
    if not isinstance(folder, str) or not all(type(i) is int for i in ids):
        return None
    try:
        import pycolmap  # deferred: its import installs glog's signal handlers

        model_dir = safe_path(root, folder, "colmap_model")
        check_colmap_binary(model_dir)
        points = model_points(pycolmap.Reconstruction(str(model_dir)), ids)
    except Exception:  # noqa: BLE001 - optional: without the tracks the .ply's points serve
        return None
    if points is None:
        return None
    return ScenePoints(points.xyz @ A_inv[:3, :3].T + A_inv[:3, 3], points.observed)


def _points(root: Path, meta: dict[str, Any], A_inv: Tensor, source: Path, c2w: Tensor, paths: list[Path],
            required: bool) -> ScenePoints | None:
    """The scene's SfM points: tracked ones from our COLMAP model, else the .ply's, else those of a COLMAP model
    beside the file that fits its cameras. A .ply that cannot be read fails the scene only when the bounds depend
    on it (``required``)."""
    tracked = _tracked_points(root, meta, A_inv)
    if tracked is not None:
        return tracked
    try:
        points = _ply_points(root, meta, A_inv, source)
    except SceneError:
        if required:
            raise
        points = None
    return points if points is not None else aligned_model_points(root, c2w, paths)


def _splits(root: Path, meta: dict[str, Any], paths: list[Path], source: Path) -> dict[str, list[int]]:
    """Splits from nerfstudio's <split>_filenames lists (paths as in the frames)."""
    index = {p: i for i, p in enumerate(paths)}
    splits = {}
    for name in ("train", "val", "test"):
        listed = meta.get(f"{name}_filenames")
        if listed is None:
            continue
        field = f"{name}_filenames"
        wanted = [safe_path(root, text(f, f"{field}[{i}]", source), f"{field}[{i}]", source)
                  for i, f in enumerate(listing(listed, field, source))]
        unknown = [str(p.name) for p in wanted if p not in index]
        if unknown:
            raise SceneError(f"{source}: {name}_filenames lists files that no frame has: {', '.join(unknown[:3])}")
        splits[name] = [index[p] for p in wanted]
    return splits


def read_nerfstudio(root: Path, background: tuple[float, float, float]) -> Scene:
    source = root / FILENAME
    meta = load_json(source)
    frames = read_frames(root, [(source, meta)], default_ext=None)
    A_inv = torch.linalg.inv(_applied_transform(meta, source))
    c2w = A_inv @ frames.c2w
    points = _points(root, meta, A_inv, source, c2w, frames.paths, required=frames.near is None)
    depths = None
    if frames.near is None and points is not None:
        h, w = frames.sizes[0]  # projection needs K and poses; the size only bounds "inside the image"
        depths = point_depths(Cameras(frames.K, c2w, h, w), points.xyz)
    views = ReadViews(root=root, paths=frames.paths, K=frames.K, c2w=c2w, format="nerfstudio",
                      sizes=frames.sizes, near=frames.near, far=frames.far, depths=depths, points=points,
                      splits=_splits(root, meta, frames.paths, source), layout=layout_key(meta, source),
                      depth_paths=frames.depth_paths, depth_scale=depth_scale(meta, frames, source),
                      distortion=frames.distortion, source=source)
    return assemble(views, background)
