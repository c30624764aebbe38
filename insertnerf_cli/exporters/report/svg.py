"""Inline SVG drawings for the pages: a line chart, and cameras seen from above and from the side."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from insertnerf_cli.exporters.report.html import esc

_PATH_COLOUR, _INPUT_COLOUR, _AXIS_COLOUR = "#1f6feb", "#8a949e", "#c9d1d9"


def _nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round tick values covering [low, high] (steps of 1, 2 or 5 times a power of ten)."""
    span = max(high - low, 1e-9)
    raw = span / count
    step = min((m * 10 ** math.floor(math.log10(raw)) for m in (1, 2, 5, 10)), key=lambda s: abs(s - raw))
    start = math.floor(low / step) * step
    return [start + i * step for i in range(int(math.ceil((high - start) / step)) + 1)]


def line_chart(xs: Sequence[float], ys: Sequence[float], x_label: str, y_label: str, width: int = 560,
               height: int = 300) -> str:
    """A chart of ys against xs: points joined by a line, each labelled with its value, axes with round ticks."""
    left, right, top, bottom = 56, 16, 16, 44
    finite = [y for y in ys if math.isfinite(y)] or [0.0]
    y_ticks = _nice_ticks(min(finite) - 0.5, max(finite) + 0.5)
    x0, x1 = min(xs), max(xs) if max(xs) > min(xs) else min(xs) + 1
    x0, x1 = x0 - 0.06 * (x1 - x0), x1 + 0.06 * (x1 - x0)  # room for the end points' labels inside the axes
    y0, y1 = y_ticks[0], y_ticks[-1]

    def sx(x: float) -> float:
        return left + (x - x0) / (x1 - x0) * (width - left - right)

    def sy(y: float) -> float:
        return top + (1 - (y - y0) / (y1 - y0)) * (height - top - bottom)

    parts = [f'<svg width="{width}" height="{height}" '
             f'viewBox="0 0 {width} {height}" role="img" aria-label="{esc(y_label)} against {esc(x_label)}">']
    for y in y_ticks:
        parts.append(f'<line x1="{left}" x2="{width - right}" y1="{sy(y):.1f}" y2="{sy(y):.1f}" '
                     f'stroke="{_AXIS_COLOUR}" stroke-width="1"/>'
                     f'<text x="{left - 6}" y="{sy(y) + 4:.1f}" font-size="12" text-anchor="end">{y:g}</text>')
    for x in xs:
        parts.append(f'<text x="{sx(x):.1f}" y="{height - bottom + 18}" font-size="12" '
                     f'text-anchor="middle">{x:g}</text>')
    points = [(sx(x), sy(y)) for x, y in zip(xs, ys) if math.isfinite(y)]
    parts.append(f'<polyline fill="none" stroke="{_PATH_COLOUR}" stroke-width="2" '
                 f'points="{" ".join(f"{px:.1f},{py:.1f}" for px, py in points)}"/>')
    for (px, py), y in zip(points, [y for y in ys if math.isfinite(y)]):
        parts.append(f'<circle cx="{px:.1f}" cy="{py:.1f}" r="4" fill="{_PATH_COLOUR}"/>'
                     f'<text x="{px:.1f}" y="{py - 9:.1f}" font-size="12" text-anchor="middle">{y:.2f}</text>')
    parts.append(f'<text x="{(left + width - right) / 2:.0f}" y="{height - 6}" font-size="13" '
                 f'text-anchor="middle">{esc(x_label)}</text>'
                 f'<text x="14" y="{(top + height - bottom) / 2:.0f}" font-size="13" text-anchor="middle" '
                 f'transform="rotate(-90 14 {(top + height - bottom) / 2:.0f})">{esc(y_label)}</text></svg>')
    return "".join(parts)


@dataclass(frozen=True)
class ViewAxes:
    """The axes cameras are drawn in: ``up`` (the cameras' mean up), ``across`` (the main horizontal spread of
    the input cameras) and ``depth`` (up x across); rows of a [3, 3] matrix."""

    matrix: np.ndarray  # [3, 3]

    @classmethod
    def of(cls, centres: np.ndarray, ups: np.ndarray) -> "ViewAxes":
        """From camera centres [N, 3] and up vectors [N, 3] (world)."""
        up = ups.mean(axis=0)
        up = up / max(np.linalg.norm(up), 1e-12)
        flat = centres - centres.mean(axis=0)
        flat = flat - np.outer(flat @ up, up)
        if np.abs(flat).max() > 1e-12:
            across = np.linalg.svd(flat, full_matrices=False)[2][0]  # the main direction of the spread
        else:  # one camera, or all on a vertical line: any horizontal direction
            across = np.cross(up, np.eye(3)[np.argmin(np.abs(up))])
        across = across - (across @ up) * up
        across = across / max(np.linalg.norm(across), 1e-12)
        return cls(np.stack([across, np.cross(up, across), up]))


def cameras_views(path_centres: np.ndarray, path_forward: np.ndarray, input_centres: np.ndarray,
                  input_forward: np.ndarray, axes: ViewAxes, closed: bool = False, size: int = 360) -> str:
    """Two panels, from above (across, depth) and from the side (across, up): the input cameras as grey dots
    with a tick along their optical axis, the rendered path as a blue line (back to its start when ``closed``),
    its first frame ringed. Centres [N, 3] and optical axes [N, 3] in world units."""
    return "".join(_panel(title, dims, path_centres, path_forward, input_centres, input_forward, axes, closed, size)
                   for title, dims in (("from above", (0, 1)), ("from the side", (0, 2))))


def _panel(title: str, dims: tuple[int, int], path_c: np.ndarray, path_f: np.ndarray, in_c: np.ndarray,
           in_f: np.ndarray, axes: ViewAxes, closed: bool, size: int) -> str:
    pad = 24
    project = axes.matrix[list(dims)]  # [2, 3]
    pc, ic = path_c @ project.T, in_c @ project.T  # [F, 2], [N, 2]
    every = np.vstack([pc, ic])
    centre, half = (every.max(0) + every.min(0)) / 2, max(float((every.max(0) - every.min(0)).max()) / 2, 1e-9)
    tick = 0.12 * half

    def s(p: np.ndarray) -> tuple[float, float]:
        q = (p - centre) / half * (size / 2 - pad)
        return size / 2 + q[0], size / 2 - q[1]  # SVG's y grows downwards

    parts = [f'<svg width="{size}" height="{size}" viewBox="0 0 {size} {size}" '
             f'role="img" aria-label="cameras {esc(title)}"><text x="8" y="16" font-size="13">{esc(title)}</text>']
    for c, f in zip(ic, in_f @ project.T):
        (x0, y0), (x1, y1) = s(c), s(c + tick * f / max(np.linalg.norm(f), 1e-12))
        parts.append(f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" stroke="{_INPUT_COLOUR}"/>'
                     f'<circle cx="{x0:.1f}" cy="{y0:.1f}" r="2.5" fill="{_INPUT_COLOUR}"/>')
    line = " ".join("{:.1f},{:.1f}".format(*s(c)) for c in pc)
    shape = "polygon" if closed else "polyline"
    parts.append(f'<{shape} fill="none" stroke="{_PATH_COLOUR}" stroke-width="2" points="{line}"/>')
    for c, f in zip(pc, path_f @ project.T):
        (x0, y0), (x1, y1) = s(c), s(c + tick * f / max(np.linalg.norm(f), 1e-12))
        parts.append(f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" stroke="{_PATH_COLOUR}" '
                     f'stroke-opacity="0.5"/>')
    x0, y0 = s(pc[0])
    parts.append(f'<circle cx="{x0:.1f}" cy="{y0:.1f}" r="6" fill="none" stroke="{_PATH_COLOUR}" stroke-width="2"/>'
                 "</svg>")
    return "".join(parts)
