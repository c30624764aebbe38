"""The description of one synthetic scene: placed shapes, materials, lights and the camera stage.

A :class:`World` is pure data drawn from a random generator by compose.py; render.py turns it into one
ray-casting mesh. World axes: z up (as Blender), units such that object-layout subjects have radius ~1.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from insertnerf_cli.synth.drawing import random_texture, sky_image
from insertnerf_cli.synth.geometry import PRIMITIVES, THIN, Shape, deformed
from insertnerf_cli.synth.implicit import implicit_shape
from insertnerf_cli.synth.textures import Texture, fbm, srgb_to_linear

Mapping = Literal["triplanar", "sky"]
LightKind = Literal["directional", "point"]


@dataclass(frozen=True)
class Material:
    """Surface appearance.

    Attributes:
        texture: linear-RGB albedo pyramid.
        tile: world units covered by one texture tile.
        specular: strength of the Blinn-Phong highlight (0 = matte).
        shininess: Blinn-Phong exponent (larger = tighter highlight).
        metallic: 0 gives white highlights, 1 highlights tinted by the albedo.
        mapping: "triplanar" in object space, or "sky": by direction, unlit (emissive).
        name: short description for the scene record.
        mirror: Fresnel reflectance at normal incidence of a mirror-like coat (0 = none): lacquer, glaze
            and plastics ~0.03-0.12, polished metal 0.5-0.9 (tinted by the albedo when metallic); the
            reflection grows toward grazing angles (Schlick) and shows the scene itself (one bounce).
        macro: optional grey variation [0, 1] multiplied over large surfaces, with its own tile size
            ``macro_tile`` and ``macro_strength``: breaks the visible repetition of a tiled floor or wall.
    """

    texture: Texture
    tile: float
    specular: float = 0.0
    shininess: float = 20.0
    metallic: float = 0.0
    mapping: Mapping = "triplanar"
    name: str = ""
    mirror: float = 0.0
    macro: Texture | None = None
    macro_tile: float = 1.0
    macro_strength: float = 0.0


@dataclass(frozen=True)
class Placed:
    """A shape placed in the world: x_world = scale * rotation @ x_object + translation.

    Attributes:
        casts_shadow: False for enclosures (sky, room walls) that would block every shadow ray.
    """

    shape: Shape
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]
    scale: float
    material: int
    casts_shadow: bool = True

    def world_vertices(self) -> np.ndarray:
        """[P, 3] vertices in world coordinates."""
        return self.scale * self.shape.mesh.vertices @ self.rotation.T + self.translation


@dataclass(frozen=True)
class Light:
    """A directional light (``vector`` points toward the light) or a point light (``vector`` = position).

    ``color`` is linear RGB irradiance on a surface facing the light (at distance 1 for point lights).
    ``shadows``: cast shadow rays; weak fill lights skip them (their real shadows are soft and faint).
    """

    kind: LightKind
    vector: np.ndarray  # [3]
    color: np.ndarray  # [3]
    shadows: bool = True


@dataclass(frozen=True)
class Stage:
    """Where cameras may go, for layouts.py.

    Attributes:
        center: [3] point the cameras look at (object and 360) or the centre of the camera plane (forward).
        radius: bounding radius of the subject around ``center``.
        ground: height of the ground plane, or None when there is none.
        limit: cameras stay within this distance of ``center`` (inside the room or sky dome, clear of the
            furniture and scenery along its edge).
        ceiling: cameras stay below this height (a room's ceiling).
        depth: forward layout: distance from the camera plane to the nearest subject geometry; handheld
            layout: distance from the camera plane to the subject.
        style: handheld layout: "grid" (forward-facing, hand-held) or "orbit" (a phone walking around).
    """

    center: np.ndarray
    radius: float
    ground: float | None = None
    limit: float = np.inf
    ceiling: float = np.inf
    depth: float = 0.0
    style: str = ""


@dataclass(frozen=True)
class World:
    """Everything the renderer needs about one scene.

    Attributes:
        background: sRGB colour [3] for rays that hit nothing (enclosed worlds never show it).
        ambient_sky, ambient_ground: linear RGB ambient light from above and from below.
        description: what was drawn, for the scene record (JSON-ready).
        sky: environment at infinity, looked up by ray direction, for rays that leave the scene (None: they
            show ``background``). Either way such pixels have no surface: depth 0.
    """

    objects: tuple[Placed, ...]
    materials: tuple[Material, ...]
    lights: tuple[Light, ...]
    stage: Stage
    background: np.ndarray
    ambient_sky: np.ndarray
    ambient_ground: np.ndarray
    description: dict = field(default_factory=dict)
    sky: Material | None = None


# ---------------------------------------------------------------------------------------------- random parts
def random_shape(rng: np.random.Generator) -> Shape:
    """A subject shape: primitive (25%), deformed primitive (25%), implicit (30%) or thin structure (20%)."""
    group = rng.choice(4, p=[0.25, 0.25, 0.3, 0.2])
    if group == 0:
        return PRIMITIVES[str(rng.choice(list(PRIMITIVES)))](rng)
    if group == 1:
        return deformed(rng)
    if group == 2:
        return implicit_shape(rng)
    return THIN[str(rng.choice(list(THIN)))](rng)


# Pixels per side of the macro-variation texture: it only carries low frequencies.
_MACRO_SIZE = 64


def random_material(rng: np.random.Generator, tile_scale: float = 1.0, glossy: bool = True) -> Material:
    """A textured material with a random specular lobe; ``tile_scale`` scales the texture's world size.

    ``glossy=False`` (floors, walls, ground) keeps a faint sheen only: a strong lobe on a large plane turns
    whole floors white, and matte dielectrics reflect a few percent.
    """
    texture, name = random_texture(rng)
    shiny = rng.random() < 0.5
    specular = float(rng.uniform(0.05, 0.6)) if shiny else float(rng.uniform(0.0, 0.05))
    tile = tile_scale * float(np.exp(rng.uniform(np.log(0.15), np.log(1.5))))
    material = Material(texture=texture, tile=tile, specular=specular if glossy else min(specular, 0.03),
                        shininess=float(np.exp(rng.uniform(np.log(5), np.log(300)))),
                        metallic=float(rng.random() < 0.2), name=name)
    if glossy:
        if rng.random() < 0.25:  # a polished or varnished coat that mirrors its surroundings
            coat = rng.uniform(0.5, 0.9) if material.metallic else rng.uniform(0.03, 0.12)
            material = replace(material, mirror=float(coat), name=f"{name}+mirror")
        return material
    # A non-integer ratio of tile sizes, so the two patterns never line up again.
    macro = Texture.from_image(np.repeat(fbm(rng, _MACRO_SIZE)[..., None], 3, axis=2))
    return replace(material, macro=macro, macro_tile=tile * float(rng.uniform(4.3, 9.7)),
                   macro_strength=float(rng.uniform(0.2, 0.6)))


def sky_material(rng: np.random.Generator) -> Material:
    image = sky_image(rng)
    return Material(texture=Texture.from_image(srgb_to_linear(image)), tile=float(rng.integers(1, 3)),
                    mapping="sky", name="sky")


def random_rotation(rng: np.random.Generator, upright: bool) -> np.ndarray:
    """[3, 3]: a rotation about z only (objects standing on a floor) or uniformly random."""
    if upright:
        return Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)).as_matrix()
    quat = rng.normal(size=4)  # a normalised Gaussian 4-vector is a uniform rotation
    return Rotation.from_quat(quat / np.linalg.norm(quat)).as_matrix()


def sun_light(rng: np.random.Generator, strength: float, shadows: bool = True) -> Light:
    """A directional light from a random direction above the horizon, warm to cool white."""
    azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(15), np.radians(75))
    direction = np.array([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
    return Light("directional", direction, strength * light_tint(rng), shadows)


def light_tint(rng: np.random.Generator) -> np.ndarray:
    """Linear RGB of unit luminance-ish: near white, between warm (tungsten) and cool (shade)."""
    warmth = rng.uniform(-1, 1) * 0.25
    return np.array([1.0 + warmth, 1.0, 1.0 - warmth])


def ambient_pair(rng: np.random.Generator, strength: float) -> tuple[np.ndarray, np.ndarray]:
    """Ambient light from the sky side and from the ground side (linear RGB)."""
    sky = strength * light_tint(rng) * np.array([0.9, 0.95, 1.1])
    return sky, sky * rng.uniform(0.3, 0.7)


def exposed(world: World, factor: float) -> World:
    """The same world with every light and the ambient term scaled by ``factor`` (skies are unlit)."""
    lights = tuple(replace(light, color=light.color * factor) for light in world.lights)
    return replace(world, lights=lights, ambient_sky=world.ambient_sky * factor,
                   ambient_ground=world.ambient_ground * factor)
