"""`render --pointcloud`: every frame's valid depth (opacity >= 0.5) lifted to coloured 3-D points in the scene's
own units and axes (like `poses`'s sparse.ply), fused into one PLY that MeshLab, CloudCompare and Blender open."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.exporters.outputs import FramePaths, read_depth
from insertnerf_cli.files.atomic import write_bytes

# About a million points open at once in every viewer and keep the file near 15 MB.
DEFAULT_POINTS = 1_000_000
_SEED = 0  # the subsample is the same on every run


def frame_points(camera: Cameras, depth: np.ndarray, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points [P, 3] float64, colours [P, 3] uint8) of one frame's valid pixels.

    Args:
        camera: the frame's camera (1) at the depth map's size, in the scene's units.
        depth: [H, W] camera z in the same units, NaN = invalid; rgb: [H, W, 3] uint8.
    """
    if len(camera) != 1 or depth.shape != (camera.height, camera.width) or rgb.shape[:2] != depth.shape:
        raise ValueError(f"one camera of {camera.height}x{camera.width} and depth/colour maps of that size expected, "
                         f"got {len(camera)} cameras, depth {depth.shape}, colours {rgb.shape}")
    valid = np.isfinite(depth)
    uv = camera.pixel_grid().to(torch.float64)[torch.from_numpy(valid)]  # [P, 2]
    z = torch.from_numpy(depth[valid]).to(torch.float64)  # [P]
    points = camera.to(dtype=torch.float64).unproject(uv[None], z[None])[0]
    return points.numpy(), rgb[valid][:, :3]


def fuse_frames(cameras: Cameras, files: Sequence[FramePaths], depth_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The points and colours of every frame whose files are on disk (``cameras`` [F] match ``files`` [F])."""
    import imageio.v3 as iio

    points, colours = [], []
    for i, paths in enumerate(files):
        p, c = frame_points(cameras.subset([i]), read_depth(paths.depth, depth_scale), iio.imread(paths.frame))
        points.append(p.astype(np.float32))
        colours.append(c)
    return np.concatenate(points), np.concatenate(colours)


def subsample(points: np.ndarray, colours: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``limit`` points, drawn uniformly without replacement (the same draw on every run)."""
    if len(points) <= limit:
        return points, colours
    keep = np.sort(np.random.default_rng(_SEED).choice(len(points), size=limit, replace=False))
    return points[keep], colours[keep]


def write_pointcloud(path: Path, cameras: Cameras, files: Sequence[FramePaths], depth_scale: float,
                     limit: int = DEFAULT_POINTS) -> int:
    """Fuse the frames into a binary PLY with per-vertex RGBA colours at ``path`` (atomically); returns the
    number of points written."""
    import trimesh

    points, colours = subsample(*fuse_frames(cameras, files, depth_scale), limit)
    if not len(points):  # no valid depth anywhere: trimesh cannot export an empty cloud, the header says it all
        write_bytes(path, _EMPTY_PLY)
        return 0
    alpha = np.full((len(colours), 1), 255, dtype=np.uint8)
    cloud = trimesh.PointCloud(points, colors=np.concatenate([colours, alpha], axis=1))
    write_bytes(path, cloud.export(file_type="ply"))
    return len(points)


_EMPTY_PLY = ("ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              "property uchar alpha\nend_header\n").encode("ascii")
