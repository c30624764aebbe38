"""The chunked whole-image renderer: one frame of a camera through the model (compositing lives in
model/compositing.py)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Callable, Iterator, TypeVar

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.cameras.rays import Rays, rays_for_image
from insertnerf_cli.model import EncodedViews, InsertNeRF
from insertnerf_cli.model.compositing import Composite
from insertnerf_cli.model.guide import GuideOptions, guide_weights
from insertnerf_cli.model.sampling import RaySamples

T = TypeVar("T")


@dataclass(frozen=True)
class ImageOutput:
    """A rendered frame: rgb [H, W, 3] in [0, 1], depth [H, W] (camera z), opacity [H, W]."""

    rgb: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W]
    opacity: Tensor  # [H, W]


# Light a NeRF++ foreground must let through for its pixel's background to be rendered: under half an 8-bit step.
VISIBLE_LIGHT = 1.0 / 512


@dataclass(frozen=True)
class Shortcuts:
    """How much of the exact per-ray work a frame skips (render and eval use the defaults; tests hold every
    shortcut to the exact path).

    Attributes:
        coarse_stride: the coarse pass runs on every coarse_stride-th pixel of each row and column (and the last
            ones); every other pixel places its fine samples by the bilinear blend of the weights of its four
            nearest coarse rays. Neighbouring rays cross the same surfaces at nearly the same depth, and every ray
            of a frame has the same coarse sample depths (one near/far), so the weights carry over. 1: exact. With
            the SfM depth prior guiding the fine samples, 8 scored as well as 4 on the dev captures (room +0.13,
            flower +0.01, mold_gold_cape +0.04 dB at 10 views) for a quarter of the coarse pass
            (docs/research-log.md, Speed).
        empty_opacity: a pixel whose four nearest coarse rays all see less opacity than this shows background and
            gets no fine pass. 0: never skip.
        fine_stride: the fine pass runs first on every fine_stride-th pixel of each row and column (and the last
            ones); then on the grid of half that stride (fine_levels), where a pixel not yet rendered takes the
            bilinear blend of its four nearest results of the level before when they agree (see smooth_rgb,
            smooth_depth) and gets its own fine pass otherwise; and so on down to every pixel. The generator's
            pictures are smooth over most of a frame, so most pixels need no pass of their own. 1: every pixel.
        smooth_rgb: the four agree when each colour channel and the opacity differ by at most this between them.
        smooth_depth: ... and their depths by at most this fraction of the frame's depth range (far - near), so
            that a depth map is never blended across an edge that the colours do not show.
        stride_size: the strides are those of a frame of this long side; a larger frame takes strides above 1
            scaled by its long side over this (rounded), so that a grid step spans the same part of the picture:
            at 512 px, 16 / 8 scored within 0.05 dB of 4 / 4 at 10 views (room -0.04, flower -0.05; at 3 views
            +0.57 / +0.04) in 0.57x room's eval time, at 996 px +0.21 dB in 0.64x (docs/research-log.md, Speed).
            Smaller frames keep them. 0: never scaled.
    """

    coarse_stride: int = 8
    empty_opacity: float = 1e-3
    fine_stride: int = 4
    smooth_rgb: float = 0.03
    smooth_depth: float = 0.1
    stride_size: int = 256

    def __post_init__(self) -> None:
        if (self.coarse_stride < 1 or self.fine_stride < 1 or not 0.0 <= self.empty_opacity < 1.0
                or not 0.0 <= self.smooth_rgb <= 1.0 or not 0.0 <= self.smooth_depth <= 1.0 or self.stride_size < 0):
            raise ValueError(f"strides must be >= 1, empty_opacity in [0, 1), the smooth_ bounds in [0, 1] and "
                             f"stride_size >= 0, got {self}")

    def for_size(self, long_side: int) -> Shortcuts:
        """These shortcuts with the strides of a frame whose long side is ``long_side`` px (stride_size)."""
        if not self.stride_size or long_side <= self.stride_size:
            return self
        factor = long_side / self.stride_size

        def scaled(stride: int) -> int:
            return stride if stride == 1 else max(stride, round(stride * factor))

        return replace(self, coarse_stride=scaled(self.coarse_stride), fine_stride=scaled(self.fine_stride))

    @property
    def exact(self) -> bool:
        return self.coarse_stride == 1 and self.empty_opacity == 0.0 and self.fine_stride == 1


EXACT = Shortcuts(coarse_stride=1, empty_opacity=0.0, fine_stride=1)


def render_image(model: InsertNeRF, encoded: EncodedViews, camera: Cameras, near: float | Tensor,
                 far: float | Tensor, chunk: int = 512, shortcuts: Shortcuts = Shortcuts(),
                 prior: Tensor | None = None, guide_options: GuideOptions = GuideOptions()) -> ImageOutput:
    """Render one full frame of ``camera`` (a Cameras of length 1) from the encoded reference views.

    Rays go through the network ``chunk`` at a time without autograd, so peak memory is bounded by the chunk
    size, not by the image size. The fine pass is returned.
    Args:
        model: the generator (its mode is left unchanged; the forward runs with train=False).
        encoded: model.encode(...) of the reference views, computed once per frame or per sequence.
        camera: the target camera (1), same device as the model.
        near, far: scalar depth bounds of the target view.
        chunk: rays per network call. Each per-view tensor (chunk x samples x views x channels floats) should
            stay inside the CPU caches, and each of a chunk's ~1,000 torch calls should carry enough rays to hide its
            fixed cost: with 32 coarse and 16 fine samples and 8 views, 512 rays per call rendered a room frame
            at 256 px in 0.83x the time of 128, and 1,024 or 2,048 no faster (docs/research-log.md, Speed); above
            glibc's 32 MB mmap threshold every allocation also page-faults.
        shortcuts: the work skipped (Shortcuts); EXACT runs every ray's own coarse and fine pass.
        prior: [H, W] depth of the scene's SfM points in this view (depth_prior.prior_depth; NaN where none), or
            None: a share of each pixel's fine samples goes around it (model.guide.guide_weights under
            ``guide_options``).
    """
    if len(camera) != 1:
        raise ValueError(f"render_image renders one camera, got {len(camera)}")
    height, width = camera.height, camera.width
    param = next(model.parameters())
    camera = camera.to(device=param.device, dtype=param.dtype)
    bounds = torch.as_tensor([near, far], dtype=param.dtype, device=param.device).reshape(2)
    rays = rays_for_image(camera, bounds[:1], bounds[1:])
    guide = None if prior is None else prior.to(param).reshape(height * width)  # [R]

    with _chunk_workers(param.device) as workers:
        with ThreadPoolExecutor(workers) as pool:
            def chunked(work: Callable[[Tensor], T], count: int) -> list[T]:
                starts = range(0, count, chunk)
                return list(pool.map(lambda s: _no_grad(work, torch.arange(s, min(s + chunk, count),
                                                                           device=param.device)), starts))

            if shortcuts.exact:
                outs = chunked(lambda i: _render_exact(model, encoded, rays[i], None if guide is None else guide[i],
                                                       guide_options),
                               len(rays))
                rgb, depth, opacity = (torch.cat([getattr(o, k) for o in outs]) for k in ("rgb", "depth", "opacity"))
            else:
                rgb, depth, opacity = _render_with_shortcuts(model, encoded, rays, (height, width), shortcuts,
                                                             chunked, guide, guide_options)
    return ImageOutput(rgb=rgb.reshape(height, width, 3).clamp(0.0, 1.0), depth=depth.reshape(height, width),
                       opacity=opacity.reshape(height, width))


def _render_exact(model: InsertNeRF, encoded: EncodedViews, rays: Rays, guide: Tensor | None,
                  guide_options: GuideOptions) -> Composite:
    """Each ray's own coarse and fine pass; with ``guide`` [R] the fine samples follow the guided weights."""
    if guide is None:
        return model.render(encoded, rays)
    samples, weights = model.coarse_weights(encoded, rays)
    return model.render_fine(encoded, rays, samples, guide_weights(weights, samples.t, guide, guide_options))


def _no_grad(work: Callable[[Tensor], T], index: Tensor) -> T:
    with torch.inference_mode():  # thread-local: entered in the worker that runs the chunk
        return work(index)


def _render_with_shortcuts(model: InsertNeRF, encoded: EncodedViews, rays: Rays, size: tuple[int, int],
                           shortcuts: Shortcuts, chunked: Callable, guide: Tensor | None,
                           guide_options: GuideOptions) -> tuple[Tensor, ...]:
    """(rgb [R, 3], depth [R], opacity [R]) of the frame's R = H * W rays: the coarse pass on a grid of every
    coarse_stride-th pixel, fine samples placed by the blend of the nearest grid rays, empty pixels skipped, the
    fine pass on a grid of every fine_stride-th pixel and on the pixels between whose neighbours disagree."""
    device = rays.origins.device
    shortcuts = shortcuts.for_size(max(size))
    grid = PixelGrid(*size, shortcuts.coarse_stride, device)
    grid_rays = rays[grid.index]
    passes = chunked(lambda i: model.coarse_weights(encoded, grid_rays[i]), len(grid_rays))
    grid_weights = torch.cat([w for _, w in passes])  # [G, S_c]
    # One near/far for the whole frame: every ray has the coarse sample depths of the first grid ray.
    t, edges = passes[0][0].t[:1], passes[0][0].edges[:1]  # [1, S_c], [1, S_c + 1]
    if guide is not None:  # on the grid, before the blend: a pixel whose grid neighbours' priors differ (an edge,
        # a wrong fill) gets samples around each of them; guided per pixel after the blend, such a pixel's samples
        # would all sit at one of them.
        grid_weights = guide_weights(grid_weights, t.expand(len(grid_weights), -1), guide[grid.index], guide_options)
    # A pixel's coarse weights are the blend of its grid neighbours', made only for the pixels the fine pass runs on.
    live = grid.nearest_max(grid_weights.sum(dim=-1)) >= shortcuts.empty_opacity  # [R]

    # What an empty pixel shows: what the reference views see at infinity; the fine pass composites its pixels
    # over the same. NeRF++'s background field comes after the foreground instead (below).
    nerfpp = model.config.backbone == "nerfpp"
    backdrop = model.background.to(grid_weights).expand(len(rays), 3)
    if nerfpp:
        backdrop = torch.zeros_like(backdrop)
    elif model.config.infinity_sample:
        backdrop = torch.cat(chunked(lambda i: model.backdrop(encoded, rays[i]), len(rays)))

    def fine(rows: Tensor) -> Callable[[Tensor], Composite]:
        def run(i: Tensor) -> Composite:
            return model.render_fine(encoded, rays[rows[i]], RaySamples(t.expand(len(i), -1),
                                                                        edges.expand(len(i), -1)),
                                     grid.blend(grid_weights, rows[i]), backdrop[rows[i]])
        return run

    # [R, 5]: rgb, depth, opacity; what compositing gives a ray that sees nothing until a fine pass fills it
    out = torch.cat([backdrop, t.mean().expand(len(rays), 1), grid_weights.new_zeros(len(rays), 1)], dim=-1)

    def fill(rows: Tensor) -> None:
        outs = chunked(fine(rows), len(rows))
        if outs:
            out[rows] = torch.cat([torch.cat([o.rgb, o.depth[:, None], o.opacity[:, None]], dim=-1) for o in outs])

    depth_range = edges[0, -1] - edges[0, 0]
    _fine_pass_by_levels(out, live, size, shortcuts, depth_range, fill)
    if nerfpp:  # compositing is linear in what lies behind: C = C_fg + T_fg C_bg
        transmittance = 1.0 - out[:, 4:5]  # [R, 1]
        out[:, :3] += transmittance * _background(model, encoded, rays, size, shortcuts, chunked, depth_range,
                                                  transmittance[:, 0])
    return out[:, :3], out[:, 3], out[:, 4]


def _background(model: InsertNeRF, encoded: EncodedViews, rays: Rays, size: tuple[int, int], shortcuts: Shortcuts,
                chunked: Callable, depth_range: Tensor, transmittance: Tensor) -> Tensor:
    """[R, 3] NeRF++'s background field behind each of the frame's R pixels, given the light [R] its foreground lets
    through. Run on pixel grids as the fine pass runs, where more than VISIBLE_LIGHT gets through; a pixel takes
    the blend of its four neighbours where their colours spread by at most smooth_rgb over its transmittance, since
    the pixel shows its background only that much dimmed (a bound on what the blend changes in it)."""
    behind = torch.zeros(len(rays), 5, dtype=transmittance.dtype, device=transmittance.device)

    def fill(rows: Tensor) -> None:
        if len(rows):
            behind[rows, :3] = torch.cat(chunked(lambda i: model.backdrop(encoded, rays[rows[i]]), len(rows)))

    _fine_pass_by_levels(behind, transmittance > VISIBLE_LIGHT, size, shortcuts, depth_range, fill,
                         1.0 / transmittance.clamp(min=VISIBLE_LIGHT))
    return behind[:, :3]


def _fine_pass_by_levels(out: Tensor, live: Tensor, size: tuple[int, int], shortcuts: Shortcuts, depth_range: Tensor,
                         fill: Callable[[Tensor], None], looser: Tensor | None = None) -> None:
    """Fill ``out`` [R, 5] (rgb, depth, opacity) of the ``live`` [R] pixels level by level (fine_levels): a
    level's new pixels take the blend of the level before where its four pixels agree (``looser`` [R]: each
    pixel's colour bound smooth_rgb times this), else ``fill`` gives them their own fine pass."""
    known = torch.zeros_like(live)
    previous: PixelGrid | None = None
    for stride in fine_levels(shortcuts.fine_stride):
        grid = PixelGrid(*size, stride, live.device)
        todo = torch.zeros_like(live)
        todo[grid.index] = True
        todo &= live & ~known
        pending = todo.nonzero()[:, 0]  # [N] ascending
        if previous is not None:
            corners = out[previous.index]  # [G, 5]
            spread = previous.spread(corners, pending)  # [N, 5]
            bound = shortcuts.smooth_rgb if looser is None else shortcuts.smooth_rgb * looser[pending]
            smooth = ((spread[:, [0, 1, 2, 4]].amax(dim=-1) <= bound)
                      & (spread[:, 3] <= shortcuts.smooth_depth * depth_range.clamp(min=1e-6)))  # [N]
            out[pending[smooth]] = previous.blend(corners, pending[smooth])
            pending = pending[~smooth]
        fill(pending)
        known[grid.index] = True
        previous = grid


def fine_levels(stride: int) -> list[int]:
    """The strides of the fine pass's levels, coarse to fine: stride, then halved (rounded down) down to 1, so
    that each level's grid contains the one before (4 -> [4, 2, 1], 3 -> [3, 1], 1 -> [1])."""
    levels = [stride]
    while levels[-1] > 1:
        levels.append(levels[-1] // 2)
    return levels


class PixelGrid:
    """The pixels of an H x W frame that a pass runs on first: every ``stride``-th row and column, plus the last
    ones, so that every pixel lies between grid pixels and none is extrapolated.

    Its methods take the [G, C] values at the grid pixels and give a value for each pixel ``at`` [N] (row-major
    indices; None: all H * W, in order). Asking for the pixels a caller uses makes each the same number as asking
    for all, at a fraction of the cost on a large frame.

    Attributes:
        index: [G] row-major pixel indices of the grid pixels (G = rows x columns of the grid).
    """

    def __init__(self, height: int, width: int, stride: int, device: torch.device) -> None:
        self.width = width
        self.rows, self.cols = _grid_line(height, stride, device), _grid_line(width, stride, device)
        self.index = (self.rows[:, None] * width + self.cols[None, :]).reshape(-1)  # [G]
        (self.r0, self.r1, self.fr), (self.c0, self.c1, self.fc) = (_between(self.rows, height),
                                                                    _between(self.cols, width))

    def blend(self, values: Tensor, at: Tensor | None = None) -> Tensor:
        """[N, C] the bilinear blend of the four grid pixels around each pixel."""
        corners = self._corners(values, at)
        if at is None:
            fr, fc = self.fr[:, None, None], self.fc[None, :, None]  # [H, 1, 1], [1, W, 1]
        else:
            fr, fc = self.fr[at // self.width, None], self.fc[at % self.width, None]  # [N, 1] each
        fr, fc = fr.to(values), fc.to(values)
        top = corners[0] * (1 - fc) + corners[1] * fc
        bottom = corners[2] * (1 - fc) + corners[3] * fc
        return (top * (1 - fr) + bottom * fr).reshape(-1, values.shape[-1])

    def nearest_max(self, values: Tensor, at: Tensor | None = None) -> Tensor:
        """[G] values -> [N] the largest of the four around each pixel."""
        corners = self._corners(values[:, None], at)
        return torch.stack(corners).amax(dim=0).reshape(-1)

    def spread(self, values: Tensor, at: Tensor | None = None) -> Tensor:
        """[N, C] the largest minus the smallest of the four grid pixels around each pixel, per channel."""
        corners = torch.stack(self._corners(values, at))  # [4, H, W, C] or [4, N, C]
        return (corners.amax(dim=0) - corners.amin(dim=0)).reshape(-1, values.shape[-1])

    def _corners(self, values: Tensor, at: Tensor | None) -> list[Tensor]:
        """The values of the grid pixels above-left, above-right, below-left, below-right of each pixel: [H, W, C]
        each for all pixels, [N, C] for the pixels ``at``."""
        table = values.reshape(len(self.rows), len(self.cols), -1)
        if at is None:
            return [table[r][:, c] for r in (self.r0, self.r1) for c in (self.c0, self.c1)]
        row, col = at // self.width, at % self.width
        return [table[r[row], c[col]] for r in (self.r0, self.r1) for c in (self.c0, self.c1)]


def _grid_line(size: int, stride: int, device: torch.device) -> Tensor:
    """Grid positions along one axis: 0, stride, 2 stride, ... and size - 1."""
    line = torch.arange(0, size, stride, device=device)
    return line if line[-1] == size - 1 else torch.cat([line, line.new_tensor([size - 1])])


def _between(line: Tensor, size: int) -> tuple[Tensor, Tensor, Tensor]:
    """For every pixel 0..size-1: the grid positions below and above it (indices into ``line``) and how far
    along it is from the one to the other (0 on a grid pixel)."""
    pixels = torch.arange(size, device=line.device)
    upper = torch.searchsorted(line, pixels).clamp(max=len(line) - 1)  # first grid position >= pixel
    lower = torch.where(line[upper] == pixels, upper, (upper - 1).clamp(min=0))
    span = (line[upper] - line[lower]).clamp(min=1)
    return lower, upper, (pixels - line[lower]).float() / span


@contextmanager
def _chunk_workers(device: torch.device) -> Iterator[int]:
    """Threads to render chunks with: on a CPU, one chunk per core with one intra-op thread each.

    The per-chunk tensors are small (they must stay in cache), so splitting each op over the cores scales
    poorly; torch releases the GIL inside ops, and whole chunks on separate threads rendered a 200x200 frame
    1.5x faster on 2 cores (bench/model_speed.py). A GPU runs the chunks in order.
    """
    threads = torch.get_num_threads()
    if device.type != "cpu" or threads == 1:
        yield 1
        return
    torch.set_num_threads(1)
    try:
        yield threads
    finally:
        torch.set_num_threads(threads)
