"""Ray casting with embree (embreex, the engine behind trimesh's ``RayMeshIntersector``).

A :class:`World` is flattened once into a :class:`SceneMesh` (all triangles, per-face object index,
per-corner normals, one embree scene for camera rays and one for shadow casters) and reused for every view.
:class:`Caster` calls embreex directly rather than through trimesh: trimesh converts to float64, normalises
every direction and has no occlusion query, which made camera rays twice and shadow rays four times slower.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from insertnerf_cli.synth.world import World

# Smooth shading stops at creases sharper than this (cylinder rims, box-like CSG edges).
_CREASE = np.radians(35.0)


class Caster:
    """An embree scene of triangles [F, 3, 3] answering first-hit and occlusion queries in batches.

    Coordinates are shifted so the geometry starts at the origin before the float32 conversion (float32 is
    most precise near zero), as trimesh does.
    """

    def __init__(self, triangles: np.ndarray) -> None:
        self.shift = triangles.reshape(-1, 3).min(axis=0)
        self._scene = rtcore_scene.EmbreeScene()
        vertices = (triangles.reshape(-1, 3) - self.shift).astype(np.float32)
        # The mesh object must stay referenced for as long as the scene is used.
        self._mesh = TriangleMesh(scene=self._scene, vertices=vertices,
                                  indices=np.arange(len(vertices), dtype=np.int32).reshape(-1, 3))

    def first(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Index of the first triangle hit [R] (-1 = miss), its ray parameter t [R] in units of the
        direction's length, and its barycentric (u, v) [R, 2]."""
        out = self._scene.run(self._origins(origins), np.ascontiguousarray(directions, dtype=np.float32), output=1)
        return out["primID"].astype(np.int64), out["tfar"], np.stack([out["u"], out["v"]], axis=1)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distance: np.ndarray | None) -> np.ndarray:
        """[R] bool: something lies along the ray before ``distance`` [R] (None = unbounded) in units of
        ``directions``' length."""
        dists = None if distance is None else np.ascontiguousarray(distance, dtype=np.float32)
        out = self._scene.run(self._origins(origins), np.ascontiguousarray(directions, dtype=np.float32),
                              dists=dists, query="OCCLUDED")
        return out == 0  # embreex: 0 where occluded, -1 where the ray is free

    def _origins(self, origins: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(origins - self.shift, dtype=np.float32)


@dataclass(frozen=True)
class SceneMesh:
    """All triangles of a world, ready for ray casting.

    Attributes:
        caster: embree scene of every triangle (camera rays).
        shadow_caster: embree scene of shadow-casting triangles only (None if there are none).
        shadow_faces: [Fs] index into ``triangles`` of each shadow-caster triangle.
        triangles: [F, 3, 3] world-space corners; face_normals [F, 3]; corner_normals [F, 3, 3].
        face_object: [F] index into ``world.objects``.
        shadow_extent: size of the shadow casters' bounding box (sets the offset of shadow-ray origins).
        object_rotation, object_translation, object_material: [O, 3, 3], [O, 3], [O] of the placed objects.
    """

    caster: Caster
    shadow_caster: Caster | None
    shadow_faces: np.ndarray  # [Fs]
    triangles: np.ndarray  # [F, 3, 3]
    face_normals: np.ndarray  # [F, 3]
    corner_normals: np.ndarray  # [F, 3, 3]
    face_object: np.ndarray  # [F]
    shadow_extent: float
    object_rotation: np.ndarray  # [O, 3, 3]
    object_translation: np.ndarray  # [O, 3]
    object_material: np.ndarray  # [O]


@dataclass(frozen=True)
class Hits:
    """First hits of R rays, of which H hit something.

    Attributes:
        ray: [H] index of the ray; t: [H] ray parameter (z-depth for camera rays); points [H, 3];
        normals: [H, 3] shading normals turned to face the ray; objects: [H] object index;
        geometric: [H, 3] face normals turned to face the ray (offsets of shadow-ray origins).
    """

    ray: np.ndarray
    t: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    objects: np.ndarray
    geometric: np.ndarray


def build_scene_mesh(world: World) -> SceneMesh:
    """Flatten every placed object into one triangle soup with per-corner shading normals."""
    triangles, corners, owner, casts = [], [], [], []
    for index, placed in enumerate(world.objects):
        mesh = placed.shape.mesh
        if placed.shape.smooth:
            mesh = trimesh.graph.smooth_shade(mesh, angle=_CREASE)
            normals = mesh.vertex_normals[mesh.faces] @ placed.rotation.T  # [F, 3, 3]
        else:
            normals = np.repeat((mesh.face_normals @ placed.rotation.T)[:, None], 3, axis=1)
        vertices = placed.scale * mesh.vertices @ placed.rotation.T + placed.translation
        triangles.append(vertices[mesh.faces])
        corners.append(normals)
        owner.append(np.full(len(mesh.faces), index))
        casts.append(np.full(len(mesh.faces), placed.casts_shadow))
    tris = np.concatenate(triangles)
    shadow_faces = np.flatnonzero(np.concatenate(casts))
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-20)
    casters = tris[shadow_faces].reshape(-1, 3)
    return SceneMesh(caster=Caster(tris), shadow_caster=Caster(tris[shadow_faces]) if len(shadow_faces) else None,
                     shadow_faces=shadow_faces, triangles=tris, face_normals=normals,
                     corner_normals=np.concatenate(corners), face_object=np.concatenate(owner),
                     shadow_extent=float(np.ptp(casters, axis=0).max()) if len(casters) else 1.0,
                     object_rotation=np.stack([o.rotation for o in world.objects]),
                     object_translation=np.stack([o.translation for o in world.objects]),
                     object_material=np.array([o.material for o in world.objects]))


def cast(scene: SceneMesh, origins: np.ndarray, directions: np.ndarray) -> Hits:
    """First hit of each ray (origins, directions [R, 3]; directions need not be unit)."""
    face, t, uv = scene.caster.first(origins, directions)
    ray = np.flatnonzero(face >= 0)
    # embree's float32 t is exact to ~1e-7 relative: far below the millimetre steps of the depth files.
    face, t, uv = face[ray], t[ray].astype(np.float64), uv[ray]
    points = origins[ray] + t[:, None] * directions[ray]
    weights = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)  # barycentric, from embree
    normals = np.einsum("hk,hkc->hc", weights, scene.corner_normals[face])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    # Thin cards, room walls and the sky are seen from their back side too: shade the side facing the ray.
    geometric = scene.face_normals[face].copy()
    facing = np.einsum("hc,hc->h", geometric, directions[ray]) > 0
    normals[facing] *= -1
    geometric[facing] *= -1
    return Hits(ray, t, points, normals, scene.face_object[face], geometric)
