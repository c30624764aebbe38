"""How accurate are the poses `insertnerf poses` recovers? Render a textured scene with known cameras, run
``estimate_poses`` on the images alone, align the result to the truth with a similarity, print the errors.

    python3 bench/poses_accuracy.py                    # 30 views, 400x400, the issue's figures
    python3 bench/poses_accuracy.py --views 24 --size 320 --keep /tmp/poses_bench
    python3 bench/poses_accuracy.py --scene synth      # a 360 scene of `insertnerf synth` instead

Scene: a textured room (walls, floor, ceiling) around a box and a sphere; cameras on a horizontal circle
looking at the centre (a 360-degree capture). Colours are a solid 3-D value-noise texture of the hit point, so
no patch repeats (repeated texture is a separate trap, see docs/commands/poses.md). Rendered by ray casting
with trimesh + embree. Targets from the issue: >= 95 % registered, rotation error <= 1 deg, camera-centre
error <= 1 % of the scene radius (the mean distance of the cameras from their centroid). The pose check runs
in warn-only mode so the errors are printed even when it fails.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.cameras.camera import Cameras, intrinsics  # noqa: E402
from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses  # noqa: E402
from insertnerf_cli.scenes.colmap_model import fit_similarity  # noqa: E402

ROOM_HALF = 5.0  # the room spans [-5, 5]^3
# (lattice cells per world unit, weight): a 400 px view at 60 deg shows ~100 px per unit at 3 units, so the
# finest octave makes blobs of a few pixels and the coarsest gives every region its own colour.
TEXTURE_OCTAVES = ((1.5, 0.5), (5.0, 0.3), (15.0, 0.2))
TEXTURE_CONTRAST = 6.0


@dataclass(frozen=True)
class RenderedScene:
    """Ground truth of the bench: N images and their cameras (OpenCV c2w)."""

    images: list[np.ndarray]  # N x [H, W, 3] uint8 RGB
    cameras: Cameras
    radius: float  # camera circle radius, the scene radius the centre error is measured against


def scene_mesh() -> trimesh.Trimesh:
    """Room (inward normals) + a box + a sphere, as one mesh."""
    room = trimesh.creation.box(extents=[2 * ROOM_HALF] * 3)
    room.invert()
    block = trimesh.creation.box(extents=[1.2, 1.6, 1.0])
    block.apply_translation([0.6, 0.2, -0.3])
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.7)
    ball.apply_translation([-0.7, -0.1, 0.5])
    return trimesh.util.concatenate([room, block, ball])


def orbit_cameras(views: int, size: tuple[int, int], radius: float, fov_deg: float,
                  height: Callable[[float], float], arc_deg: float = 360.0) -> Cameras:
    """``views`` cameras on a circle (world z up) at ``height(angle)``, looking at the origin, OpenCV c2w.

    ``size`` is (height, width) in pixels; ``fov_deg`` the horizontal field of view; the cameras are spread
    evenly over ``arc_deg`` degrees of the circle (a full turn leaves no gap between the last and the first).
    """
    rows, cols = size
    f = 0.5 * cols / math.tan(math.radians(fov_deg) / 2)
    c2w = torch.zeros(views, 4, 4, dtype=torch.float64)
    step = math.radians(arc_deg) / (views if arc_deg >= 360.0 else max(views - 1, 1))
    for i in range(views):
        a = step * i
        centre = torch.tensor([radius * math.cos(a), radius * math.sin(a), height(a)], dtype=torch.float64)
        forward = -centre / centre.norm()
        right = torch.linalg.cross(forward, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
        right = right / right.norm()
        down = torch.linalg.cross(forward, right)
        c2w[i, :3, :3] = torch.stack([right, down, forward], dim=1)
        c2w[i, :3, 3] = centre
        c2w[i, 3, 3] = 1.0
    K = intrinsics(f, f, cols / 2, rows / 2).expand(views, 3, 3).clone()
    return Cameras(K, c2w, rows, cols)


def _hash_noise(cells: np.ndarray, seed: int) -> np.ndarray:
    """Pseudo-random values in [0, 1) [P] at integer lattice points [P, 3], stateless (no lattice in memory)."""
    h = cells.astype(np.int64) @ np.array([73856093, 19349663, 83492791], dtype=np.int64) + seed * 2654435761
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(np.float64) / 65536.0


def value_noise(points: np.ndarray, frequency: float, seed: int) -> np.ndarray:
    """Trilinear value noise [P] of world points [P, 3] with ``frequency`` lattice cells per world unit."""
    x = points * frequency
    base = np.floor(x)
    frac = x - base
    out = np.zeros(len(points))
    for corner in np.ndindex(2, 2, 2):
        offset = np.array(corner)
        weight = np.prod(np.where(offset == 1, frac, 1.0 - frac), axis=1)
        out += weight * _hash_noise(base + offset, seed)
    return out


def solid_texture(points: np.ndarray, seed: int) -> np.ndarray:
    """RGB in [0, 1] [P, 3] of world points [P, 3]: three octaves of value noise per channel, contrast
    sharpened so blobs have crisp edges (SIFT finds blob corners, not smooth gradients)."""
    rgb = np.zeros_like(points)
    for c in range(3):
        for frequency, weight in TEXTURE_OCTAVES:
            rgb[:, c] += weight * value_noise(points, frequency, seed + 17 * c)
    return 0.5 + 0.5 * np.tanh(TEXTURE_CONTRAST * (rgb - 0.5))


Colouring = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (hits [P, 3], triangle ids [P]) -> RGB [P, 3]


def render(mesh: trimesh.Trimesh, cameras: Cameras, colouring: Colouring,
           background: float = 0.8) -> list[np.ndarray]:
    """Ray-cast every camera: ``colouring`` of the hit times a Lambert term from a fixed light direction."""
    intersector = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    light = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    uv = cameras.pixel_grid().reshape(1, -1, 2)  # [1, H*W, 2]
    images = []
    for i in range(len(cameras)):
        cam = cameras.subset([i])
        dirs = cam.ray_directions(uv)[0].numpy()  # [H*W, 3]
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origins = np.broadcast_to(cam.centers[0].numpy(), dirs.shape)
        tri, ray, hits = intersector.intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
        colour = np.full((dirs.shape[0], 3), background)
        shade = 0.55 + 0.45 * np.abs(mesh.face_normals[tri] @ light)
        colour[ray] = colouring(hits, tri) * shade[:, None]
        images.append((colour.reshape(cameras.height, cameras.width, 3) * 255).round().astype(np.uint8))
    return images


def render_scene(views: int, size: int, seed: int = 0, arc_deg: float = 360.0) -> RenderedScene:
    radius = 3.0
    cameras = orbit_cameras(views, (size, size), radius, fov_deg=60.0, height=lambda a: 0.6 + 0.3 * math.sin(3 * a),
                            arc_deg=arc_deg)
    # The same seed for every view: the texture is a property of the world, not of the image.
    images = render(scene_mesh(), cameras, lambda hits, _: solid_texture(hits, seed))
    return RenderedScene(images, cameras, radius)


def pose_errors(truth: Cameras, est: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera rotation error (deg) and centre error (world units) after aligning ``est`` onto ``truth``."""
    rotation, translation, s, _ = fit_similarity(est.centers.double(), truth.centers.double())
    rot, t = rotation.numpy(), translation.numpy()
    centres = s * est.centers.numpy() @ rot.T + t
    r_est = rot @ est.c2w[:, :3, :3].numpy()  # [N, 3, 3] camera axes in the true world
    rel = np.einsum("nji,njk->nik", truth.c2w[:, :3, :3].numpy(), r_est)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    return np.degrees(np.arccos(cos)), np.linalg.norm(centres - truth.centers.numpy(), axis=1)


@dataclass(frozen=True)
class Truth:
    """Images on disk and the cameras they were rendered with."""

    images_dir: Path
    names: list[str]  # file names, in camera order
    cameras: Cameras
    radius: float  # mean distance of the camera centres from their centroid


def _mean_radius(cameras: Cameras) -> float:
    centres = cameras.centers.numpy()
    return float(np.linalg.norm(centres - centres.mean(0), axis=1).mean())


def room_truth(root: Path, views: int, size: int) -> Truth:
    scene = render_scene(views, size)
    images_dir = root / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    names = [f"view_{i:03d}.png" for i in range(views)]
    for name, img in zip(names, scene.images):
        cv2.imwrite(str(images_dir / name), img[..., ::-1])
    return Truth(images_dir, names, scene.cameras, _mean_radius(scene.cameras))


def synth_truth(root: Path, views: int, size: int, seed: int) -> Truth:
    """A 360-layout scene of `insertnerf synth` (its textures tile: a repeated-texture case for SfM)."""
    from insertnerf_cli.scenes import load_scene
    from insertnerf_cli.synth import CaptureOptions, SceneSpec
    from insertnerf_cli.synth.dataset import render_into

    spec = SceneSpec(index=0, seed=seed, layout="360", views=views, test_views=0, resolution=size,
                     aspects=(1.0,), capture=CaptureOptions())
    render_into(root, spec)
    scene = load_scene(root / spec.name)
    return Truth(scene.image_paths[0].parent, [p.name for p in scene.image_paths], scene.cameras,
                 _mean_radius(scene.cameras))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="room", choices=["room", "synth"])
    parser.add_argument("--views", type=int, default=30)
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0, help="synth scene seed")
    parser.add_argument("--matcher", default="auto", choices=["auto", "exhaustive", "sequential"])
    parser.add_argument("--keep", type=Path, help="write images and the scene here instead of a temp folder")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        t0 = time.perf_counter()
        truth = (room_truth(root, args.views, args.size) if args.scene == "room"
                 else synth_truth(root, args.views, args.size, args.seed))
        print(f"rendered {args.views} views at {args.size}x{args.size} in {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        options = PosesOptions(matcher=args.matcher, overwrite=True, allow_inconsistent=True)
        result = estimate_poses(truth.images_dir, root / "scene", options)
        wall = time.perf_counter() - t0
    _print_figures(truth, result, wall)


def _print_figures(truth: Truth, result, wall: float) -> None:
    rot_err, centre_err = pose_errors(truth.cameras.subset([truth.names.index(n) for n in result.registered]),
                                      result.cameras)
    centre_pct = 100 * centre_err / truth.radius
    print(f"registered        {len(result.registered)}/{len(truth.names)} "
          f"({100 * len(result.registered) / len(truth.names):.1f} %)")
    print(f"reprojection      {result.mean_reprojection_error:.3f} px mean")
    print(f"rotation error    median {np.median(rot_err):.3f} deg, max {rot_err.max():.3f} deg")
    print(f"centre error      median {np.median(centre_pct):.3f} %, max {centre_pct.max():.3f} % "
          f"of the scene radius ({truth.radius:.2f})")
    print(f"pose check        {'passed' if result.check.passed else 'FAILED'}: {result.check.summary()}")
    print(f"wall time         {wall:.1f} s for estimate_poses "
          f"({', '.join(f'{s.name} {s.seconds:.1f} s' for s in result.stages)})")


if __name__ == "__main__":
    main()
