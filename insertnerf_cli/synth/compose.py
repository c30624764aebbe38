"""Random scene compositions for the four layouts: object, 360, forward and handheld.

* object: a cluster of shapes of radius ~1 at the origin on a plain (white, black, coloured) or textured
  background, sometimes on a base plate (like NeRF-Synthetic).
* 360: shapes standing on a ground in the middle of a room, an open sky or a street (like phone orbits); with
  supports, on a plinth, a pedestal or a table instead (like a sculpture on its stand).
* forward: shapes spread at many depths in front of a camera plane, with walls, buildings or sky behind
  (like LLFF captures).
* handheld: a subject among clutter at many depths, with thin structures and occluders, captured either
  forward-facing by hand (small baselines) or by a phone walking around it.
"""
from __future__ import annotations

import numpy as np

from insertnerf_cli.synth import geometry
from insertnerf_cli.synth.builder import Builder, cluster, identity, normalize
from insertnerf_cli.synth.drawing import flat_texture
from insertnerf_cli.synth.enclosures import enclose, scene_lights
from insertnerf_cli.synth.geometry import THIN, Shape
from insertnerf_cli.synth.world import (
    Material,
    Stage,
    World,
    random_material,
    random_rotation,
    random_shape,
    sun_light,
)

# Half-size of the x-y box that object and 360 cameras (at distance ~2.5-5 from a radius-1 subject) need.
_REACH = np.array([5.0, 5.0])


def _base_plate(b: Builder) -> None:
    """A thin slab under the cluster, its top at z = 0 (like the base of NeRF-Synthetic's lego)."""
    vertices = np.concatenate([o.world_vertices() for o in b.objects])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    thickness = 0.05 * float(np.ptp(vertices[:, :2], axis=0).max())
    extents = np.array([*(high[:2] - low[:2]) * b.rng.uniform(1.1, 1.4, 2), thickness])
    center = np.array([*(high[:2] + low[:2]) / 2, -thickness / 2])
    plate = Shape(geometry.trimesh_box(extents), smooth=False, kind="base-plate")
    b.add(plate, identity(), center, 1.0, material=b.material(random_material(b.rng)))


def _random_background(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    kind = str(rng.choice(["white", "black", "color", "textured"], p=[0.3, 0.2, 0.25, 0.25]))
    color = {"white": np.ones(3), "black": np.zeros(3)}.get(kind, rng.uniform(0.05, 0.95, 3))
    return kind, color


def compose_object(rng: np.random.Generator) -> World:
    """A NeRF-Synthetic-like subject of radius 1 at the origin, lit by 1-3 lights."""
    b = Builder(rng)
    on_plate = rng.random() < 0.3
    cluster(b, int(rng.integers(1, 6)), 0.0 if on_plate else None)
    if on_plate:
        _base_plate(b)
    lowest = normalize(b, 1.0)
    kind, background = _random_background(rng)
    stage = Stage(np.zeros(3), 1.0, lowest if on_plate else None)
    if kind == "textured":
        ground = lowest if on_plate else lowest - float(rng.uniform(0.0, 0.5))
        enclosure = enclose(b, rng, ground, -_REACH, _REACH)
        stage = Stage(np.zeros(3), 1.0, ground, enclosure.limit, ceiling=enclosure.ceiling)
    # A key light and up to two more; the third casts no shadow (cost: one batch of shadow rays per light).
    lights = [sun_light(rng, rng.uniform(0.6, 1.8), shadows=k < 2) for k in range(int(rng.integers(1, 4)))]
    return b.world(lights, stage, background,
                   ambient=float(rng.uniform(0.15, 0.5)), layout="object", surroundings=kind, plate=on_plate)


def compose_360(rng: np.random.Generator, supports: bool = False) -> World:
    """Subjects of radius ~1 standing on a floor at the origin, inside a room or under a sky; with ``supports``,
    standing on a plinth, a pedestal or a table whose foot is on the floor (support)."""
    b = Builder(rng)
    cluster(b, int(rng.integers(1, 6)), 0.0)
    floor = normalize(b, 1.0)
    extra = {}
    if supports:
        floor, extra["support"] = support(b, floor)
    enclosure = enclose(b, rng, floor, -_REACH, _REACH)
    stage = Stage(np.zeros(3), 1.0, floor, enclosure.limit, ceiling=enclosure.ceiling)
    return b.world(scene_lights(rng, enclosure), stage, np.zeros(3),
                   ambient=float(rng.uniform(0.15, 0.4)), layout="360", surroundings=enclosure.kind, **extra)


def support(b: Builder, top: float) -> tuple[float, str]:
    """A support under the subject placed so far, its top at z = ``top``: a plinth (a box), a round pedestal or a
    table (a top on four legs), 0.5-1.3 subject radii high; half of them plain white or light grey, like a
    sculpture's stand, a surface SfM finds few points on. Returns the height of its foot (the floor) and its kind.
    """
    rng = b.rng
    vertices = np.concatenate([o.world_vertices() for o in b.objects])
    footprint = float(np.abs(vertices[:, :2]).max())  # the subject's half-width about the origin
    height = float(rng.uniform(0.5, 1.3))
    kind = str(rng.choice(["plinth", "pedestal", "table"]))
    if rng.random() < 0.5:
        material = b.material(Material(texture=flat_texture(np.full(3, rng.uniform(0.75, 0.95))), tile=1.0,
                                       specular=float(rng.uniform(0.0, 0.1)), name="plain"))
    else:
        material = b.material(random_material(rng, glossy=False))

    def place(mesh, center: list[float], name: str, smooth: bool = False) -> None:
        b.add(Shape(mesh, smooth=smooth, kind=name), identity(), np.array(center), 1.0, material=material)

    def block(extents: list[float], center: list[float], name: str) -> None:
        place(geometry.trimesh_box(np.array(extents)), center, name)

    if kind == "plinth":
        half = footprint * float(rng.uniform(0.6, 1.1))
        block([2 * half, 2 * half, height], [0.0, 0.0, top - height / 2], "support-plinth")
    elif kind == "pedestal":
        radius = footprint * float(rng.uniform(0.4, 0.8))
        place(geometry.cylinder_mesh(radius, height), [0.0, 0.0, top - height / 2], "support-pedestal", smooth=True)
    else:
        width, depth = footprint * float(rng.uniform(1.2, 1.8)), footprint * float(rng.uniform(0.9, 1.4))
        slab, leg = 0.08 * height, 0.06 * footprint + 0.04
        block([2 * width, 2 * depth, slab], [0.0, 0.0, top - slab / 2], "support-table")
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                block([leg, leg, height - slab],
                      [sx * (width - leg), sy * (depth - leg), top - slab - (height - slab) / 2], "support-table-leg")
    return top - height, kind


def _spread(b: Builder, count: int, near: float, deep: float, floor: float) -> None:
    """``count`` shapes at depths from ``near`` to ``deep`` along +y, denser near the camera, filling the
    frame sideways; most stand on the floor, some float (hanging lamps, branches, signs)."""
    rng = b.rng
    for _ in range(count):
        depth = float(near + (deep - near) * rng.random() ** 1.5)
        scale = float(depth * rng.uniform(0.08, 0.3))
        x = depth * rng.uniform(-0.6, 0.6)
        if rng.random() < 0.6:
            b.stand(random_shape(rng), np.array([x, depth + scale]), scale, floor, upright=rng.random() < 0.7)
        else:
            b.add(random_shape(rng), random_rotation(rng, False),
                  np.array([x, depth + scale, floor + depth * rng.uniform(0.1, 0.5)]), scale)


def _thin_and_occluders(b: Builder, near: float, floor: float) -> list[str]:
    """Maybe a fence or railing across the view, and maybe a thin occluder (leaves, rods) at the side of the
    frame between the camera plane and the subject at depth ``near``; returns what was added."""
    rng, added = b.rng, []
    if rng.random() < 0.35:
        depth = float(near * rng.uniform(0.5, 2.5))
        b.stand(geometry.fence(rng), np.array([depth * rng.uniform(-0.3, 0.3), depth]),
                float(depth * rng.uniform(0.8, 1.6)), floor, upright=True)
        added.append("fence")
    if rng.random() < 0.4:
        depth = float(near * rng.uniform(0.3, 0.6))
        kind = str(rng.choice(["plant", "rods"]))
        height = floor + depth * rng.uniform(0.0, 0.6)
        b.add(THIN[kind](rng), random_rotation(rng, False),
              np.array([depth * rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.45), depth, height]),
              float(depth * rng.uniform(0.3, 0.6)))
        added.append(f"occluder-{kind}")
    return added


def compose_forward(rng: np.random.Generator) -> World:
    """Shapes at depths from ``near`` to ``deep`` along +y in front of a camera plane at the origin."""
    b = Builder(rng)
    near = float(rng.uniform(1.5, 3.0))
    deep = float(near * rng.uniform(3.0, 8.0))
    floor = -float(rng.uniform(0.8, 2.0))
    _spread(b, int(rng.integers(4, 14)), near, deep, floor)
    extras = _thin_and_occluders(b, near, floor)
    enclosure = enclose(b, rng, floor, np.array([-0.7 * deep, -1.0]), np.array([0.7 * deep, 1.3 * deep]))
    return b.world(scene_lights(rng, enclosure), Stage(np.zeros(3), deep, floor, depth=near), np.zeros(3),
                   ambient=float(rng.uniform(0.15, 0.4)), layout="forward", surroundings=enclosure.kind,
                   extras=extras)


def compose_handheld(rng: np.random.Generator) -> World:
    """A subject of radius 1 among clutter, captured by hand: forward-facing ("grid": the subject 2.5-6 units
    ahead along +y, clutter, fences and occluders at many depths, a deep background) or by a phone walking
    around it ("orbit": clutter on the floor around it)."""
    b = Builder(rng)
    cluster(b, int(rng.integers(1, 6)), 0.0)
    lowest = normalize(b, 1.0)
    if rng.random() < 0.6:
        distance, above = float(rng.uniform(2.5, 6.0)), float(rng.uniform(0.0, 0.8))
        b.shift(np.array([0.0, distance, 0.0]))  # the subject's centre at (0, distance, 0)
        floor, deep = lowest, min(distance * float(rng.uniform(2.5, 6.0)), 24.0)  # forward's deepest
        _spread(b, int(rng.integers(3, 16)), 0.5 * distance, deep, floor)
        extras = _thin_and_occluders(b, distance, floor)
        enclosure = enclose(b, rng, floor, np.array([-0.7 * deep, -1.0]), np.array([0.7 * deep, 1.3 * deep]))
        # Cameras a little above the subject's centre, looking slightly down at it.
        stage = Stage(np.array([0.0, 0.0, above]), deep, floor, depth=distance, style="grid")
    else:
        for _ in range(int(rng.integers(2, 9))):  # clutter on the floor around the subject, outside the orbit
            angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(5.5, 8.0)
            b.stand(random_shape(rng), distance * np.array([np.cos(angle), np.sin(angle)]),
                    float(rng.uniform(0.3, 1.2)), lowest, upright=rng.random() < 0.7)
        extras = []
        floor = lowest
        enclosure = enclose(b, rng, floor, -1.8 * _REACH, 1.8 * _REACH)
        stage = Stage(np.zeros(3), 1.0, floor, min(enclosure.limit, 5.0), ceiling=enclosure.ceiling, style="orbit")
    return b.world(scene_lights(rng, enclosure), stage, np.zeros(3), ambient=float(rng.uniform(0.15, 0.4)),
                   layout="handheld", rig=stage.style, surroundings=enclosure.kind, extras=extras)


COMPOSERS = {"object": compose_object, "360": compose_360, "forward": compose_forward, "handheld": compose_handheld}
