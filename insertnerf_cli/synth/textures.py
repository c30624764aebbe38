"""Procedural tileable 2D textures, prefiltered into mip levels and sampled per hit point.

Patterns (spectral fBm noise, stripes, checkers and bricks, Voronoi cells, periodic gradients, and
OpenCV-drawn lines, shapes and glyphs) are scalar fields on the unit torus, coloured through a random
palette and layered. Every pattern tiles, so triplanar mapping in object space shows no seams.
Textures are stored in linear RGB; :func:`sample` picks a mip level from each point's pixel footprint so
that distant surfaces do not alias.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

# Texture resolution (pixels per tile side) of the finest mip level.
SIZE = 256
# Coarsest mip level, in pixels per side: 1 is the mean colour that a pixel covering many tiles sees.
_MIN_LEVEL = 1


@dataclass(frozen=True)
class Texture:
    """A mip pyramid of one tileable texture, packed side by side in one atlas.

    Each level is stored with a one-texel border copied from its opposite edge, so bilinear taps at a
    tile's edge wrap around without leaving the level.

    Attributes:
        atlas: [SIZE + 2, sum(sizes + 2), 3] float32 linear RGB; level l (with its border) occupies columns
            offsets[l]:offsets[l] + sizes[l] + 2 of its first sizes[l] + 2 rows.
        offsets, sizes: [L] int column offset and side length (without border) of each level.
    """

    atlas: np.ndarray  # [S + 2, sum(sizes + 2), 3]
    offsets: np.ndarray  # [L]
    sizes: np.ndarray  # [L]

    @staticmethod
    def from_image(image: np.ndarray) -> "Texture":
        """Build the pyramid of a square tileable linear-RGB image [S, S, 3]."""
        levels = [image.astype(np.float32)]
        while levels[-1].shape[0] // 2 >= _MIN_LEVEL:
            prev = levels[-1]
            # Box-filter 2x2: exact for a tile, and keeps the texture periodic.
            levels.append(prev.reshape(prev.shape[0] // 2, 2, prev.shape[1] // 2, 2, 3).mean(axis=(1, 3)))
        sizes = np.array([lv.shape[0] for lv in levels])
        offsets = np.concatenate([[0], np.cumsum(sizes + 2)[:-1]])
        atlas = np.zeros((sizes[0] + 2, (sizes + 2).sum(), 3), dtype=np.float32)
        for lv, off in zip(levels, offsets):
            atlas[:lv.shape[0] + 2, off:off + lv.shape[1] + 2] = np.pad(lv, ((1, 1), (1, 1), (0, 0)), mode="wrap")
        return Texture(atlas, offsets, sizes)


# cv2.remap wants maps narrower than 2^15; lookups are laid out in rows of this many points.
_REMAP_ROW = 4096


def sample(texture: Texture, uv: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """Bilinear lookup with wrap-around at the mip level matching each point's footprint.

    Args:
        uv: [P, 2] texture coordinates in tiles (any real value; the texture repeats).
        footprint: [P] size of the pixel on the surface, in tiles.
    Returns:
        [P, 3] linear RGB (float32).
    """
    if len(uv) == 0:  # cv2.remap refuses empty maps
        return np.zeros((0, 3), dtype=np.float32)
    level = np.log2(np.maximum(footprint * texture.sizes[0], 1e-9))
    level = np.clip(np.rint(level), 0, len(texture.sizes) - 1).astype(np.int64)
    size = texture.sizes[level]  # [P]
    # cv2.remap puts texel centres at integer coordinates: texel i of a level is at i + 1 (after the border),
    # and continuous coordinate c = frac(u) * size has texel i centred at i + 0.5, hence c + 0.5.
    x = (uv[:, 0] - np.floor(uv[:, 0])) * size + (texture.offsets[level] + 0.5)
    y = (uv[:, 1] - np.floor(uv[:, 1])) * size + 0.5
    count = len(uv)
    rows = -(-count // _REMAP_ROW)
    maps = np.zeros((2, rows * _REMAP_ROW), dtype=np.float32)
    maps[0, :count], maps[1, :count] = x, y
    maps = maps.reshape(2, rows, _REMAP_ROW)
    out = cv2.remap(texture.atlas, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:count]


# ---------------------------------------------------------------------------------------------- colour
def srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(rgb: np.ndarray) -> np.ndarray:
    rgb = np.clip(rgb, 0.0, 1.0)
    return np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * rgb ** (1 / 2.4) - 0.055)


# Hue ranges of common real materials: wood, earth and skin; foliage; sky, water and denim.
_NATURAL_HUES = ((0.02, 0.12), (0.15, 0.4), (0.53, 0.66))


def random_color(rng: np.random.Generator, hue: float | None = None) -> np.ndarray:
    """An sRGB colour [3] biased toward real scenes: 25% near-greys, 35% natural hues, mostly muted, few vivid."""
    kind = rng.random()
    if hue is not None:
        h = (hue + rng.normal(0, 0.04)) % 1.0
    elif kind < 0.6:
        low, high = _NATURAL_HUES[rng.integers(len(_NATURAL_HUES))]
        h = rng.uniform(low, high)
    else:
        h = rng.random()
    if kind < 0.25:
        s = rng.uniform(0.0, 0.08)
    else:
        s = rng.beta(1.2, 2.5) if rng.random() < 0.85 else rng.uniform(0.6, 1.0)
    v = rng.uniform(0.12, 0.95)
    return np.array(colorsys.hsv_to_rgb(h, s, v))


def palette(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` sRGB colours [count, 3]: analogous hues, complementary pairs, or unrelated ones."""
    scheme = rng.integers(3)
    base = rng.random()
    hues = [base if scheme == 0 else (base + 0.5 * (i % 2)) % 1.0 if scheme == 1 else None for i in range(count)]
    return np.stack([random_color(rng, h) for h in hues])


def colorize(field: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Map a scalar field [S, S] in [0, 1] through a piecewise-linear palette [K, 3] -> [S, S, 3]."""
    stops = np.linspace(0.0, 1.0, len(colors))
    return np.stack([np.interp(field, stops, colors[:, c]) for c in range(3)], axis=-1)


# ---------------------------------------------------------------------------------------------- patterns
def _normalize(field: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(field, [1, 99])
    return np.clip((field - lo) / max(hi - lo, 1e-9), 0.0, 1.0)


def fbm(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Spectral fractal noise [S, S] in [0, 1]: random phases, power-law amplitudes (periodic by construction)."""
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    stretch = rng.uniform(1.0, 6.0) if rng.random() < 0.3 else 1.0  # anisotropic: wood, brushed metal
    k = np.sqrt((fx * stretch) ** 2 + fy ** 2)
    low = rng.uniform(1.0, 6.0)  # lowest feature frequency, in cycles per tile
    amplitude = np.where(k >= low, np.maximum(k, 1e-9) ** -rng.uniform(1.0, 2.2), 0.0)
    spectrum = amplitude * np.exp(2j * np.pi * rng.random(amplitude.shape)) * rng.rayleigh(1.0, amplitude.shape)
    field = np.fft.irfft2(spectrum, s=(size, size))
    style = rng.integers(3)
    if style == 1:  # turbulence: creases where the noise crosses zero
        field = np.abs(field)
    elif style == 2:  # ridges
        field = -np.abs(field)
    return _normalize(field)


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    t = (np.arange(size) + 0.5) / size
    return np.meshgrid(t, t, indexing="xy")


def stripes(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Periodic stripes along an integer wave vector, optionally warped by noise and sharpened."""
    x, y = _grid(size)
    a, b = rng.integers(-6, 7, 2)
    if a == 0 and b == 0:
        a = 3
    phase = 2 * np.pi * (a * x + b * y)
    if rng.random() < 0.4:
        phase = phase + rng.uniform(1.0, 4.0) * (fbm(rng, size) - 0.5)
    field = 0.5 + 0.5 * np.sin(phase)
    sharp = rng.uniform(1.0, 20.0)
    return 1 / (1 + np.exp(-sharp * (field - rng.uniform(0.3, 0.7))))


def checkers(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Checkerboard, brick or tile pattern with grout lines."""
    x, y = _grid(size)
    n = int(rng.integers(2, 12))
    style = rng.integers(3)
    if style == 0:
        return ((np.floor(x * n) + np.floor(y * n)) % 2).astype(np.float64)
    rows = n
    cols = max(1, n // int(rng.integers(1, 3)))
    shift = 0.5 * (np.floor(y * rows) % 2) if style == 1 else 0.0  # brick rows are offset by half a brick
    u, v = (x * cols + shift) % 1.0, (y * rows) % 1.0
    grout = rng.uniform(0.03, 0.12)
    return ((u > grout) & (v > grout)).astype(np.float64) * (0.75 + 0.25 * rng.random((rows, cols + 1))[
        np.minimum((y * rows).astype(int), rows - 1), np.minimum((x * cols + shift).astype(int), cols)])


def voronoi(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Voronoi cells on the torus: flat random cell values, distance to the seed, or cell borders."""
    seeds = rng.random((int(rng.integers(6, 60)), 2))
    x, y = _grid(size)
    points = np.stack([x.ravel(), y.ravel()], axis=1)
    dist, idx = cKDTree(seeds, boxsize=1.0).query(points, k=2)
    style = rng.integers(3)
    if style == 0:
        field = rng.random(len(seeds))[idx[:, 0]]
    elif style == 1:
        field = dist[:, 0] / dist[:, 0].max()
    else:
        field = np.clip((dist[:, 1] - dist[:, 0]) * np.sqrt(len(seeds)) * rng.uniform(2, 8), 0, 1)
    return field.reshape(size, size)


def gradient(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """A smooth periodic ramp (one or two cycles per tile)."""
    x, y = _grid(size)
    a, b = rng.integers(0, 3, 2)
    a = a if (a or b) else 1
    return 0.5 + 0.5 * np.cos(2 * np.pi * (a * x + b * y) + rng.uniform(0, 2 * np.pi))


PATTERNS: dict[str, Callable[[np.random.Generator, int], np.ndarray]] = {
    "noise": fbm, "stripes": stripes, "checkers": checkers, "voronoi": voronoi, "gradient": gradient}
