"""Rendering one camera view of a :class:`World`: camera rays, shading, and extra rays on edges.

Camera rays come from :meth:`Cameras.ray_directions` with camera-z = 1, so the hit distance along a ray is
the z-depth written to the depth maps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.synth.capture import luminance
from insertnerf_cli.synth.raycast import SceneMesh, cast
from insertnerf_cli.synth.shading import shade, sky_radiance
from insertnerf_cli.synth.textures import srgb_to_linear
from insertnerf_cli.synth.world import World

# Sub-pixel offsets (pixels) of the extra rays at edges: a rotated grid, which resolves near-horizontal and
# near-vertical edges better than a square one.
_EDGE_SAMPLES = np.array([[-0.125, -0.375], [0.375, -0.125], [0.125, 0.375], [-0.375, 0.125]])
# Relative depth jump between neighbouring pixels that counts as a silhouette inside one object.
_DEPTH_EDGE = 0.04


@dataclass(frozen=True)
class ViewRender:
    """One rendered view: linear radiance [H, W, 3] and z-depth [H, W] (0 where the ray hit nothing)."""

    radiance: np.ndarray
    depth: np.ndarray


def render_view(scene: SceneMesh, world: World, camera: Cameras) -> ViewRender:
    """Render one camera (a Cameras of length 1) with extra rays on object edges (anti-aliasing)."""
    h, w = camera.height, camera.width
    uv = camera.pixel_grid().reshape(1, -1, 2)  # [1, H*W, 2]
    radiance, depth, objects = _trace(scene, world, camera, uv)
    edges = _edge_pixels(depth.reshape(h, w), objects.reshape(h, w)).reshape(-1)
    if edges.any():
        base = uv[0, torch.from_numpy(np.flatnonzero(edges))]  # [E, 2]
        offsets = torch.from_numpy(_EDGE_SAMPLES).to(base)
        sub = (base[:, None] + offsets[None]).reshape(1, -1, 2)  # [1, E*4, 2]
        extra, _, _ = _trace(scene, world, camera, sub)
        extra = extra.reshape(-1, len(_EDGE_SAMPLES), 3)
        radiance[edges] = (radiance[edges] + extra.sum(axis=1)) / (len(_EDGE_SAMPLES) + 1)
    return ViewRender(radiance.reshape(h, w, 3), depth.reshape(h, w))


def _trace(scene: SceneMesh, world: World, camera: Cameras, uv: torch.Tensor
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radiance [P, 3], z-depth [P] and object index [P] (-1 = miss) of the rays through pixels uv [1, P, 2]."""
    directions = camera.ray_directions(uv)[0].numpy()  # [P, 3], camera-z = 1
    origins = np.broadcast_to(camera.centers[0].numpy(), directions.shape)
    hits = cast(scene, origins, directions)
    radiance = np.empty(directions.shape)
    focal = float(camera.K[0, 0, 0])
    if world.sky is None:
        radiance[:] = srgb_to_linear(world.background)
    else:  # rays that leave the scene see the sky at infinity; they keep depth 0 (no surface)
        missed = np.ones(len(directions), dtype=bool)
        missed[hits.ray] = False
        radiance[missed] = sky_radiance(world.sky, directions[missed], focal)
    depth = np.zeros(len(directions))
    objects = np.full(len(directions), -1)
    radiance[hits.ray] = shade(scene, world, hits, directions[hits.ray], focal)
    depth[hits.ray] = hits.t
    objects[hits.ray] = hits.objects
    return radiance, depth, objects


def _edge_pixels(depth: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """[H, W] bool: pixels whose 4-neighbours show another object or a depth jump (silhouettes, creases)."""
    edge = np.zeros(depth.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        da, db = depth[tuple(a)], depth[tuple(b)]
        jump = (objects[tuple(a)] != objects[tuple(b)]) | (np.abs(da - db) > _DEPTH_EDGE * np.maximum(da, db))
        edge[tuple(a)] |= jump
        edge[tuple(b)] |= jump
    return edge


def auto_exposure(scene: SceneMesh, world: World, cameras: Cameras, target: float = 0.85) -> float:
    """Factor for the lights so that the 95th percentile of lit-surface luminance lands at ``target``.

    Measured on up to four views at a quarter of the resolution; the sky and the background (rays that hit
    nothing) are left out (a photographer exposes for the subject; the sky stays as painted).
    """
    samples = []
    for i in np.linspace(0, len(cameras) - 1, min(4, len(cameras))).round().astype(int):
        camera = cameras[[int(i)]]
        small = camera.rescale(max(1, camera.height // 4), max(1, camera.width // 4))
        radiance, _, objects = _trace(scene, world, small, small.pixel_grid().reshape(1, -1, 2))
        samples.append(luminance(radiance[objects >= 0]))
    values = np.concatenate(samples)
    if len(values) == 0:
        return 1.0
    return float(np.clip(target / max(np.percentile(values, 95), 1e-6), 0.25, 4.0))
