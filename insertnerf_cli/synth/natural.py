"""Textures with the statistics of photographs, beside the patterns of textures.py.

Natural images have amplitude spectra falling as ~1/f, occlusion structure (surfaces in front of others: the
dead-leaves model), a roughly log-normal spread of luminance, and colours that vary mostly in brightness
and little in hue. Here: coloured pink noise, dead leaves, and wood, stone (granite, marble, cobbles) and
fabric (woven threads) built from those. Every image is a tileable sRGB image [S, S, 3] in [0, 1].
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from insertnerf_cli.synth.textures import SIZE, colorize, fbm, random_color


def pink(rng: np.random.Generator, size: int = SIZE, exponent: float | None = None) -> np.ndarray:
    """Zero-mean unit-std periodic noise [S, S] whose amplitude spectrum falls as 1/f^exponent (0.8-1.3)."""
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    k = np.sqrt(fx ** 2 + fy ** 2)
    beta = rng.uniform(0.8, 1.3) if exponent is None else exponent
    amplitude = np.where(k > 0, np.maximum(k, 1e-9) ** -beta, 0.0)
    field = np.fft.irfft2(amplitude * np.exp(2j * np.pi * rng.random(amplitude.shape)), s=(size, size))
    return (field - field.mean()) / max(field.std(), 1e-12)


def _photo_colors(rng: np.random.Generator, luminance: np.ndarray, base: np.ndarray, size: int) -> np.ndarray:
    """Colour a zero-mean field ``luminance`` [S, S] around the sRGB colour ``base`` [3]: log-normal
    brightness and a small, smooth chroma drift (hue varies far less than brightness in photos)."""
    contrast = rng.uniform(0.2, 0.6)
    brightness = np.exp(contrast * luminance)[..., None]
    chroma = 1 + rng.uniform(0.02, 0.06) * np.stack([pink(rng, size, 2.2) for _ in range(3)], axis=-1)
    return np.clip(base * brightness * chroma, 0.0, 1.0)


def pink_texture(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Coloured 1/f noise: grass, soil, plaster, foliage seen from afar."""
    return _photo_colors(rng, pink(rng, size), random_color(rng), size)


def dead_leaves(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Discs (or ellipses) of radius r with density ~ r^-3, each one colour from a small natural palette,
    falling on top of each other over a 1/f ground: scale-invariant occlusion statistics."""
    base = [random_color(rng) for _ in range(int(rng.integers(2, 6)))]
    ground = _photo_colors(rng, pink(rng, size), base[0], size)
    canvas = np.ascontiguousarray((ground * 255).astype(np.uint8))
    low, high = size / 64, size / rng.uniform(3, 8)
    ellipses = rng.random() < 0.5
    # Enough leaves to cover all but ~1% of the tile: E[area] of p(r) ~ r^-3 is 2 pi a^2 b^2 ln(b/a) / (b^2 - a^2).
    mean_area = 2 * np.pi * low ** 2 * high ** 2 * np.log(high / low) / (high ** 2 - low ** 2)
    count = int(min(4.6 * size ** 2 / (mean_area * (0.65 if ellipses else 1.0)), 2000))
    u = rng.random(count)
    radii = 1 / np.sqrt(u / high ** 2 + (1 - u) / low ** 2)  # inverse CDF of p(r) ~ r^-3 on [low, high]
    centers = rng.uniform(0, size, (count, 2))
    shades = np.exp(rng.normal(0, 0.25, count))
    picks = rng.integers(len(base), size=count)
    flat = rng.uniform(0.3, 1.0, count) if ellipses else np.ones(count)
    angles = rng.uniform(0, 180, count)
    for k in range(count):
        fill = tuple(int(c) for c in np.clip(base[picks[k]] * shades[k] * 255, 0, 255))
        axes = (max(int(radii[k]), 1), max(int(radii[k] * flat[k]), 1))
        reach = axes[0] + 1
        for dx in _wraps(centers[k, 0], reach, size):  # a leaf crossing the tile's edge wraps around
            for dy in _wraps(centers[k, 1], reach, size):
                cv2.ellipse(canvas, (int(centers[k, 0] + dx), int(centers[k, 1] + dy)), axes, float(angles[k]),
                            0, 360, fill, -1, cv2.LINE_AA)
    return canvas.astype(np.float64) / 255


def _wraps(center: float, reach: float, size: int) -> tuple[int, ...]:
    """Tile offsets at which a shape of half-size ``reach`` around ``center`` shows in [0, size)."""
    return (0, *((size,) if center - reach < 0 else ()), *((-size,) if center + reach >= size else ()))


def wood(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Growth rings (stripes warped by low-frequency noise, a darker late-wood edge) with fine grain along
    the fibres."""
    x, y = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size, indexing="xy")
    rings = int(rng.integers(4, 16))
    phase = rings * y + rng.uniform(0.5, 2.0) * (fbm(rng, size) - 0.5)
    ring = (phase - np.floor(phase)) ** rng.uniform(1.5, 4.0)  # slow early wood, sharp late wood
    grain = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((size, size))) * _stretch_filter(size, 12.0),
                          s=(size, size))
    grain = grain / max(grain.std(), 1e-12)
    light = random_color(rng, hue=rng.uniform(0.04, 0.11))
    dark = light * rng.uniform(0.35, 0.7)
    image = colorize(ring, np.stack([light, dark]))
    return np.clip(image * np.exp(0.08 * grain)[..., None], 0, 1)


def _stretch_filter(size: int, stretch: float) -> np.ndarray:
    """rfft2 filter [S, S//2 + 1] damping frequencies along x ``stretch`` times more than along y: noise
    smeared into streaks along x, the direction of the rings' lines (the fibres)."""
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    k = np.sqrt((fx * stretch) ** 2 + fy ** 2)
    return np.where(k > 0, np.maximum(k, 1e-9) ** -0.7, 0.0) * np.exp(-(fy / (0.4 * size)) ** 2)


def stone(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Granite (speckles of 2-4 minerals in 1/f noise), marble (turbulent veins) or cobbles (Voronoi stones
    of varied tone with dark joints)."""
    style = int(rng.integers(3))
    base = random_color(rng, hue=rng.uniform(0.0, 0.15) if rng.random() < 0.6 else None)
    base = 0.6 * base + 0.4 * base.mean()  # stone is mostly desaturated
    if style == 0:
        image = _photo_colors(rng, pink(rng, size, 0.6), base, size)
        minerals = rng.random((size, size))
        for _ in range(int(rng.integers(2, 5))):
            spots = minerals < rng.uniform(0.03, 0.15)
            image[spots] = random_color(rng) * 0.5 + 0.5 * np.mean(random_color(rng))
            minerals = rng.random((size, size))
        # Softened across the tile's edges too (OpenCV's filters have no wrap-around border).
        padded = np.pad(image, ((4, 4), (4, 4), (0, 0)), mode="wrap")
        return cv2.GaussianBlur(padded, (0, 0), 0.6)[4:-4, 4:-4]
    if style == 1:
        x = (np.arange(size) + 0.5)[None, :] / size
        veins = np.abs(np.sin(2 * np.pi * (int(rng.integers(1, 4)) * x + rng.uniform(1, 3) * pink(rng, size, 1.4))))
        veins = veins ** rng.uniform(0.2, 0.6)
        vein_color = random_color(rng) * rng.uniform(0.3, 0.8)
        return np.clip(colorize(veins, np.stack([vein_color, base])) * np.exp(0.1 * pink(rng, size))[..., None], 0, 1)
    seeds = rng.random((int(rng.integers(8, 40)), 2))
    t = (np.arange(size) + 0.5) / size
    points = np.stack(np.meshgrid(t, t, indexing="xy"), axis=-1).reshape(-1, 2)
    dist, idx = cKDTree(seeds, boxsize=1.0).query(points, k=2)
    tone = np.exp(rng.normal(0, 0.25, len(seeds)))[idx[:, 0]].reshape(size, size)
    joint = np.clip((dist[:, 1] - dist[:, 0]).reshape(size, size) * np.sqrt(len(seeds)) * 8, 0, 1)
    image = _photo_colors(rng, 0.6 * pink(rng, size), base, size) * (tone * (0.3 + 0.7 * joint))[..., None]
    return np.clip(image, 0, 1)


def fabric(rng: np.random.Generator, size: int = SIZE) -> np.ndarray:
    """Woven threads: warp and weft of slightly varying tone crossing in a plain or twill order, with
    per-thread shading and fuzz; sometimes a woven check of two colours."""
    threads = int(rng.choice([32, 64, 128]))
    cell = size // threads
    u = (np.arange(size) % cell + 0.5) / cell
    row, col = np.arange(size)[:, None] // cell, np.arange(size)[None, :] // cell
    twill = int(rng.integers(1, 3))
    warp_on_top = ((row + col) // twill) % 2 == 0  # plain weave (1) or 2/2 twill (2)
    profile = np.sin(np.pi * u) ** 0.5  # a thread is lit in the middle, dark at its edges
    warp_tone = np.exp(rng.normal(0, 0.08, threads))[col] * profile[None, :]
    weft_tone = np.exp(rng.normal(0, 0.08, threads))[row] * profile[:, None]
    a, b = random_color(rng), random_color(rng)
    warp_color = np.where(((col // int(rng.integers(2, 8))) % 2 == 0)[..., None], a, b) if rng.random() < 0.3 else a
    weft_color = b if rng.random() < 0.5 else a * rng.uniform(0.7, 1.0)
    image = np.where(warp_on_top[..., None], warp_color * warp_tone[..., None], weft_color * weft_tone[..., None])
    return np.clip(image * np.exp(0.1 * pink(rng, size))[..., None], 0, 1)


NATURAL: dict[str, Callable[[np.random.Generator, int], np.ndarray]] = {
    "pink": pink_texture, "dead-leaves": dead_leaves, "wood": wood, "stone": stone, "fabric": fabric}


def natural_texture(rng: np.random.Generator, size: int = SIZE) -> tuple[np.ndarray, str]:
    """One of the natural textures, and its name."""
    name = str(rng.choice(list(NATURAL)))
    return NATURAL[name](rng, size), name
