"""Triangulated SfM points kept between runs: `render` and `eval --out` write the points they triangulate, with
each view's observations, into OUT/points/ (or the folder --points-cache names), keyed by the photos (names, sizes,
modification times), the poses and intrinsics the points were triangulated at, the views that could observe them
and the triangulation's options. A later run of the same scene (another resolution, path or view count) loads them
instead of triangulating again.

One ``.npz`` per key (numbers only, read with ``allow_pickle=False``): ``xyz`` [P, 3] float64, ``views`` [V] int64
(the scene's view count, so a file cannot be applied to another scene), ``observed`` [O] int64 (every view's point
indices, concatenated) and ``offsets`` [V + 1] int64 (where each view's indices start).
"""
from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from insertnerf_cli.files.atomic import write_bytes
from insertnerf_cli.files.outdir import check_output
from insertnerf_cli.scenes import Scene
from insertnerf_cli.scenes.points import ScenePoints

# Bump when triangulation changes what the same photos, poses and options give.
CACHE_VERSION = 1


def check_cache_folder(folder: Path, scene_dir: Path) -> None:
    """Refuse, before any work, a --points-cache folder that lies inside (or holds) the scene, is a file or cannot
    be written: the cache is written by every run that uses it."""
    check_output(folder, [scene_dir], what="--points-cache", kind="input scene")


def cache_key(scene: Scene, views: Sequence[int], options: object) -> str:
    """A hex key of everything the triangulated points depend on: the photos (as files), the cameras (float64
    bytes of K and c2w, in the world the points will be in), the views that may observe points, the options."""
    digest = hashlib.sha256()
    photos = []
    for path in scene.image_paths:
        stat = Path(path).stat()
        photos.append([Path(path).name, stat.st_size, stat.st_mtime_ns])
    digest.update(json.dumps({"version": CACHE_VERSION, "photos": photos, "views": sorted(set(views)),
                              "size": [scene.cameras.height, scene.cameras.width], "options": repr(options)},
                             sort_keys=True).encode())
    for tensor in (scene.cameras.K, scene.cameras.c2w):
        digest.update(tensor.detach().to("cpu", torch.float64).contiguous().numpy().tobytes())
    return digest.hexdigest()[:24]


def cache_file(folder: Path, key: str) -> Path:
    return Path(folder) / f"{key}.npz"


def load_points(path: Path, views: int) -> ScenePoints | None:
    """The points stored at ``path`` for a scene of ``views`` views, or None where there is no such file or it is
    unreadable or for another view count (then the caller triangulates again and replaces it)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            xyz, offsets, observed = data["xyz"], data["offsets"], data["observed"]
            count = int(data["views"])
    except (OSError, KeyError, ValueError):
        return None
    if count != views or xyz.ndim != 2 or xyz.shape[1] != 3 or offsets.shape != (views + 1,) \
            or offsets[0] != 0 or offsets[-1] != len(observed) or (np.diff(offsets) < 0).any() \
            or (len(observed) and (observed.min() < 0 or observed.max() >= len(xyz))):
        return None
    per_view = tuple(torch.from_numpy(observed[offsets[i]:offsets[i + 1]].astype(np.int64)) for i in range(views))
    return ScenePoints(torch.from_numpy(xyz.astype(np.float64)), per_view)


def save_points(path: Path, points: ScenePoints, views: int) -> None:
    """Write ``points`` (with observations for each of ``views`` views) to ``path`` atomically."""
    observed = points.observed if points.observed is not None else tuple(torch.zeros(0, dtype=torch.int64)
                                                                         for _ in range(views))
    lengths = [len(o) for o in observed]
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    flat = torch.cat([o.to(torch.int64) for o in observed]).numpy() if lengths else np.zeros(0, np.int64)
    buffer = io.BytesIO()
    np.savez(buffer, xyz=points.xyz.detach().to("cpu", torch.float64).numpy(), views=np.int64(views),
             offsets=offsets, observed=flat)
    write_bytes(path, buffer.getvalue())
