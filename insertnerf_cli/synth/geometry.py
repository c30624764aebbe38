"""Procedural shapes in object space: primitives, deformed variants and thin structures.

Every builder takes a numpy ``Generator`` and returns a :class:`Shape` centred near the origin with a
size of about 1 (its bounding radius lies in [0.4, 1]); the scene composer scales and places it.
Implicit shapes (booleans, blobs, rocks) live in implicit.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh
from trimesh import creation

# Triangle budget per curved primitive: enough that silhouettes look round at a few hundred pixels.
_SECTIONS = 32
# Edge length (object units) below which deformable meshes are subdivided so bends stay smooth.
_DEFORM_EDGE = 0.08


@dataclass(frozen=True)
class Shape:
    """A mesh in its own object frame.

    Attributes:
        mesh: triangles in object coordinates.
        smooth: interpolate vertex normals (curved surfaces) instead of using face normals.
        kind: name of the builder, kept in the scene description.
    """

    mesh: trimesh.Trimesh
    smooth: bool
    kind: str


def _mesh(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices=np.asarray(vertices, dtype=np.float64), faces=faces, process=False)


def _subdivided(mesh: trimesh.Trimesh, max_edge: float = _DEFORM_EDGE) -> trimesh.Trimesh:
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge)
    return _mesh(vertices, faces)


# ---------------------------------------------------------------------------------------------- primitives
def box(rng: np.random.Generator) -> Shape:
    return Shape(creation.box(extents=rng.uniform(0.4, 1.2, 3)), smooth=False, kind="box")


def sphere(rng: np.random.Generator) -> Shape:
    mesh = creation.icosphere(subdivisions=3, radius=0.5)
    if rng.random() < 0.5:  # ellipsoid
        mesh.apply_scale(rng.uniform(0.6, 1.5, 3))
    return Shape(mesh, smooth=True, kind="sphere")


def cylinder(rng: np.random.Generator) -> Shape:
    mesh = creation.cylinder(radius=rng.uniform(0.2, 0.5), height=rng.uniform(0.4, 1.3), sections=_SECTIONS)
    return Shape(mesh, smooth=True, kind="cylinder")


def cone(rng: np.random.Generator) -> Shape:
    height = rng.uniform(0.5, 1.2)
    mesh = creation.cone(radius=rng.uniform(0.25, 0.55), height=height, sections=_SECTIONS)
    mesh.apply_translation((0.0, 0.0, -height / 2))
    return Shape(mesh, smooth=True, kind="cone")


def capsule(rng: np.random.Generator) -> Shape:
    mesh = creation.capsule(height=rng.uniform(0.3, 0.9), radius=rng.uniform(0.15, 0.35), count=[16, 16])
    return Shape(mesh, smooth=True, kind="capsule")


def torus(rng: np.random.Generator) -> Shape:
    major = rng.uniform(0.3, 0.5)
    mesh = creation.torus(major_radius=major, minor_radius=major * rng.uniform(0.2, 0.55),
                          major_sections=_SECTIONS, minor_sections=_SECTIONS // 2)
    return Shape(mesh, smooth=True, kind="torus")


PRIMITIVES: dict[str, Callable[[np.random.Generator], Shape]] = {
    "box": box, "sphere": sphere, "cylinder": cylinder, "cone": cone, "capsule": capsule, "torus": torus}


# ---------------------------------------------------------------------------------------------- deformations
def twist(vertices: np.ndarray, turns: float) -> np.ndarray:
    """Rotate each vertex [P, 3] about z by an angle proportional to its height."""
    z = vertices[:, 2]
    angle = turns * 2 * np.pi * (z - z.min()) / max(np.ptp(z), 1e-9)
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * vertices[:, 0] - s * vertices[:, 1], s * vertices[:, 0] + c * vertices[:, 1], z], axis=1)


def taper(vertices: np.ndarray, amount: float) -> np.ndarray:
    """Scale x, y linearly with height: 1 at the bottom, 1 + amount at the top."""
    z = vertices[:, 2]
    scale = 1.0 + amount * (z - z.min()) / max(np.ptp(z), 1e-9)
    return vertices * np.stack([scale, scale, np.ones_like(scale)], axis=1)


def bend(vertices: np.ndarray, angle: float) -> np.ndarray:
    """Bend along z around an axis parallel to y, through a total ``angle`` (radians)."""
    if abs(angle) < 1e-6:
        return vertices
    z = vertices[:, 2]
    radius = max(np.ptp(z), 1e-9) / angle
    theta = (z - z.min()) / radius
    x = vertices[:, 0]
    out = vertices.copy()
    out[:, 0] = (radius + x) * np.cos(theta) - radius
    out[:, 2] = z.min() + (radius + x) * np.sin(theta)
    return out


def wobble(vertices: np.ndarray, rng: np.random.Generator, amplitude: float, waves: int = 6) -> np.ndarray:
    """Displace vertices by a smooth random field: a sum of plane waves with random directions."""
    directions = rng.normal(size=(waves, 3))
    freqs = rng.uniform(2.0, 7.0, waves)[:, None] * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    phases = rng.uniform(0, 2 * np.pi, waves)
    field = np.sin(vertices @ freqs.T + phases)  # [P, waves]
    offsets = field @ rng.normal(size=(waves, 3)) / np.sqrt(waves)  # [P, 3]
    return vertices + amplitude * offsets


def deformed(rng: np.random.Generator) -> Shape:
    """A primitive with one or two of twist, taper, bend and wobble applied."""
    base = PRIMITIVES[str(rng.choice(list(PRIMITIVES)))](rng)
    mesh = _subdivided(base.mesh)
    vertices = mesh.vertices
    ops = rng.choice(["twist", "taper", "bend", "wobble"], size=rng.integers(1, 3), replace=False)
    for op in ops:
        if op == "twist":
            vertices = twist(vertices, rng.uniform(-0.5, 0.5))
        elif op == "taper":
            vertices = taper(vertices, rng.uniform(-0.7, 0.8))
        elif op == "bend":
            vertices = bend(vertices, rng.uniform(-1.5, 1.5))
        else:
            vertices = wobble(vertices, rng, rng.uniform(0.02, 0.08))
    return Shape(_mesh(vertices, mesh.faces), smooth=base.smooth, kind=f"{base.kind}+{'+'.join(ops)}")


# ---------------------------------------------------------------------------------------------- thin structures
def _rod(start: np.ndarray, end: np.ndarray, radius: float) -> trimesh.Trimesh:
    """A thin cylinder between two points."""
    return creation.cylinder(radius=radius, segment=np.stack([start, end]), sections=10)


def rods(rng: np.random.Generator) -> Shape:
    """A frame of thin rods: the edges of a box, a few random struts, or a bundle of sticks."""
    radius = rng.uniform(0.008, 0.03)
    style = rng.choice(["frame", "sticks"])
    if style == "frame":
        half = rng.uniform(0.2, 0.5, 3)
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
        pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(corners[i] != corners[j]) == 1]
        parts = [_rod(corners[i], corners[j], radius) for i, j in pairs]
    else:
        starts = rng.uniform(-0.3, 0.3, (int(rng.integers(3, 9)), 3)) * (1, 1, 0) + (0, 0, -0.5)
        ends = starts + rng.normal(0, 0.25, starts.shape) + (0, 0, 1.0)
        parts = [_rod(a, b, radius) for a, b in zip(starts, ends)]
    return Shape(trimesh.util.concatenate(parts), smooth=True, kind=f"rods-{style}")


def plate(rng: np.random.Generator) -> Shape:
    """A thin board, optionally bent like a sheet."""
    mesh = _subdivided(creation.box(extents=(rng.uniform(0.5, 1.2), rng.uniform(0.3, 1.0), rng.uniform(0.01, 0.04))),
                       max_edge=0.1)
    vertices = mesh.vertices[:, [2, 1, 0]]  # bend about y acts along the plate's long side
    vertices = bend(vertices, rng.uniform(-1.2, 1.2) * (rng.random() < 0.5))[:, [2, 1, 0]]
    return Shape(_mesh(vertices, mesh.faces), smooth=False, kind="plate")


def leaf_card(length: float, width: float, curl: float, segments: int = 8) -> trimesh.Trimesh:
    """A single-sided leaf-shaped card along +x: a strip that is widest in the middle and curls down."""
    s = np.linspace(0.0, 1.0, segments + 1)
    half = width * np.sin(np.pi * s) ** 0.8 / 2
    x = s * length
    z = -curl * (s * length) ** 2
    left = np.stack([x, half, z], axis=1)
    right = np.stack([x, -half, z], axis=1)
    vertices = np.concatenate([left, right])
    n = segments + 1
    quads = [(i, i + 1, n + i + 1, n + i) for i in range(segments)]
    faces = np.array([f for a, b, c, d in quads for f in ((a, d, b), (b, d, c))])
    return _mesh(vertices, faces)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, axis)


def plant(rng: np.random.Generator) -> Shape:
    """A stem with leaf cards spiralling around it (thin, self-occluding, single-sided geometry)."""
    height = rng.uniform(0.6, 1.0)
    parts = [_rod(np.array([0, 0, -height / 2]), np.array([0, 0, height / 2]), rng.uniform(0.01, 0.025))]
    n_leaves = int(rng.integers(4, 14))
    golden = np.pi * (3 - np.sqrt(5))
    for i in range(n_leaves):
        leaf = leaf_card(rng.uniform(0.2, 0.45), rng.uniform(0.06, 0.18), rng.uniform(0.0, 1.5))
        leaf.apply_transform(_rotation(np.array([0, 1.0, 0]), -rng.uniform(0.1, 0.8)))  # tilt up
        leaf.apply_transform(_rotation(np.array([0, 0, 1.0]), i * golden))
        leaf.apply_translation((0, 0, -height / 2 + height * (0.2 + 0.8 * (i + 1) / n_leaves)))
        parts.append(leaf)
    return Shape(trimesh.util.concatenate(parts), smooth=True, kind="plant")


def fence(rng: np.random.Generator) -> Shape:
    """A fence or railing along x, one unit long: posts, 1-3 rails, and maybe thin pickets in between."""
    height = rng.uniform(0.25, 0.5)
    posts = int(rng.integers(3, 8))
    thickness = rng.uniform(0.006, 0.02)
    xs = np.linspace(-0.5, 0.5, posts)
    parts = [creation.box(extents=(2 * thickness, 2 * thickness, height)) for _ in xs]
    for part, x in zip(parts, xs):
        part.apply_translation((x, 0.0, height / 2))
    for level in rng.uniform(0.3, 1.0, int(rng.integers(1, 4))):
        parts.append(_rod(np.array([-0.5, 0, level * height]), np.array([0.5, 0, level * height]), thickness * 0.7))
    if rng.random() < 0.5:  # pickets
        for x in np.linspace(-0.5, 0.5, int(rng.integers(8, 40))):
            parts.append(_rod(np.array([x, 0, 0.0]), np.array([x, 0, height * 0.9]), thickness * 0.5))
    return Shape(trimesh.util.concatenate(parts), smooth=False, kind="fence")


THIN: dict[str, Callable[[np.random.Generator], Shape]] = {"rods": rods, "plate": plate, "plant": plant,
                                                           "fence": fence}


# ---------------------------------------------------------------------------------------------- scenery
def trimesh_box(extents: np.ndarray) -> trimesh.Trimesh:
    """An axis-aligned box [3] centred at the origin."""
    return creation.box(extents=extents)


def cylinder_mesh(radius: float, height: float, sections: int = 32) -> trimesh.Trimesh:
    """An upright closed cylinder centred at the origin."""
    return creation.cylinder(radius=radius, height=height, sections=sections)


def ground_disc(radius: float, height: float, sections: int = 48, rings: int = 8) -> trimesh.Trimesh:
    """A disc facing +z at the given height, as concentric rings of quads with radii growing geometrically.

    Rings keep triangles compact; a plain fan of long slivers from the centre slows embree's BVH down.
    """
    radii = np.concatenate([[0.0], radius * np.geomspace(0.02, 1.0, rings)])  # [rings + 1]
    angle = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    ring_xy = radii[:, None, None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)  # [rings + 1, sections, 2]
    vertices = np.concatenate([ring_xy.reshape(-1, 2), np.full((ring_xy.shape[0] * sections, 1), height)], axis=1)
    r, s = np.meshgrid(np.arange(rings), np.arange(sections), indexing="ij")
    a, b = r * sections + s, r * sections + (s + 1) % sections  # inner ring
    c, d = a + sections, b + sections  # outer ring
    faces = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)])
    return _mesh(vertices, faces)


def _quad(corners: np.ndarray) -> trimesh.Trimesh:
    """Two triangles of a quad [4, 3] given counter-clockwise as seen from the side it faces."""
    return _mesh(corners, np.array([[0, 1, 2], [0, 2, 3]]))


def room_faces(extents: np.ndarray) -> list[tuple[str, trimesh.Trimesh]]:
    """The six inward-facing quads ("floor", "ceiling", 4 x "wall") of a box [3] with its floor at z = 0."""
    x, y, z = extents[0] / 2, extents[1] / 2, extents[2]
    c = np.array([[-x, -y, 0], [x, -y, 0], [x, y, 0], [-x, y, 0],
                  [-x, -y, z], [x, -y, z], [x, y, z], [-x, y, z]], dtype=np.float64)
    faces = {"floor": [0, 1, 2, 3], "ceiling": [4, 7, 6, 5], "wall-s": [0, 4, 5, 1], "wall-e": [1, 5, 6, 2],
             "wall-n": [2, 6, 7, 3], "wall-w": [3, 7, 4, 0]}
    return [(name.split("-")[0], _quad(c[idx])) for name, idx in faces.items()]
