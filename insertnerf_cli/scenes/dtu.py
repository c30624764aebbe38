"""DTU scenes, in their two common packagings.

MVSNet (MVSNeRF, GeoNeRF): ``Cameras/{v:08d}_cam.txt`` (``extrinsic`` 4x4 world-to-camera, ``intrinsic`` 3x3,
then ``depth_min depth_interval [depth_num depth_max]``) with ``Rectified/[scanN_train/]rect_{v+1:03d}_{light}
_r5000.png``; light 3 is used when there are several. The cam files' K may be for another resolution (the
training set's ``Cameras/train/`` is at 1/4): the power-of-two scale that puts the principal point near the
image centre is applied, and ``Cameras/`` then ``Cameras/train/`` are tried.

IDR/DVR (pixelNeRF, NeuS): ``cameras.npz`` (or ``cameras_sphere.npz``) with ``world_mat_i`` = K[R|t] and
optional ``scale_mat_i`` with ``image/*.png``. P = world_mat @ scale_mat (the object in the unit sphere) is
split with cv2.decomposeProjectionMatrix; near/far bound the unit sphere.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np
import torch

from insertnerf_cli.cameras.camera import w2c_to_c2w
from insertnerf_cli.errors import SceneError, os_error_message
from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.binfiles import load_npz
from insertnerf_cli.scenes.common import ReadViews, assemble, safe_path
from insertnerf_cli.scenes.images import find_images, image_size
from insertnerf_cli.scenes.values import matrix, number

CAMERA_DIRS = ("Cameras", "Cameras/train")
NPZ_NAMES = ("cameras.npz", "cameras_sphere.npz")
PREFERRED_LIGHTS = ("3", "max")  # MVSNeRF/pixelNeRF habit: the brightest uniform lighting
MVSNET_PLANES = 192  # far = depth_min + interval * 192 when the file gives no depth_max
# A cam file's K fits an image when its principal point lies within this fraction of the image centre.
_CENTRE_TOLERANCE = 0.1
_RECT_NAME = re.compile(r"rect_(\d+)_(\w+?)(?:_r5000)?\.\w+$", re.IGNORECASE)


def is_mvsnet(root: Path) -> bool:
    return (root / "Cameras").is_dir() and (root / "Rectified").is_dir()


def npz_file(root: Path) -> Path | None:
    return next((root / n for n in NPZ_NAMES if (root / n).is_file()), None)


def _parse_cam(path: Path) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """w2c [4, 4], K [3, 3] and (near, far) from one MVSNet cam file."""
    try:
        words = path.read_text().split()
        ext, intr = words.index("extrinsic"), words.index("intrinsic")
        w2c = np.array(words[ext + 1: ext + 17], dtype=np.float64).reshape(4, 4)
        K = np.array(words[intr + 1: intr + 10], dtype=np.float64).reshape(3, 3)
        depth = [float(x) for x in words[intr + 10:]]
    except OSError as err:
        raise SceneError(os_error_message(err)) from None
    except ValueError as err:
        raise SceneError(f"cannot read DTU camera file {path}: {err}") from None
    if len(depth) < 2:  # a file cut short keeps depth_min alone
        raise SceneError(f"{path}: no 'depth_min depth_interval' line after the intrinsics (cut short?)")
    matrix(w2c, "extrinsic", path, [(4, 4)])
    number(K[0, 2], "intrinsic cx", path, low=0.0)  # _fit_K divides by it
    matrix(K, "intrinsic", path, [(3, 3)])
    far = depth[3] if len(depth) >= 4 else depth[0] + depth[1] * MVSNET_PLANES
    return w2c, K, (depth[0], far)


def _fit_K(K: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """K scaled by the power of two that centres its principal point in an image of ``size``; None if none."""
    h, w = size
    scale = 2.0 ** round(math.log2(w / (2.0 * K[0, 2])))
    fitted = K.copy()
    fitted[:2] *= scale
    ok = abs(2 * fitted[0, 2] - w) <= _CENTRE_TOLERANCE * w and abs(2 * fitted[1, 2] - h) <= _CENTRE_TOLERANCE * h
    return fitted if ok else None


def _mvsnet_images(root: Path, images: str) -> list[tuple[int, Path]]:
    """(view index, image path) pairs, one image per view (the preferred light)."""
    folder = safe_path(root, images, "images folder")
    if not folder.is_dir():
        folder = root / "Rectified"
        scans = sorted(p for p in folder.iterdir() if p.is_dir())
        if not find_images(folder) and len(scans) == 1:
            folder = scans[0]
        elif not find_images(folder):
            raise SceneError(f"{root}: Rectified/ holds {len(scans)} scans; pick one with the images option, "
                             f"e.g. images='Rectified/{scans[0].name if scans else 'scan1_train'}'")
    by_view: dict[int, dict[str, Path]] = {}
    paths = find_images(folder)
    for p in paths:
        m = _RECT_NAME.match(p.name)
        if m:
            by_view.setdefault(int(m.group(1)) - 1, {})[m.group(2)] = p
    if not by_view:  # not DTU names: pair the sorted images with the sorted cam files
        return list(enumerate(paths))
    pick = lambda lights: next((lights[k] for k in PREFERRED_LIGHTS if k in lights), lights[min(lights)])  # noqa
    return [(v, pick(by_view[v])) for v in sorted(by_view)]


def read_mvsnet(root: Path, images: str, background: tuple[float, float, float]) -> Scene:
    pairs = _mvsnet_images(root, images)
    size = image_size(pairs[0][1])
    for sub in CAMERA_DIRS:
        files = [root / sub / f"{v:08d}_cam.txt" for v, _ in pairs]
        if not all(f.is_file() for f in files):
            continue
        cams = [_parse_cam(f) for f in files]
        Ks = [_fit_K(K, size) for _, K, _ in cams]
        if all(K is not None for K in Ks):
            break
    else:
        raise SceneError(f"{root}: no camera folder of {', '.join(CAMERA_DIRS)} has a cam file for every image "
                         f"whose intrinsics fit {size[1]}x{size[0]} images")
    w2c = torch.from_numpy(np.stack([c[0] for c in cams]))  # [N, 4, 4]
    bounds = torch.tensor([c[2] for c in cams], dtype=torch.float64)
    views = ReadViews(root=root, paths=[p for _, p in pairs], K=torch.from_numpy(np.stack(Ks)),
                      c2w=w2c_to_c2w(w2c), format="dtu", near=bounds[:, 0], far=bounds[:, 1], source=root / sub)
    return assemble(views, background)


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K [3, 3] (positive focal lengths, K[2, 2] = 1) and OpenCV c2w [4, 4] from a projection P [3, 4]."""
    K, R, center = cv2.decomposeProjectionMatrix(P[:3, :4])[:3]  # a degenerate P gives NaN, refused later
    K = K / K[2, 2]
    signs = np.diag(np.sign(np.diag(K)))  # RQ is unique up to these signs; make the focal lengths positive
    K, R = K @ signs, signs @ R
    if np.linalg.det(R) < 0:
        R = -R  # P is homogeneous: -P is the same camera
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = center[:3, 0] / center[3, 0]
    return K, c2w


def read_idr(root: Path, images: str, background: tuple[float, float, float]) -> Scene:
    source = npz_file(root)
    folder = safe_path(root, images, "images folder")
    folder = folder if folder.is_dir() else root / "image"
    paths = find_images(folder) if folder.is_dir() else []
    data = load_npz(source)  # each entry's declared shape checked against its bytes before allocating
    if not paths or any(f"world_mat_{i}" not in data for i in range(len(paths))):
        raise SceneError(f"{source}: needs world_mat_0..world_mat_{len(paths) - 1} for the {len(paths)} images "
                         f"in {folder.name}/")
    has_scale = all(f"scale_mat_{i}" in data for i in range(len(paths)))
    mats = [matrix(data[f"world_mat_{i}"], f"world_mat_{i}", source, [(3, 4), (4, 4)]) for i in range(len(paths))]
    if has_scale:
        mats = [P[:3] @ matrix(data[f"scale_mat_{i}"], f"scale_mat_{i}", source, [(4, 4)])
                for i, P in enumerate(mats)]
    with np.errstate(divide="ignore", invalid="ignore"):
        Ks, poses = zip(*(decompose_projection(P) for P in mats))
    c2w = torch.from_numpy(np.stack(poses))
    near = far = None
    if has_scale:  # the object lies in the unit sphere: bound it along each camera's distance to the origin
        dist = c2w[:, :3, 3].norm(dim=-1)
        near, far = (dist - 1.0).clamp(min=0.05 * dist), dist + 1.0
    views = ReadViews(root=root, paths=paths, K=torch.from_numpy(np.stack(Ks)), c2w=c2w, format="dtu",
                      near=near, far=far, layout="object" if has_scale else None, source=source)
    return assemble(views, background)
