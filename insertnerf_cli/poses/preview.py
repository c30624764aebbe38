"""Previews of a posed scene for any mesh viewer (MeshLab, Blender, CloudCompare): the sparse points as a
coloured point cloud, and the cameras as frustum pyramids with a tab on their "up" side, coloured from blue
(first camera) to red (last) so the capture order and orientation can be read at a glance."""
from __future__ import annotations

import os

import numpy as np
import torch
import trimesh

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.files.atomic import write_bytes

# Frustum faces as vertex indices per camera: 0 = centre, 1..4 = image corners (top-left, top-right,
# bottom-right, bottom-left), 5 = tip of the "up" tab above the top edge.
_FRUSTUM_FACES = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [1, 5, 2]], dtype=np.int64)
_VERTICES_PER_CAMERA = 6
# The up tab rises this fraction of the image height above the top edge.
_TAB_HEIGHT = 0.35
# Frustums are this fraction of the median distance between neighbouring cameras deep, so they do not overlap.
_DEPTH_OF_SPACING = 0.6


def write_point_cloud(path: str | os.PathLike, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Write points xyz [P, 3] with uint8 colours rgb [P, 3] as a binary PLY, atomically."""
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValueError(f"xyz and rgb must both be [P, 3], got {xyz.shape} and {rgb.shape}")
    alpha = np.full((len(rgb), 1), 255, dtype=np.uint8)
    cloud = trimesh.PointCloud(vertices=xyz, colors=np.hstack([rgb.astype(np.uint8), alpha]))
    write_bytes(path, cloud.export(file_type="ply"))


def default_frustum_depth(cameras: Cameras) -> float:
    """A frustum depth from the camera spacing: a fraction of the median nearest-neighbour distance."""
    centres = cameras.centers.detach().to("cpu", torch.float64)  # [N, 3]
    if len(centres) < 2:
        return 1.0
    dist = torch.cdist(centres, centres)
    dist.fill_diagonal_(float("inf"))
    spacing = float(dist.min(dim=1).values.median())
    return _DEPTH_OF_SPACING * spacing if spacing > 0 else 1.0


def frustum_mesh(cameras: Cameras, depth: float | None = None) -> trimesh.Trimesh:
    """One pyramid per camera (apex at the centre, base = the image rectangle at z = ``depth``) plus an up tab.

    Args:
        cameras: N cameras (OpenCV c2w).
        depth: base distance along each optical axis, world units (None: from the camera spacing).
    """
    depth = default_frustum_depth(cameras) if depth is None else depth
    n, h, w = len(cameras), float(cameras.height), float(cameras.width)
    corners = torch.tensor([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [w / 2, -_TAB_HEIGHT * h]],
                           dtype=torch.float64)
    cams = cameras.to(dtype=torch.float64, device="cpu")
    uv = corners.expand(n, -1, -1)  # [N, 5, 2]
    base = cams.unproject(uv, torch.full((n, len(corners)), depth, dtype=torch.float64))  # [N, 5, 3]
    vertices = torch.cat([cams.centers[:, None], base], dim=1).reshape(-1, 3).numpy()  # [N*6, 3]
    offsets = (np.arange(n) * _VERTICES_PER_CAMERA)[:, None, None]
    faces = (_FRUSTUM_FACES[None] + offsets).reshape(-1, 3)  # [N*5, 3]
    t = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
    colour = np.stack([255 * t, 64 * np.ones_like(t), 255 * (1 - t), 255 * np.ones_like(t)], axis=1)
    face_colors = np.repeat(colour.astype(np.uint8), len(_FRUSTUM_FACES), axis=0)  # [N*5, 4]
    return trimesh.Trimesh(vertices=vertices, faces=faces, face_colors=face_colors, process=False)


def write_camera_frustums(path: str | os.PathLike, cameras: Cameras, depth: float | None = None) -> None:
    """Write :func:`frustum_mesh` as a binary PLY, atomically."""
    write_bytes(path, frustum_mesh(cameras, depth).export(file_type="ply"))
