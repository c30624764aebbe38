"""Surface colour at ray hits: textures mapped in object space, Lambert + Blinn-Phong lights with cast
shadows (one batch of shadow rays per light), a sky/ground ambient term, one-bounce mirror reflections on
coated materials, and the unlit sky at infinity.

Radiance is linear RGB in units where a white Lambertian surface facing a light of colour 1 has radiance 1
(the 1/pi of the BRDF is folded into the light colours).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insertnerf_cli.synth.raycast import Hits, SceneMesh, cast
from insertnerf_cli.synth.textures import sample, srgb_to_linear
from insertnerf_cli.synth.world import Light, Material, World

# Triplanar blend sharpness: higher gives narrower transitions between the three projections.
_BLEND_POWER = 4.0
# Projections with a smaller blend weight are skipped (saves texture lookups on flat faces).
_MIN_WEIGHT = 0.02
# Shadow-ray origins move off the surface by this fraction of the shadow casters' size (float32 embree).
_SHADOW_OFFSET = 1e-4
# Grazing views stretch a pixel's footprint by 1/cos; cap the stretch so distant floors stay detailed.
_MIN_COS = 0.25


def shade(scene: SceneMesh, world: World, hits: Hits, directions: np.ndarray, focal: float,
          reflections: bool = True) -> np.ndarray:
    """Radiance [H, 3] of hits seen along ray directions [H, 3] (camera-z = 1) by a camera of focal length
    ``focal`` pixels; ``reflections=False`` leaves mirror coats out (the bounce of a reflection)."""
    if len(hits.t) == 0:
        return np.zeros((0, 3), dtype=np.float32)
    view = -directions / _norm(directions)[:, None]  # [H, 3] toward the camera
    cos_view = np.maximum(np.einsum("hc,hc->h", hits.normals, view), _MIN_COS)
    footprint = hits.t / focal / cos_view  # [H] world size of one pixel on the surface
    material_of = scene.object_material[hits.objects]  # [H]
    local, weights = _object_frame(scene, hits)
    albedo = np.zeros((len(hits.t), 3), dtype=np.float32)
    order = np.argsort(material_of, kind="stable")  # hits grouped by material: one slice each
    starts = np.searchsorted(material_of[order], np.arange(len(world.materials) + 1))
    for m, material in enumerate(world.materials):
        sel = order[starts[m]:starts[m + 1]]
        if len(sel) == 0:
            continue
        albedo[sel] = _triplanar(material, local[sel], weights[sel], footprint[sel])
    surface = Surface(albedo, *(np.array([getattr(mat, key) for mat in world.materials])[material_of]
                                for key in ("specular", "shininess", "metallic")))
    radiance = _lit(scene, world, surface, hits, np.arange(len(hits.t)), view)
    mirror = np.array([mat.mirror for mat in world.materials])[material_of]
    coated = np.flatnonzero(mirror > 0) if reflections else np.zeros(0, dtype=np.int64)
    if len(coated):
        cos = np.clip(np.einsum("hc,hc->h", hits.normals[coated], view[coated]), 0.0, 1.0)
        fresnel = (mirror[coated] + (1 - mirror[coated]) * (1 - cos) ** 5)[:, None]
        metallic = surface.metallic[coated, None]
        tint = (1 - metallic) + metallic * albedo[coated]
        reflected = _reflected(scene, world, hits, coated, view[coated], focal)
        radiance[coated] = (1 - fresnel) * radiance[coated] + fresnel * tint * reflected
    return radiance


def _reflected(scene: SceneMesh, world: World, hits: Hits, sel: np.ndarray, view: np.ndarray, focal: float
               ) -> np.ndarray:
    """Radiance [S, 3] arriving at hits ``sel`` along the mirror direction of ``view`` [S, 3] (one bounce:
    the surface hit there is shaded without reflections; rays that leave the scene see the sky)."""
    normals = hits.normals[sel]
    mirrored = 2 * np.einsum("sc,sc->s", normals, view)[:, None] * normals - view
    origins = hits.points[sel] + hits.geometric[sel] * _SHADOW_OFFSET * scene.shadow_extent
    second = cast(scene, origins, mirrored)
    out = np.empty((len(sel), 3), dtype=np.float32)
    missed = np.ones(len(sel), dtype=bool)
    missed[second.ray] = False
    out[missed] = srgb_to_linear(world.background) if world.sky is None else \
        sky_radiance(world.sky, mirrored[missed], focal)
    out[second.ray] = shade(scene, world, second, mirrored[second.ray], focal, reflections=False)
    return out


@dataclass(frozen=True)
class Surface:
    """Per-hit material values of S lit hits: albedo [S, 3]; specular, shininess, metallic [S]."""

    albedo: np.ndarray
    specular: np.ndarray
    shininess: np.ndarray
    metallic: np.ndarray


def _object_frame(scene: SceneMesh, hits: Hits) -> tuple[np.ndarray, np.ndarray]:
    """Hit points in their object's frame [H, 3] and triplanar blend weights [H, 3] (rows sum to 1).

    Object frame in world units, R^T (x - t): the texture moves with the object but keeps its world scale.
    """
    rotations = scene.object_rotation[hits.objects]  # [H, 3, 3]
    local = np.einsum("hji,hj->hi", rotations, hits.points - scene.object_translation[hits.objects])
    normal = np.einsum("hji,hj->hi", rotations, hits.normals).astype(np.float32)
    weights = (normal * normal) ** (_BLEND_POWER / 2)
    weights /= weights @ np.ones((3, 1), dtype=np.float32)
    weights[weights < _MIN_WEIGHT] = 0.0
    weights /= weights @ np.ones((3, 1), dtype=np.float32)
    return local, weights


# The two object axes each planar projection keeps: x-projection uses (y, z), and so on.
_PLANE_AXES = ((1, 2), (0, 2), (0, 1))


def _triplanar(material: Material, local: np.ndarray, weights: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """Albedo [S, 3]: three planar projections of points ``local`` [S, 3] blended by ``weights`` [S, 3]."""
    albedo = np.zeros((len(local), 3), dtype=np.float32)
    for axis, keep in enumerate(_PLANE_AXES):
        use = np.flatnonzero(weights[:, axis] > 0)
        if len(use) == 0:
            continue
        uv = local[use][:, keep] / material.tile
        color = sample(material.texture, uv, footprint[use] / material.tile)
        if material.macro is not None:
            ratio = material.tile / material.macro_tile
            variation = sample(material.macro, uv * ratio, footprint[use] / material.macro_tile)
            color *= 1.0 + material.macro_strength * (2.0 * variation - 1.0)
        albedo[use] += weights[use, axis, None] * color
    return albedo


def sky_radiance(material: Material, directions: np.ndarray, focal: float) -> np.ndarray:
    """Colour [S, 3] of the sky at infinity along ray directions [S, 3] (camera-z = 1) of a camera of focal
    length ``focal`` pixels: u = azimuth, v = elevation above the horizon (below it: the horizon's colour)."""
    length = _norm(directions)
    direction = directions / length[:, None]
    azimuth = np.arctan2(direction[:, 1], direction[:, 0]) / (2 * np.pi)
    elevation = np.clip(np.arcsin(np.clip(direction[:, 2], -1, 1)) / (np.pi / 2), 0.0, 0.999)
    uv = np.stack([azimuth * material.tile, elevation], axis=1)
    angle = 1.0 / (focal * length)  # angle one pixel spans, radians
    return sample(material.texture, uv, angle * material.tile / (2 * np.pi))


def _lit(scene: SceneMesh, world: World, surface: Surface, hits: Hits, sel: np.ndarray, view: np.ndarray
         ) -> np.ndarray:
    """Ambient + sum over lights of shadowed Lambert and Blinn-Phong terms, [S, 3]; one batch of shadow
    rays per light. Whole-array float32 arithmetic with 0/1 visibility is faster than gathering subsets."""
    f32 = np.float32
    normals, points = hits.normals[sel].astype(f32), hits.points[sel]
    albedo, view = surface.albedo.astype(f32), view.astype(f32)
    up = 0.5 + 0.5 * normals[:, 2:3]
    radiance = albedo * (world.ambient_ground.astype(f32) * (1 - up) + world.ambient_sky.astype(f32) * up)
    metallic = surface.metallic.astype(f32)[:, None]
    highlight = (1 - metallic) + metallic * albedo  # [S, 3]
    # (s + 8) / 8 keeps the lobe's energy roughly constant as it narrows.
    strength = (surface.specular * (surface.shininess + 8) / 8).astype(f32)
    shininess = surface.shininess.astype(f32)
    # cos(n, h) below which the lobe is under 1e-3 of its peak: skipping those saves most of the powers.
    cutoff = np.exp(np.log(f32(1e-3)) / shininess)
    origins = points + hits.geometric[sel] * _SHADOW_OFFSET * scene.shadow_extent
    for light in world.lights:
        to_light, irradiance = _light_at(light, points)
        # One direction for all points of a directional light: a matrix-vector product.
        cos = normals @ to_light[0] if light.kind == "directional" else np.einsum("sc,sc->s", normals, to_light)
        facing = np.flatnonzero(cos > 0)
        weight = np.zeros(len(cos), dtype=f32)
        visible = facing[_unblocked(scene, light, origins[facing], to_light[facing])]
        weight[visible] = cos[visible] * irradiance[visible, 0]
        half = to_light + view
        half /= np.maximum(_norm(half), f32(1e-12))[:, None]
        n_h = np.einsum("sc,sc->s", normals, half)
        lobe = np.zeros(len(n_h), dtype=f32)
        peak = np.flatnonzero((n_h > cutoff) & (weight > 0))
        lobe[peak] = strength[peak] * np.exp(shininess[peak] * np.log(n_h[peak]))
        radiance += (albedo + highlight * lobe[:, None]) * (weight[:, None] * light.color.astype(f32))
    return radiance


def _light_at(light: Light, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions toward the light [S, 3] (float32) and irradiance scale [S, 1] (inverse square for
    points)."""
    if light.kind == "directional":
        direction = (light.vector / np.linalg.norm(light.vector)).astype(np.float32)
        return np.broadcast_to(direction, points.shape), np.ones((len(points), 1), dtype=np.float32)
    offset = light.vector - points
    distance2 = np.maximum(np.einsum("sc,sc->s", offset, offset), 1e-12)[:, None]
    return (offset / np.sqrt(distance2)).astype(np.float32), (1.0 / distance2).astype(np.float32)


def _unblocked(scene: SceneMesh, light: Light, origins: np.ndarray, to_light: np.ndarray) -> np.ndarray:
    """[L] True where the shadow ray from ``origins`` toward the light reaches it (one embree batch)."""
    if not light.shadows or scene.shadow_caster is None or len(origins) == 0:
        return np.ones(len(origins), dtype=bool)
    distance = _norm(light.vector - origins) if light.kind == "point" else None
    return ~scene.shadow_caster.occluded(origins, to_light, distance)


def _norm(vectors: np.ndarray) -> np.ndarray:
    """Lengths [N] of vectors [N, 3] (einsum: much faster than a reduction over a length-3 axis)."""
    return np.sqrt(np.einsum("nc,nc->n", vectors, vectors))
