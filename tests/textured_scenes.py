"""Textured scenes with known cameras, ray cast with trimesh + embree, for the pose tests and the pose benches.

A textured room (walls, floor, ceiling) around a box and a sphere, seen by cameras on a horizontal circle looking
at the centre (a 360-degree capture); and beer's failure made exact (bench/poses_fold.py): a box whose opposite
sides carry the same texture on a floor whose texture is the same after a half turn, inside uniquely textured
walls. Colours are a solid 3-D value-noise texture of the hit point, so no patch repeats unless a colouring makes
it. bench/poses_accuracy.py, bench/poses_fold.py and bench/poses_trap.py import this module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import torch
import trimesh

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.scenes.colmap_model import fit_similarity
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms

ROOM_HALF = 5.0  # the room spans [-5, 5]^3
# (lattice cells per world unit, weight): a 400 px view at 60 deg shows ~100 px per unit at 3 units, so the
# finest octave makes blobs of a few pixels and the coarsest gives every region its own colour.
TEXTURE_OCTAVES = ((1.5, 0.5), (5.0, 0.3), (15.0, 0.2))
TEXTURE_CONTRAST = 6.0
# The fold scene: room half-width and height, box extents (world units).
FOLD_ROOM_HALF, FOLD_ROOM_HEIGHT, FOLD_BOX = 8.0, 6.0, (1.2, 0.8, 1.6)


@dataclass(frozen=True)
class RenderedScene:
    """Ground truth of the room: N images and their cameras (OpenCV c2w)."""

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
    """The room seen by ``views`` cameras of ``size`` x ``size`` pixels on a circle of radius 3."""
    radius = 3.0
    cameras = orbit_cameras(views, (size, size), radius, fov_deg=60.0, height=lambda a: 0.6 + 0.3 * math.sin(3 * a),
                            arc_deg=arc_deg)
    # The same seed for every view: the texture is a property of the world, not of the image.
    images = render(scene_mesh(), cameras, lambda hits, _: solid_texture(hits, seed))
    return RenderedScene(images, cameras, radius)


def write_posed_room(root: Path, views: int, size: int, arc_deg: float = 70.0) -> RenderedScene:
    """The room's photos in ``root``/images and a nerfstudio transforms.json of their true poses (bounds 0.5 to 8,
    no points): a posed scene to triangulate. Returns what was rendered."""
    truth = render_scene(views=views, size=size, arc_deg=arc_deg)
    (root / "images").mkdir(parents=True)
    names = [f"images/view_{i:02d}.png" for i in range(views)]
    for name, image in zip(names, truth.images):
        cv2.imwrite(str(root / name), image[..., ::-1])
    write_nerfstudio_transforms(root / "transforms.json", truth.cameras, names, near=0.5, far=8.0)
    return truth


def pose_errors(truth: Cameras, est: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera rotation error (deg) and centre error (world units) after aligning ``est`` onto ``truth``."""
    rotation, translation, s, _ = fit_similarity(est.centers.double(), truth.centers.double())
    rot, t = rotation.numpy(), translation.numpy()
    centres = s * est.centers.numpy() @ rot.T + t
    r_est = rot @ est.c2w[:, :3, :3].numpy()  # [N, 3, 3] camera axes in the true world
    rel = np.einsum("nji,njk->nik", truth.c2w[:, :3, :3].numpy(), r_est)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    return np.degrees(np.arccos(cos)), np.linalg.norm(centres - truth.centers.numpy(), axis=1)


def fold_mesh() -> trimesh.Trimesh:
    """The box on the floor (z = 0) inside the room (inward walls and ceiling, the floor its bottom face)."""
    box = trimesh.creation.box(extents=FOLD_BOX)
    box.apply_translation([0.0, 0.0, FOLD_BOX[2] / 2])
    room = trimesh.creation.box(extents=[2 * FOLD_ROOM_HALF, 2 * FOLD_ROOM_HALF, FOLD_ROOM_HEIGHT])
    room.apply_translation([0.0, 0.0, FOLD_ROOM_HEIGHT / 2])
    room.invert()
    return trimesh.util.concatenate([box, room])


def half_turn_colouring(hits: np.ndarray, _: np.ndarray) -> np.ndarray:
    """The fold scene's box and floor: textured at (x, y, z) as at (-x, -y, z); the walls and ceiling: uniquely."""
    on_walls = (np.abs(hits[:, :2]).max(1) > FOLD_ROOM_HALF - 1e-3) | (hits[:, 2] > FOLD_ROOM_HEIGHT - 1e-3)
    canonical = hits.copy()
    flip = (hits[:, 0] < 0) | ((hits[:, 0] == 0) & (hits[:, 1] < 0))
    canonical[flip, :2] *= -1.0
    rgb = solid_texture(canonical, 0)
    rgb[on_walls] = solid_texture(hits[on_walls] * 0.5 + 11.0, 5)
    return rgb
