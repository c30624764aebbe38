"""The accumulator every composition draws into (placed shapes, materials, the sky) and the subject cluster
that the object, 360 and handheld compositions share."""
from __future__ import annotations

import numpy as np

from insertnerf_cli.synth.geometry import Shape
from insertnerf_cli.synth.world import (
    Light,
    Material,
    Placed,
    Stage,
    World,
    ambient_pair,
    random_material,
    random_rotation,
    random_shape,
)


class Builder:
    """Accumulates placed shapes and materials while a composition is drawn; ``sky`` is the environment at
    infinity that rays leaving the scene see (None: they see the flat background colour)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.objects: list[Placed] = []
        self.materials: list[Material] = []
        self.names: list[str] = []
        self.sky: Material | None = None

    def material(self, material: Material) -> int:
        self.materials.append(material)
        return len(self.materials) - 1

    def add(self, shape: Shape, rotation: np.ndarray, translation: np.ndarray, scale: float,
            material: int | None = None, casts_shadow: bool = True) -> Placed:
        if material is None:
            material = self.material(random_material(self.rng, tile_scale=scale))
        placed = Placed(shape, rotation, np.asarray(translation, dtype=np.float64), float(scale), material,
                        casts_shadow)
        self.objects.append(placed)
        self.names.append(shape.kind)
        return placed

    def stand(self, shape: Shape, xy: np.ndarray, scale: float, floor: float, upright: bool = True) -> Placed:
        """Place ``shape`` so its lowest point rests on z = ``floor`` (sunk a little so it does not float)."""
        rotation = random_rotation(self.rng, upright)
        lowest = (scale * shape.mesh.vertices @ rotation.T)[:, 2].min()
        sink = 0.03 * scale * self.rng.random()
        return self.add(shape, rotation, np.array([xy[0], xy[1], floor - lowest - sink]), scale)

    def shift(self, offset: np.ndarray) -> None:
        """Move every object placed so far by ``offset`` [3]."""
        self.objects = [Placed(o.shape, o.rotation, o.translation + offset, o.scale, o.material, o.casts_shadow)
                        for o in self.objects]

    def world(self, lights: list[Light], stage: Stage, background: np.ndarray, ambient: float,
              **description) -> World:
        sky, ground = ambient_pair(self.rng, ambient)
        return World(tuple(self.objects), tuple(self.materials), tuple(lights), stage, np.asarray(background),
                     sky, ground, {"shapes": self.names, "materials": [m.name for m in self.materials],
                                   "lights": [light.kind for light in lights],
                                   "sky": "at infinity (depth 0)" if self.sky is not None else "none",
                                   **description}, sky=self.sky)


def identity() -> np.ndarray:
    return np.eye(3)


def cluster(b: Builder, count: int, floor: float | None) -> None:
    """One compound subject: a main shape at the origin and ``count - 1`` smaller ones touching or
    overlapping it (occlusions, contact), free-floating or standing on ``floor``."""
    rng = b.rng
    for k in range(count):
        shape = random_shape(rng)
        scale = float(rng.uniform(0.8, 1.2) if k == 0 else rng.uniform(0.3, 0.7))
        # Shapes have a radius of ~0.5 per unit of scale: this distance makes neighbours touch or overlap.
        distance = 0.0 if k == 0 else float(rng.uniform(0.5, 1.0) * (0.5 + 0.5 * scale))
        direction = rng.normal(size=3)
        if floor is not None:
            direction[2] = 0.0
        direction *= distance / max(np.linalg.norm(direction), 1e-9)
        if floor is None:
            b.add(shape, random_rotation(rng, False), direction, scale)
        else:
            b.stand(shape, direction[:2], scale, floor, upright=rng.random() < 0.7)


def normalize(b: Builder, radius: float) -> float:
    """Scale and shift every object so the subject's bounding sphere is centred at the origin (x, y) with the
    given radius; returns the height of the lowest point afterwards."""
    vertices = np.concatenate([o.world_vertices() for o in b.objects])
    center = (vertices.max(axis=0) + vertices.min(axis=0)) / 2
    factor = radius / max(np.linalg.norm(vertices - center, axis=1).max(), 1e-9)
    b.objects = [Placed(o.shape, o.rotation, (o.translation - center) * factor, o.scale * factor, o.material,
                        o.casts_shadow) for o in b.objects]
    return float((vertices[:, 2].min() - center[2]) * factor)
