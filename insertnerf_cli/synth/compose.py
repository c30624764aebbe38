"""Random scene compositions for the three layouts: object, 360 and forward.

* object: a cluster of shapes of radius ~1 at the origin on a plain (white, black, coloured) or textured
  background, sometimes on a base plate (like NeRF-Synthetic).
* 360: shapes standing on a ground in the middle of a textured room or under a sky dome with distant
  scenery, so every ray ends on a surface (like phone orbits of real objects).
* forward: shapes spread at many depths in front of a camera plane, with ground, walls and sky behind
  (like LLFF captures).
"""
from __future__ import annotations

import numpy as np

from dataclasses import dataclass

from . import geometry
from .geometry import Shape
from .world import (Light, Material, Placed, Stage, World, ambient_pair, light_tint, random_material,
                    random_rotation, random_shape, sky_material, sun_light)

# Sky domes stay well inside the 65.535-unit range of uint16 millimetre depth.
_MAX_SKY = 40.0
# Half-size of the x-y box that object and 360 cameras (at distance ~2.5-5 from a radius-1 subject) need.
_REACH = np.array([5.0, 5.0])
# Lowest ceiling above the stage centre: clears a radius-1 subject and forward camera planes.
_MIN_CEILING = 2.5
# Texture tiles of floors, walls and grounds span 0.2-2 units: coarser tiles blur up close at 200 pixels.
_SCENERY_TILE = 1.4


@dataclass(frozen=True)
class Enclosure:
    """What surrounds the scene: kind ("room" or "sky"), the x-y box of the room (or of the needed space
    under the sky) as ``center`` [2] and ``size`` [2], the floor and ceiling heights, and ``limit``: how far
    from the origin cameras may go."""

    kind: str
    center: np.ndarray
    size: np.ndarray
    floor: float
    ceiling: float
    limit: float


class _Builder:
    """Accumulates placed shapes and materials while a composition is drawn."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.objects: list[Placed] = []
        self.materials: list[Material] = []
        self.names: list[str] = []

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

    def world(self, lights: list[Light], stage: Stage, background: np.ndarray, ambient: float,
              **description) -> World:
        sky, ground = ambient_pair(self.rng, ambient)
        return World(tuple(self.objects), tuple(self.materials), tuple(lights), stage, np.asarray(background),
                     sky, ground, {"shapes": self.names, "materials": [m.name for m in self.materials],
                                   "lights": [light.kind for light in lights], **description})


def _identity() -> np.ndarray:
    return np.eye(3)


def _cluster(b: _Builder, count: int, floor: float | None) -> None:
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


def _normalize(b: _Builder, radius: float) -> float:
    """Scale and shift every object so the subject's bounding sphere is centred at the origin (x, y) with the
    given radius; returns the height of the lowest point afterwards."""
    vertices = np.concatenate([o.world_vertices() for o in b.objects])
    center = (vertices.max(axis=0) + vertices.min(axis=0)) / 2
    factor = radius / max(np.linalg.norm(vertices - center, axis=1).max(), 1e-9)
    b.objects = [Placed(o.shape, o.rotation, (o.translation - center) * factor, o.scale * factor, o.material,
                        o.casts_shadow) for o in b.objects]
    return float((vertices[:, 2].min() - center[2]) * factor)


def _base_plate(b: _Builder) -> None:
    """A thin slab under the cluster, its top at z = 0 (like the base of NeRF-Synthetic's lego)."""
    vertices = np.concatenate([o.world_vertices() for o in b.objects])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    thickness = 0.05 * float(np.ptp(vertices[:, :2], axis=0).max())
    extents = np.array([*(high[:2] - low[:2]) * b.rng.uniform(1.1, 1.4, 2), thickness])
    center = np.array([*(high[:2] + low[:2]) / 2, -thickness / 2])
    plate = Shape(geometry.trimesh_box(extents), smooth=False, kind="base-plate")
    b.add(plate, _identity(), center, 1.0, material=b.material(random_material(b.rng)))


def _random_background(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    kind = str(rng.choice(["white", "black", "color", "textured"], p=[0.3, 0.2, 0.25, 0.25]))
    color = {"white": np.ones(3), "black": np.zeros(3)}.get(kind, rng.uniform(0.05, 0.95, 3))
    return kind, color


def compose_object(rng: np.random.Generator) -> World:
    """A NeRF-Synthetic-like subject of radius 1 at the origin, lit by 1-3 lights."""
    b = _Builder(rng)
    on_plate = rng.random() < 0.3
    _cluster(b, int(rng.integers(1, 6)), 0.0 if on_plate else None)
    if on_plate:
        _base_plate(b)
    lowest = _normalize(b, 1.0)
    kind, background = _random_background(rng)
    stage = Stage(np.zeros(3), 1.0, lowest if on_plate else None)
    if kind == "textured":
        ground = lowest if on_plate else lowest - float(rng.uniform(0.0, 0.5))
        enclosure = _enclosure(b, rng, ground, -_REACH, _REACH)
        stage = Stage(np.zeros(3), 1.0, ground, enclosure.limit, ceiling=enclosure.ceiling)
    # A key light and up to two more; the third casts no shadow (cost: one batch of shadow rays per light).
    lights = [sun_light(rng, rng.uniform(0.6, 1.8), shadows=k < 2) for k in range(int(rng.integers(1, 4)))]
    return b.world(lights, stage, background,
                   ambient=float(rng.uniform(0.15, 0.5)), layout="object", surroundings=kind, plate=on_plate)


def _enclosure(b: _Builder, rng: np.random.Generator, floor: float, lo: np.ndarray, hi: np.ndarray) -> Enclosure:
    """Surround the scene with a room (walls, floor, ceiling, furniture) or a sky dome over a ground disc.

    ``lo``, ``hi`` [2]: the x-y box that must stay inside (subjects and cameras).
    Returns the kind and the largest distance from the origin that cameras may use.
    """
    span = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
    if rng.random() < 0.5:
        center = (lo + hi) / 2
        size = (hi - lo) * rng.uniform(1.1, 1.6, 2)
        extents = np.array([*size, max(rng.uniform(0.35, 0.6) * size.max(), _MIN_CEILING - floor)])
        material = b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False))
        for name, mesh in geometry.room_faces(extents):
            mesh.apply_translation((center[0], center[1], floor))
            if name != "wall":  # floor and ceiling differ from the walls
                material = b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False))
            b.add(Shape(mesh, smooth=False, kind=name), _identity(), np.zeros(3), 1.0, material=material,
                  casts_shadow=False)
        for _ in range(int(rng.integers(2, 7))):  # furniture along the walls
            along = rng.uniform(-0.45, 0.45)
            spot = np.array([[0.47, along], [-0.47, along], [along, 0.47], [along, -0.47]])[rng.integers(4)]
            b.stand(random_shape(rng), center + spot * size, float(rng.uniform(0.05, 0.15) * size.min()), floor)
        # Furniture reaches ~0.2 of the way in from the walls: cameras stay inside 0.7 of the nearest wall.
        limit = float(np.min(np.abs(np.concatenate([center - size / 2, center + size / 2]))) * 0.7)
        return Enclosure("room", center, size, floor, floor + extents[2], limit)
    radius = float(min(rng.uniform(2.0, 4.0) * span, _MAX_SKY))
    b.add(Shape(geometry.sky_dome(radius), smooth=False, kind="sky"), _identity(), np.zeros(3), 1.0,
          material=b.material(sky_material(rng)), casts_shadow=False)
    b.add(Shape(geometry.ground_disc(radius * 0.995, floor), smooth=False, kind="ground"), _identity(),
          np.zeros(3), 1.0, material=b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False)),
          casts_shadow=False)
    for _ in range(int(rng.integers(3, 12))):  # distant scenery: hills, rocks, trees, blocks
        # Beyond the needed space when the dome allows it; deep forward scenes mix scenery into their far part.
        angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(min(span * 1.1, 0.6 * radius), 0.8 * radius)
        b.stand(random_shape(rng), distance * np.array([np.cos(angle), np.sin(angle)]),
                float(rng.uniform(0.05, 0.2) * distance), floor)
    return Enclosure("sky", (lo + hi) / 2, hi - lo, floor, floor + radius, span)


def _scene_lights(rng: np.random.Generator, enclosure: Enclosure) -> list[Light]:
    """A sun (sky) or 1-3 point lights under the ceiling (room), plus maybe a weak fill light."""
    if enclosure.kind == "sky":
        lights = [sun_light(rng, rng.uniform(1.2, 2.5))]
    else:
        lights = []
        height = enclosure.ceiling - enclosure.floor
        for k in range(int(rng.integers(1, 4))):
            xy = enclosure.center + rng.uniform(-0.35, 0.35, 2) * enclosure.size
            position = np.array([*xy, enclosure.floor + rng.uniform(0.6, 0.9) * height])
            # Irradiance ~1-2 at the floor below the light, whatever the room size.
            power = rng.uniform(1.0, 2.0) * (position[2] - enclosure.floor) ** 2
            lights.append(Light("point", position, power * light_tint(rng) / 2, shadows=k < 2))
    if rng.random() < 0.4:
        lights.append(sun_light(rng, rng.uniform(0.1, 0.4), shadows=False))
    return lights


def compose_360(rng: np.random.Generator) -> World:
    """Subjects of radius ~1 standing on a floor at the origin, inside a room or under a sky."""
    b = _Builder(rng)
    _cluster(b, int(rng.integers(1, 6)), 0.0)
    floor = _normalize(b, 1.0)
    enclosure = _enclosure(b, rng, floor, -_REACH, _REACH)
    stage = Stage(np.zeros(3), 1.0, floor, enclosure.limit, ceiling=enclosure.ceiling)
    return b.world(_scene_lights(rng, enclosure), stage, np.zeros(3),
                   ambient=float(rng.uniform(0.15, 0.4)), layout="360", surroundings=enclosure.kind)


def compose_forward(rng: np.random.Generator) -> World:
    """Shapes at depths from ``near`` to ``deep`` along +y in front of a camera plane at the origin."""
    b = _Builder(rng)
    near = float(rng.uniform(1.5, 3.0))
    deep = float(near * rng.uniform(3.0, 8.0))
    floor = -float(rng.uniform(0.8, 2.0))
    for _ in range(int(rng.integers(4, 14))):
        depth = float(near + (deep - near) * rng.random() ** 1.5)  # denser near the camera
        scale = float(depth * rng.uniform(0.08, 0.3))
        x = depth * rng.uniform(-0.6, 0.6)
        if rng.random() < 0.6:
            b.stand(random_shape(rng), np.array([x, depth + scale]), scale, floor, upright=rng.random() < 0.7)
        else:
            b.add(random_shape(rng), random_rotation(rng, False),
                  np.array([x, depth + scale, floor + depth * rng.uniform(0.1, 0.5)]), scale)
    enclosure = _enclosure(b, rng, floor, np.array([-0.7 * deep, -1.0]), np.array([0.7 * deep, 1.3 * deep]))
    return b.world(_scene_lights(rng, enclosure), Stage(np.zeros(3), deep, floor, depth=near), np.zeros(3),
                   ambient=float(rng.uniform(0.15, 0.4)), layout="forward", surroundings=enclosure.kind)


COMPOSERS = {"object": compose_object, "360": compose_360, "forward": compose_forward}
