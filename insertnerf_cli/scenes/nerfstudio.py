"""nerfstudio / instant-ngp scenes: one ``transforms.json``.

Intrinsics global or per frame; distortion (OPENCV k1 k2 k3 p1 p2, OPENCV_FISHEYE k1..k4) removed when images
load, K unchanged; ``applied_transform`` (the rotation nerfstudio applied to the COLMAP world) is inverted so
poses come back in the original world; ``train_filenames``/``val_filenames``/``test_filenames`` become splits.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from .base import Scene, SceneError
from .common import ReadViews, assemble, safe_path
from .jsonframes import depth_scale, layout_key, load_json, read_frames

FILENAME = "transforms.json"


def _undo_applied_transform(c2w: Tensor, meta: dict[str, Any], source: Path) -> Tensor:
    """c2w [N, 4, 4] in the world before ``applied_transform`` (3x4 or 4x4, new = A @ old)."""
    if "applied_transform" not in meta:
        return c2w
    A = torch.eye(4, dtype=torch.float64)
    try:
        given = torch.tensor(meta["applied_transform"], dtype=torch.float64)
        A[: given.shape[0], :] = given
        inverse = torch.linalg.inv(A)
    except (TypeError, ValueError, RuntimeError):
        raise SceneError(f"{source}: 'applied_transform' must be a 3x4 or 4x4 invertible matrix") from None
    return inverse @ c2w


def _splits(root: Path, meta: dict[str, Any], paths: list[Path], source: Path) -> dict[str, list[int]]:
    """Splits from nerfstudio's <split>_filenames lists (paths as in the frames)."""
    index = {p: i for i, p in enumerate(paths)}
    splits = {}
    for name in ("train", "val", "test"):
        listed = meta.get(f"{name}_filenames")
        if listed is None:
            continue
        wanted = [safe_path(root, f, f"{name}_filenames entry") for f in listed]
        unknown = [str(p.name) for p in wanted if p not in index]
        if unknown:
            raise SceneError(f"{source}: {name}_filenames lists files that no frame has: {', '.join(unknown[:3])}")
        splits[name] = [index[p] for p in wanted]
    return splits


def read_nerfstudio(root: Path, background: tuple[float, float, float]) -> Scene:
    source = root / FILENAME
    meta = load_json(source)
    frames = read_frames(root, [(source, meta)], default_ext=None)
    views = ReadViews(root=root, paths=frames.paths, K=frames.K,
                      c2w=_undo_applied_transform(frames.c2w, meta, source), format="nerfstudio",
                      sizes=frames.sizes, near=frames.near, far=frames.far,
                      splits=_splits(root, meta, frames.paths, source), layout=layout_key(meta, source),
                      depth_paths=frames.depth_paths, depth_scale=depth_scale(meta, frames), distortion=frames.distortion)
    return assemble(views, background)
