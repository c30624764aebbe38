"""What surrounds a scene: a furnished room, an open sky over a ground, or a street canyon between buildings.

Skies are environments at infinity (``Builder.sky``): a ray that leaves the scene takes the sky's colour by
its direction and has no surface, so its depth is 0 (as an object layout's plain background). Distant
textured walls (buildings, cliffs) and street facades stand far beyond the subject, at many depths, but
inside the 65.535-unit range of the uint16 millimetre depth files.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from insertnerf_cli.synth import geometry
from insertnerf_cli.synth.builder import Builder, identity
from insertnerf_cli.synth.geometry import Shape
from insertnerf_cli.synth.world import Light, light_tint, random_material, random_shape, sky_material, sun_light

# Radius of the ground under an open sky: the farthest surface any camera near the origin sees (< 65.5).
GROUND_RADIUS = 55.0
# Distant scenery (hills, rocks, trees) stays within this distance of the origin.
_MAX_SCENERY = 40.0
# Lowest ceiling above the stage centre: clears a radius-1 subject and forward camera planes.
_MIN_CEILING = 2.5
# Texture tiles of floors, walls and grounds span 0.2-2 units: coarser tiles blur up close at 200 pixels.
_SCENERY_TILE = 1.4
# How often each surrounding is drawn.
_KINDS, _KIND_P = ("room", "sky", "street"), (0.4, 0.35, 0.25)


@dataclass(frozen=True)
class Enclosure:
    """What surrounds the scene: kind ("room", "sky" or "street"), the x-y box of the room (or of the needed
    space) as ``center`` [2] and ``size`` [2], the floor and ceiling heights (inf: open sky), and ``limit``:
    how far from the origin cameras may go."""

    kind: str
    center: np.ndarray
    size: np.ndarray
    floor: float
    ceiling: float
    limit: float


def enclose(b: Builder, rng: np.random.Generator, floor: float, lo: np.ndarray, hi: np.ndarray) -> Enclosure:
    """Surround the scene with a room, an open sky or a street; ``lo``, ``hi`` [2]: the x-y box that must
    stay inside (subjects and cameras)."""
    kind = str(rng.choice(_KINDS, p=_KIND_P))
    if kind == "room":
        return _room(b, rng, floor, lo, hi)
    b.sky = sky_material(rng)
    b.add(Shape(geometry.ground_disc(GROUND_RADIUS, floor), smooth=False, kind="ground"), identity(), np.zeros(3),
          1.0, material=b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False)),
          casts_shadow=False)
    span = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
    if kind == "street":
        return _street(b, rng, floor, lo, hi)
    reach = float(min(rng.uniform(2.0, 4.0) * span, _MAX_SCENERY))
    for _ in range(int(rng.integers(3, 12))):  # distant scenery: hills, rocks, trees, blocks
        # Beyond the needed space when there is room; deep forward scenes mix scenery into their far part.
        angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(min(span * 1.1, 0.6 * reach), 0.8 * reach)
        b.stand(random_shape(rng), distance * np.array([np.cos(angle), np.sin(angle)]),
                float(rng.uniform(0.05, 0.2) * distance), floor)
    if rng.random() < 0.5:
        _distant_walls(b, rng, floor, int(rng.integers(1, 5)), 
                       min(max(span * 1.2, 0.3 * GROUND_RADIUS), 0.75 * GROUND_RADIUS))
    return Enclosure("sky", (lo + hi) / 2, hi - lo, floor, np.inf, span)


def _room(b: Builder, rng: np.random.Generator, floor: float, lo: np.ndarray, hi: np.ndarray) -> Enclosure:
    """Walls, floor and ceiling of a box around the needed space, with furniture along the walls."""
    center = (lo + hi) / 2
    size = (hi - lo) * rng.uniform(1.1, 1.6, 2)
    extents = np.array([*size, max(rng.uniform(0.35, 0.6) * size.max(), _MIN_CEILING - floor)])
    material = b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False))
    for name, mesh in geometry.room_faces(extents):
        mesh.apply_translation((center[0], center[1], floor))
        if name != "wall":  # floor and ceiling differ from the walls
            material = b.material(random_material(rng, tile_scale=_SCENERY_TILE, glossy=False))
        b.add(Shape(mesh, smooth=False, kind=name), identity(), np.zeros(3), 1.0, material=material,
              casts_shadow=False)
    for _ in range(int(rng.integers(2, 7))):  # furniture along the walls
        along = rng.uniform(-0.45, 0.45)
        spot = np.array([[0.47, along], [-0.47, along], [along, 0.47], [along, -0.47]])[rng.integers(4)]
        b.stand(random_shape(rng), center + spot * size, float(rng.uniform(0.05, 0.15) * size.min()), floor)
    _piers(b, rng, center, size, floor, extents[2], material)
    # Furniture reaches ~0.2 of the way in from the walls: cameras stay inside 0.7 of the nearest wall.
    limit = float(np.min(np.abs(np.concatenate([center - size / 2, center + size / 2]))) * 0.7)
    return Enclosure("room", center, size, floor, floor + extents[2], limit)


def _piers(b: Builder, rng: np.random.Generator, center: np.ndarray, size: np.ndarray, floor: float,
           height: float, wall: int) -> None:
    """0-4 piers, chimney breasts and built-in cabinets jutting 3-12% of the room into it from the walls:
    the walls stand at several depths, with inner corners and occlusion edges."""
    for _ in range(int(rng.integers(0, 5))):
        normal = int(rng.integers(2))  # the axis the wall faces along
        sign = float(rng.choice([-1.0, 1.0]))
        depth, width = rng.uniform(0.03, 0.12) * size[normal], rng.uniform(0.05, 0.25) * size[1 - normal]
        tall = height if rng.random() < 0.5 else height * rng.uniform(0.3, 0.8)
        middle, extents = np.zeros(3), np.zeros(3)
        middle[normal] = center[normal] + sign * (size[normal] / 2 - depth / 2)
        middle[1 - normal] = center[1 - normal] + rng.uniform(-0.4, 0.4) * size[1 - normal]
        middle[2] = floor + tall / 2
        extents[normal], extents[1 - normal], extents[2] = depth, width, tall
        same = rng.random() < 0.5  # plastered like the wall, or a cabinet of its own material
        _block(b, middle, extents, 0.0, wall if same else b.material(random_material(rng, glossy=False)), "pier",
               True)


def _facade_material(b: Builder, rng: np.random.Generator, size: float) -> int:
    """A matte material whose pattern stays visible on a wall ``size`` units wide seen from afar."""
    return b.material(random_material(rng, tile_scale=float(np.clip(size / 6, _SCENERY_TILE, 6.0)), glossy=False))


def _block(b: Builder, center: np.ndarray, extents: np.ndarray, yaw: float, material: int, kind: str,
           casts_shadow: bool = False) -> None:
    """A box [3] with its centre at ``center`` [3], turned by ``yaw`` about z."""
    rotation = Rotation.from_euler("z", yaw).as_matrix()
    b.add(Shape(geometry.trimesh_box(extents), smooth=False, kind=kind), rotation, center, 1.0, material=material,
          casts_shadow=casts_shadow)


def _distant_walls(b: Builder, rng: np.random.Generator, floor: float, count: int, nearest: float) -> None:
    """Textured walls (buildings, cliffs) far beyond the subject, facing the origin."""
    for _ in range(count):
        distance = float(rng.uniform(nearest, 0.85 * GROUND_RADIUS))
        angle = float(rng.uniform(0, 2 * np.pi))
        width, height = distance * rng.uniform(0.3, 0.9), distance * rng.uniform(0.08, 0.35)
        center = np.array([distance * np.cos(angle), distance * np.sin(angle), floor + height / 2])
        _block(b, center, np.array([0.04 * distance, width, height]), angle, _facade_material(b, rng, width),
               "distant-wall")


def _street(b: Builder, rng: np.random.Generator, floor: float, lo: np.ndarray, hi: np.ndarray) -> Enclosure:
    """Two rows of buildings of varied heights and setbacks along the longer side of the needed box, open to
    the sky; the street's far ends are open or closed by a distant wall."""
    axis = int(np.argmax(hi - lo)) if abs((hi - lo)[0] - (hi - lo)[1]) > 1e-6 else int(rng.integers(2))
    across = 1 - axis
    half = float(max(abs(lo[across]), abs(hi[across]))) * rng.uniform(1.1, 1.5)  # half-width of the street
    length = float(min(max(abs(lo[axis]), abs(hi[axis])) * rng.uniform(1.5, 3.0), 0.8 * GROUND_RADIUS))
    materials = [_facade_material(b, rng, 8.0) for _ in range(int(rng.integers(1, 4)))]
    for side in (-1.0, 1.0):
        start = -length
        while start < length:
            width = float(rng.uniform(0.15, 0.5) * half + 2.0)
            height = float(half * rng.uniform(0.6, 3.0))
            setback = float(rng.uniform(0.0, 0.3) * half) if rng.random() < 0.4 else 0.0
            depth = 2.0
            center = np.zeros(3)
            center[axis] = start + width / 2
            center[across] = side * (half + setback + depth / 2)
            center[2] = floor + height / 2
            extents = np.zeros(3)
            extents[axis], extents[across], extents[2] = width, depth, height
            # Facades shade the street: a canyon is half in shadow.
            _block(b, center, extents, 0.0, materials[int(rng.integers(len(materials)))], "building", True)
            start += width
    for end in (-1.0, 1.0):
        if rng.random() < 0.5:  # a building across the end of the street
            center, extents = np.zeros(3), np.zeros(3)
            height = float(half * rng.uniform(0.6, 3.0))
            center[axis], center[2] = end * (length + 1.0), floor + height / 2
            extents[axis], extents[across], extents[2] = 2.0, 2 * half + 4.0, height
            _block(b, center, extents, 0.0, materials[int(rng.integers(len(materials)))], "building")
    for _ in range(int(rng.integers(0, 6))):  # clutter along the facades: bins, posts, planters
        spot = np.zeros(2)
        spot[axis], spot[across] = rng.uniform(-0.6, 0.6) * length, rng.choice([-1.0, 1.0]) * 0.92 * half
        b.stand(random_shape(rng), spot, float(rng.uniform(0.02, 0.06) * half * 2), floor)
    return Enclosure("street", (lo + hi) / 2, hi - lo, floor, np.inf, 0.75 * half)


def scene_lights(rng: np.random.Generator, enclosure: Enclosure) -> list[Light]:
    """A sun (sky, street) or 1-3 point lights under the ceiling (room), plus maybe a weak fill light."""
    if enclosure.kind != "room":
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

