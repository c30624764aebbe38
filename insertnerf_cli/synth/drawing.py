"""OpenCV-drawn overlays (lines, shapes, glyphs) and the layering of patterns into one texture image."""
from __future__ import annotations

import string

import cv2
import numpy as np

from insertnerf_cli.synth.natural import natural_texture
from insertnerf_cli.synth.textures import PATTERNS, SIZE, Texture, colorize, fbm, palette, random_color, srgb_to_linear

_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX,
          cv2.FONT_HERSHEY_SCRIPT_SIMPLEX, cv2.FONT_HERSHEY_PLAIN, cv2.FONT_ITALIC | cv2.FONT_HERSHEY_COMPLEX)
_GLYPHS = string.ascii_letters + string.digits + "#&%@+=?"


def _tiled(draw_one, size: int) -> None:
    """Call ``draw_one(dx, dy)`` at the 9 tile offsets so shapes crossing an edge wrap around."""
    for dx in (-size, 0, size):
        for dy in (-size, 0, size):
            draw_one(dx, dy)


def draw_overlay(rng: np.random.Generator, image: np.ndarray) -> np.ndarray:
    """Draw random lines, circles, rectangles, polygons, ellipses or text onto an sRGB image [S, S, 3] (copy)."""
    canvas = np.ascontiguousarray((image * 255).astype(np.uint8))
    size = canvas.shape[0]
    style = str(rng.choice(["lines", "shapes", "glyphs", "mixed"]))
    count = int(rng.integers(3, 25))
    colors = palette(rng, 3)
    for _ in range(count):
        color = tuple(int(c) for c in (colors[rng.integers(len(colors))] * 255))
        kind = style if style != "mixed" else str(rng.choice(["lines", "shapes", "glyphs"]))
        if kind == "lines":
            _line(rng, canvas, color, size)
        elif kind == "shapes":
            _shape(rng, canvas, color, size)
        else:
            _glyphs(rng, canvas, color, size)
    return canvas.astype(np.float64) / 255


def _line(rng: np.random.Generator, canvas: np.ndarray, color: tuple, size: int) -> None:
    p0 = rng.integers(0, size, 2)
    p1 = p0 + rng.integers(-size // 2, size // 2, 2)
    width = int(rng.integers(1, 8))
    _tiled(lambda dx, dy: cv2.line(canvas, (int(p0[0] + dx), int(p0[1] + dy)), (int(p1[0] + dx), int(p1[1] + dy)),
                                   color, width, cv2.LINE_AA), size)


def _shape(rng: np.random.Generator, canvas: np.ndarray, color: tuple, size: int) -> None:
    center = rng.integers(0, size, 2)
    radius = int(rng.integers(4, size // 4))
    thickness = -1 if rng.random() < 0.6 else int(rng.integers(1, 6))
    kind = rng.integers(4)
    if kind == 0:
        draw = lambda dx, dy: cv2.circle(canvas, (int(center[0] + dx), int(center[1] + dy)), radius, color,
                                         thickness, cv2.LINE_AA)
    elif kind == 1:
        half = rng.integers(3, size // 4, 2)
        draw = lambda dx, dy: cv2.rectangle(canvas, (int(center[0] - half[0] + dx), int(center[1] - half[1] + dy)),
                                            (int(center[0] + half[0] + dx), int(center[1] + half[1] + dy)), color,
                                            thickness, cv2.LINE_AA)
    elif kind == 2:
        axes = (radius, int(rng.integers(2, radius + 1)))
        angle = float(rng.uniform(0, 180))
        draw = lambda dx, dy: cv2.ellipse(canvas, (int(center[0] + dx), int(center[1] + dy)), axes, angle, 0, 360,
                                          color, thickness, cv2.LINE_AA)
    else:
        points = (center + rng.integers(-radius, radius + 1, (int(rng.integers(3, 7)), 2))).astype(np.int32)
        draw = lambda dx, dy: cv2.fillPoly(canvas, [points + np.array([dx, dy], dtype=np.int32)], color,
                                           cv2.LINE_AA)
    _tiled(draw, size)


def _glyphs(rng: np.random.Generator, canvas: np.ndarray, color: tuple, size: int) -> None:
    text = "".join(rng.choice(list(_GLYPHS), size=int(rng.integers(1, 7))))
    font = int(_FONTS[rng.integers(len(_FONTS))])
    scale = float(rng.uniform(0.4, 2.5))
    thickness = int(rng.integers(1, 4))
    origin = rng.integers(0, size, 2)
    _tiled(lambda dx, dy: cv2.putText(canvas, text, (int(origin[0] + dx), int(origin[1] + dy)), font, scale, color,
                                      thickness, cv2.LINE_AA), size)


# ---------------------------------------------------------------------------------------------- composition
def texture_image(rng: np.random.Generator, size: int = SIZE) -> tuple[np.ndarray, str]:
    """A layered sRGB texture [S, S, 3]: a coloured base pattern, maybe a second pattern through a mask,
    maybe drawn overlays, and a low-contrast noise modulation (dirt, shading variation)."""
    kind = str(rng.choice(list(PATTERNS), p=[0.35, 0.15, 0.15, 0.2, 0.15]))
    image = colorize(PATTERNS[kind](rng, size), palette(rng, int(rng.integers(2, 5))))
    name = kind
    if rng.random() < 0.35:
        other = str(rng.choice(list(PATTERNS)))
        mask = PATTERNS[str(rng.choice(list(PATTERNS)))](rng, size)[..., None]
        image = image * (1 - mask) + colorize(PATTERNS[other](rng, size), palette(rng, 2)) * mask
        name += f"+{other}"
    if rng.random() < 0.3:
        image = draw_overlay(rng, image)
        name += "+drawn"
    dirt = rng.uniform(0.0, 0.35)
    image = image * (1 - dirt * fbm(rng, size)[..., None])
    return np.clip(image, 0.0, 1.0), name


def flat_texture(rgb: np.ndarray) -> Texture:
    """A single-colour texture from an sRGB colour [3]."""
    return Texture.from_image(np.broadcast_to(srgb_to_linear(np.asarray(rgb))[None, None], (8, 8, 3)).copy())


def random_texture(rng: np.random.Generator, size: int = SIZE) -> tuple[Texture, str]:
    """A random texture (linear RGB mip pyramid) and a short description: 10% plain colours, 40% with the
    statistics of photographs (natural.py), 50% layered patterns."""
    draw = rng.random()
    if draw < 0.1:
        return flat_texture(random_color(rng)), "flat"
    image, name = natural_texture(rng, size) if draw < 0.5 else texture_image(rng, size)
    return Texture.from_image(srgb_to_linear(image)), name


def sky_image(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """An equirectangular sky [S, S, 3] in sRGB: rows go from the horizon (row 0) to the zenith, with clouds."""
    horizon = random_color(rng, hue=rng.uniform(0.5, 0.7) if rng.random() < 0.7 else None)
    horizon = 0.5 * horizon + 0.5 * np.array([0.95, 0.95, 0.95])
    zenith = np.array([0.25, 0.45, 0.85]) * rng.uniform(0.5, 1.1) if rng.random() < 0.7 else random_color(rng)
    rows = np.linspace(0, 1, size)[:, None, None] ** rng.uniform(0.4, 1.2)
    sky = horizon * (1 - rows) + np.clip(zenith, 0, 1) * rows
    sky = np.broadcast_to(sky, (size, size, 3))
    clouds = np.clip((fbm(rng, size) - rng.uniform(0.3, 0.8)) * 3, 0, 1)[..., None] * rng.uniform(0.0, 1.0)
    return np.clip(sky * (1 - clouds) + clouds * rng.uniform(0.75, 1.0), 0, 1)
