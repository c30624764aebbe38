"""Shapes defined by signed distance fields, meshed with surface nets.

Booleans (union, intersection, difference, smooth blends), blobby metaballs and noisy rocks are easy as
fields and hard as meshes, so they are built here as fields [G, G, G] on a grid and turned into watertight
triangle meshes by :func:`surface_nets` (negative inside).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import trimesh

from insertnerf_cli.synth.geometry import Shape, wobble

# Grid cells per side: 48 gives ~10k triangles, smooth at a few hundred pixels, and meshes in ~50 ms.
GRID = 48
# The grid spans [-EXTENT, EXTENT]^3; shapes are built inside radius ~0.8 so the border stays outside.
EXTENT = 1.0

Field = Callable[[np.ndarray], np.ndarray]  # points [..., 3] -> signed distance [...]


# ---------------------------------------------------------------------------------------------- fields
def sphere_sdf(center: np.ndarray, radius: float) -> Field:
    return lambda p: np.linalg.norm(p - center, axis=-1) - radius


def box_sdf(center: np.ndarray, half: np.ndarray, rounding: float = 0.0) -> Field:
    def f(p: np.ndarray) -> np.ndarray:
        q = np.abs(p - center) - (half - rounding)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        return outside + np.minimum(q.max(axis=-1), 0.0) - rounding
    return f


def cylinder_sdf(center: np.ndarray, radius: float, half_height: float, axis: int) -> Field:
    def f(p: np.ndarray) -> np.ndarray:
        q = p - center
        radial = np.linalg.norm(np.delete(q, axis, axis=-1), axis=-1) - radius
        along = np.abs(q[..., axis]) - half_height
        d = np.stack([radial, along], axis=-1)
        return np.minimum(d.max(axis=-1), 0.0) + np.linalg.norm(np.maximum(d, 0.0), axis=-1)
    return f


def torus_sdf(center: np.ndarray, major: float, minor: float) -> Field:
    def f(p: np.ndarray) -> np.ndarray:
        q = p - center
        ring = np.linalg.norm(q[..., :2], axis=-1) - major
        return np.sqrt(ring ** 2 + q[..., 2] ** 2) - minor
    return f


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: a union whose seam is rounded over a width ~k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def random_solid(rng: np.random.Generator, scale: float) -> Field:
    """One of sphere, rounded box, cylinder or torus, at a random offset within ``scale``."""
    center = rng.uniform(-0.3, 0.3, 3) * scale
    kind = rng.integers(4)
    if kind == 0:
        return sphere_sdf(center, rng.uniform(0.25, 0.5) * scale)
    if kind == 1:
        return box_sdf(center, rng.uniform(0.15, 0.45, 3) * scale, rng.uniform(0.0, 0.08) * scale)
    if kind == 2:
        return cylinder_sdf(center, rng.uniform(0.1, 0.35) * scale, rng.uniform(0.2, 0.5) * scale,
                            int(rng.integers(3)))
    return torus_sdf(center, rng.uniform(0.25, 0.4) * scale, rng.uniform(0.06, 0.14) * scale)


# ---------------------------------------------------------------------------------------------- shapes
def boolean(rng: np.random.Generator) -> tuple[Field, str]:
    """Two or three solids combined by union, intersection, difference or smooth union."""
    field = random_solid(rng, 1.0)
    ops = []
    for _ in range(int(rng.integers(1, 3))):
        other = random_solid(rng, 1.0)
        op = str(rng.choice(["union", "intersection", "difference", "blend"], p=[0.2, 0.2, 0.4, 0.2]))
        ops.append(op)
        field = _combine(field, other, op, rng.uniform(0.05, 0.2))
    return field, "csg-" + "-".join(ops)


def _combine(a: Field, b: Field, op: str, k: float) -> Field:
    if op == "union":
        return lambda p: np.minimum(a(p), b(p))
    if op == "intersection":
        return lambda p: np.maximum(a(p), b(p))
    if op == "difference":
        return lambda p: np.maximum(a(p), -b(p))
    return lambda p: smooth_min(a(p), b(p), k)


def blobs(rng: np.random.Generator) -> tuple[Field, str]:
    """Metaballs: spheres smoothly merged into one blobby body."""
    count = int(rng.integers(3, 8))
    centers = rng.normal(0, 0.22, (count, 3))
    radii = rng.uniform(0.12, 0.3, count)
    k = rng.uniform(0.1, 0.25)

    def f(p: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(p[..., None, :] - centers, axis=-1) - radii  # [..., count]
        out = d[..., 0]
        for i in range(1, count):
            out = smooth_min(out, d[..., i], k)
        return out
    return f, "blobs"


def rock(rng: np.random.Generator) -> tuple[Field, str]:
    """A lumpy ellipsoid: a sphere field displaced by random plane waves (stones, hills, trunks)."""
    axes = rng.uniform(0.35, 0.7, 3)
    waves = 12
    dirs = rng.normal(size=(waves, 3))
    dirs *= (rng.uniform(2.0, 12.0, waves) / np.linalg.norm(dirs, axis=1))[:, None]
    amps = rng.uniform(0.01, 0.05, waves) * 4.0 / np.linalg.norm(dirs, axis=1) ** 0.5
    phases = rng.uniform(0, 2 * np.pi, waves)

    def f(p: np.ndarray) -> np.ndarray:
        base = (np.linalg.norm(p / axes, axis=-1) - 1.0) * axes.min()
        return base + np.sin(p @ dirs.T + phases) @ amps
    return f, "rock"


IMPLICIT: dict[str, Callable[[np.random.Generator], tuple[Field, str]]] = {
    "boolean": boolean, "blobs": blobs, "rock": rock}


def implicit_shape(rng: np.random.Generator, kind: str | None = None) -> Shape:
    """Mesh a random implicit shape; falls back to a sphere field if the draw came out empty."""
    kind = kind or str(rng.choice(list(IMPLICIT)))
    field, name = IMPLICIT[kind](rng)
    mesh = mesh_field(field)
    if len(mesh.faces) == 0:
        mesh, name = mesh_field(sphere_sdf(np.zeros(3), 0.5)), name + "-empty"
    if kind == "rock" and rng.random() < 0.5:
        mesh = trimesh.Trimesh(wobble(mesh.vertices, rng, 0.01), mesh.faces, process=False)
    return Shape(mesh, smooth=True, kind=name)


def mesh_field(field: Field, grid: int = GRID, extent: float = EXTENT) -> trimesh.Trimesh:
    """Evaluate ``field`` on a grid [grid]^3 spanning [-extent, extent]^3 and mesh its zero level set."""
    axis = np.linspace(-extent, extent, grid)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)  # [G, G, G, 3]
    values = field(points)
    # Force "outside" on the border so every surface is closed inside the grid.
    values[[0, -1], :, :] = values[:, [0, -1], :] = values[:, :, [0, -1]] = np.abs(values).max() + 1.0
    vertices, faces = surface_nets(values)
    return trimesh.Trimesh(vertices * (axis[1] - axis[0]) - extent, faces, process=False)


def surface_nets(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Naive surface nets on a scalar grid [G, G, G] (negative inside, positive outside on the border).

    One vertex per cell that the surface crosses, at the mean of its edges' zero crossings; one quad
    (two triangles) per grid edge with a sign change, joining the four cells around that edge and facing
    from inside to outside.

    Returns:
        vertices: [P, 3] in grid-index units; faces: [F, 3] int, counter-clockwise seen from outside.
    """
    inside = values < 0
    g = values.shape[0]
    sums = np.zeros((g - 1, g - 1, g - 1, 3))
    counts = np.zeros((g - 1, g - 1, g - 1))
    edge_sign = []
    for a in range(3):
        f0, f1 = _shift(values, a, 0), _shift(values, a, 1)
        crossed = _shift(inside, a, 0) != _shift(inside, a, 1)  # edges from p to p + e_a
        t = np.where(crossed, f0 / np.where(crossed, f0 - f1, 1.0), 0.0)
        position = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in crossed.shape],
                                        indexing="ij"), axis=-1)
        position[..., a] += t
        position *= crossed[..., None]
        for db in (0, 1):  # the four cells sharing the edge
            for dc in (0, 1):
                sums += _cells_of_edges(position, a, db, dc)
                counts += _cells_of_edges(crossed.astype(np.float64), a, db, dc)
        edge_sign.append((crossed, _shift(inside, a, 0)))
    active = counts > 0
    index = np.full(counts.shape, -1, dtype=np.int64)
    index[active] = np.arange(active.sum())
    vertices = sums[active] / counts[active][:, None]
    faces = [_quads(index, crossed, starts_inside, a) for a, (crossed, starts_inside) in enumerate(edge_sign)]
    return vertices, np.concatenate(faces)


def _shift(array: np.ndarray, axis: int, offset: int) -> np.ndarray:
    """array[p + offset * e_axis] for every p with p_axis < G - 1."""
    index = [slice(None)] * 3
    index[axis] = slice(offset, array.shape[axis] - 1 + offset)
    return array[tuple(index)]


def _cells_of_edges(edge_values: np.ndarray, a: int, db: int, dc: int) -> np.ndarray:
    """Per cell [G-1]^3, the value of its edge along axis a at offset (db, dc) in the other two axes."""
    b, c = (a + 1) % 3, (a + 2) % 3
    index = [slice(None)] * 3
    index[b] = slice(db, db + edge_values.shape[b] - 1)
    index[c] = slice(dc, dc + edge_values.shape[c] - 1)
    return edge_values[tuple(index)]


def _quads(index: np.ndarray, crossed: np.ndarray, starts_inside: np.ndarray, a: int) -> np.ndarray:
    """Two triangles [2K, 3] per crossed edge along axis a, joining its four neighbouring cells."""
    b, c = (a + 1) % 3, (a + 2) % 3
    edges = np.argwhere(crossed)  # [K, 3] edge start p (cells p - e_b - e_c .. p)
    edges = edges[(edges[:, b] >= 1) & (edges[:, c] >= 1) & (edges[:, b] < index.shape[b])
                  & (edges[:, c] < index.shape[c])]
    eb, ec = np.eye(3, dtype=np.int64)[b], np.eye(3, dtype=np.int64)[c]
    corners = [edges - eb - ec, edges - ec, edges, edges - eb]  # counter-clockwise in the (b, c) plane
    ids = np.stack([index[tuple(q.T)] for q in corners], axis=1)  # [K, 4]
    # Counter-clockwise in (b, c) faces +a, the outward side when the edge starts inside.
    flip = ~starts_inside[tuple(edges.T)]
    ids[flip] = ids[flip][:, ::-1]
    return np.concatenate([ids[:, [0, 1, 2]], ids[:, [0, 2, 3]]])
