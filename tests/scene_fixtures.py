"""One known scene, written by the tests in every format that ``load_scene`` reads.

The scene: N cameras on a tilted ring of radius 4 looking at the origin, tiny images (24 x 32) with a colour
pattern per view, and a cloud of points near the origin whose depths give the LLFF-rule bounds. Writers use
the public formats' own conventions (and pycolmap for COLMAP), never our readers.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras, check_shape, intrinsics
from insertnerf_cli.scenes.writers import write_blender_transforms, write_nerfstudio_transforms

HEIGHT, WIDTH, FOCAL = 24, 32, 30.0
RING_RADIUS = 4.0


@dataclass(frozen=True)
class KnownScene:
    """N cameras (OpenCV, float64), P points [P, 3], N uint8 RGB images [H, W, 3], names, LLFF-rule bounds [N]."""

    cameras: Cameras
    points: np.ndarray  # [P, 3]
    images: list[np.ndarray]
    names: list[str]
    near: np.ndarray  # [N]
    far: np.ndarray  # [N]


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """OpenCV c2w [4, 4] at ``center`` whose +z looks at ``target`` and whose -y leans to ``up``."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, y, z], axis=1)
    c2w[:3, 3] = center
    return c2w


def ring_cameras(n: int = 5, radius: float = RING_RADIUS, elevation_deg: float = 25.0,
                 arc_deg: float = 360.0, K: torch.Tensor | None = None) -> Cameras:
    """n cameras on a ring around the z axis looking at the origin (an object-centric capture)."""
    elev = math.radians(elevation_deg)
    poses = []
    for i in range(n):
        az = math.radians(arc_deg * i / (n if arc_deg >= 360.0 else max(n - 1, 1)))
        center = radius * np.array([math.cos(az) * math.cos(elev), math.sin(az) * math.cos(elev), math.sin(elev)])
        poses.append(look_at(center, np.zeros(3)))
    K = intrinsics(FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2) if K is None else K
    return Cameras(K.expand(n, 3, 3).clone(), torch.from_numpy(np.stack(poses)), HEIGHT, WIDTH)


def pattern_image(i: int, height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    """A distinct RGB uint8 pattern per view: gradients plus a bright square whose place depends on i."""
    v, u = np.mgrid[0:height, 0:width]
    img = np.stack([u * 255 // max(width - 1, 1), v * 255 // max(height - 1, 1),
                    np.full_like(u, (37 * i) % 256)], axis=-1).astype(np.uint8)
    r, c = (3 * i) % (height - 4), (5 * i) % (width - 4)
    img[r:r + 4, c:c + 4] = 255
    return img


def llff_bounds(cameras: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LLFF's rule, written independently: 0.1 / 99.9 percentiles of the visible points' depths per view."""
    w2c = np.linalg.inv(cameras.c2w.numpy())
    depths = np.einsum("nij,pj->npi", w2c[:, :3, :3], points)[..., 2] + w2c[:, None, 2, 3]  # [N, P]
    return np.percentile(depths, 0.1, axis=1), np.percentile(depths, 99.9, axis=1)


def known_scene(n: int = 5, seed: int = 0) -> KnownScene:
    cameras = ring_cameras(n)
    points = np.random.default_rng(seed).uniform(-0.8, 0.8, size=(40, 3))
    near, far = llff_bounds(cameras, points)
    return KnownScene(cameras, points, [pattern_image(i) for i in range(n)],
                      [f"view_{i:03d}.png" for i in range(n)], near, far)


def edit_json(path: Path, change: Callable[[dict[str, Any]], Any]) -> None:
    """Rewrite the JSON file ``path`` after ``change`` edited its data in place (json writes NaN and Infinity, as
    some exporters do)."""
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def opencv_to_llff(c2w: torch.Tensor) -> torch.Tensor:
    """Inverse of llff_to_opencv: OpenCV c2w [N, 4, 4] -> LLFF [N, 3, 4] ([down, right, back] + centre)."""
    check_shape("c2w", c2w, (None, 4, 4))
    return torch.stack([c2w[:, :3, 1], c2w[:, :3, 0], -c2w[:, :3, 2], c2w[:, :3, 3]], dim=-1)


def write_images(folder: Path, known: KnownScene, names: list[str] | None = None) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / name for name in (names or known.names)]
    for path, img in zip(paths, known.images):
        assert cv2.imwrite(str(path), img[..., ::-1])  # cv2 writes BGR
    return paths


def write_blender(root: Path, known: KnownScene, test_views: tuple[int, ...] = (1, 3)) -> Path:
    """transforms_train.json + transforms_test.json; file paths without extension, like NeRF-Synthetic."""
    for split in ("train", "test"):
        idx = [i for i in range(len(known.names)) if (i in test_views) == (split == "test")]
        write_images(root / split, known)
        write_blender_transforms(root / f"transforms_{split}.json", known.cameras.subset(idx),
                                 [f"./{split}/{Path(known.names[i]).stem}" for i in idx],
                                 near=known.near[idx], far=known.far[idx])
    return root


def write_nerfstudio(root: Path, known: KnownScene) -> Path:
    write_images(root / "images", known)
    write_nerfstudio_transforms(root / "transforms.json", known.cameras, [f"images/{n}" for n in known.names],
                                near=known.near, far=known.far)
    return root


def write_llff(root: Path, known: KnownScene, factor: int = 1) -> Path:
    """poses_bounds.npy at full size, images in images/ (or images_<factor>/ downscaled)."""
    cams = known.cameras
    root.mkdir(parents=True, exist_ok=True)
    llff = opencv_to_llff(cams.c2w).numpy()  # [N, 3, 4]
    hwf = np.tile([[cams.height], [cams.width], [float(cams.K[0, 0, 0])]], (len(cams), 1, 1))  # [N, 3, 1]
    rows = np.concatenate([llff, hwf], axis=2).reshape(len(cams), 15)
    np.save(root / "poses_bounds.npy", np.concatenate([rows, known.near[:, None], known.far[:, None]], axis=1))
    folder = root / ("images" if factor == 1 else f"images_{factor}")
    paths = write_images(folder, known)
    for p in paths if factor > 1 else []:
        img = cv2.imread(str(p))
        cv2.imwrite(str(p), cv2.resize(img, (cams.width // factor, cams.height // factor),
                                       interpolation=cv2.INTER_AREA))
    return root


def write_colmap(root: Path, known: KnownScene, text: bool = False) -> Path:
    """A PINHOLE COLMAP model written by pycolmap, with every point observed by every camera."""
    import pycolmap

    cams = known.cameras
    K = cams.K[0].numpy()
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="PINHOLE", width=cams.width,
                                                    height=cams.height,
                                                    params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]]))
    uv, _ = cams.project(torch.from_numpy(known.points))  # [N, P, 2]
    w2c = np.linalg.inv(cams.c2w.numpy())
    for i, name in enumerate(known.names):
        image = pycolmap.Image(name=name, keypoints=uv[i].numpy(), camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[i, :3, :4]))
    for j, xyz in enumerate(known.points):
        track = pycolmap.Track()
        for i in range(len(known.names)):
            track.add_element(i + 1, j)
        rec.add_point3D(xyz, track)
    out = root / "sparse" / "0"  # also creates root
    out.mkdir(parents=True, exist_ok=True)
    (rec.write_text if text else rec.write_binary)(str(out))
    write_images(root / "images", known)
    return root


def write_dtu_mvsnet(root: Path, known: KnownScene, k_factor: int = 1) -> Path:
    """Cameras/{v:08d}_cam.txt (K at 1/k_factor size) + Rectified/scan1_train/rect_{v+1:03d}_{light}_r5000.png."""
    cams = known.cameras
    (root / "Cameras").mkdir(parents=True, exist_ok=True)
    w2c = np.linalg.inv(cams.c2w.numpy())
    for i in range(len(cams)):
        K = cams.K[i].numpy().copy()
        K[:2] /= k_factor
        rows = ["extrinsic", *[" ".join(f"{x:.17g}" for x in r) for r in w2c[i]], "",
                "intrinsic", *[" ".join(f"{x:.17g}" for x in r) for r in K], "",
                f"{known.near[i]:.17g} {(known.far[i] - known.near[i]) / 192:.17g}"]
        (root / "Cameras" / f"{i:08d}_cam.txt").write_text("\n".join(rows) + "\n")
    scan = root / "Rectified" / "scan1_train"
    for light in (0, 3):  # two lightings: the reader must pick light 3
        write_images(scan, known, [f"rect_{i + 1:03d}_{light}_r5000.png" for i in range(len(cams))])
    return root


def write_dtu_idr(root: Path, known: KnownScene, scale: float = 2.0) -> Path:
    """cameras.npz with world_mat_i = K [R|t] in a world ``scale`` times larger, undone by scale_mat_i."""
    cams = known.cameras
    root.mkdir(parents=True, exist_ok=True)
    w2c = np.linalg.inv(cams.c2w.numpy())
    scale_mat = np.diag([scale, scale, scale, 1.0])  # normalised -> big world
    arrays = {}
    for i in range(len(cams)):
        P = np.eye(4)
        P[:3, :4] = cams.K[i].numpy() @ w2c[i, :3, :4] @ np.linalg.inv(scale_mat)  # projection of the big world
        arrays[f"world_mat_{i}"], arrays[f"scale_mat_{i}"] = P, scale_mat
    np.savez(root / "cameras.npz", **arrays)
    write_images(root / "image", known, [f"{i:06d}.png" for i in range(len(cams))])
    return root
