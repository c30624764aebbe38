"""Rendering target cameras of a normalised scene from their nearest reference views (shared by `render` and
`eval`; no click here). Encodings are kept per reference view, so consecutive frames, or the same held-out view
at several reference-view counts, encode each view once."""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from pathlib import Path

import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import EncodedViews, SourceViews
from insertnerf_cli.model.checkpoint import bundled_checkpoint, load_model as load_checkpoint
from insertnerf_cli.model.occlusion import Occlusion
from insertnerf_cli.rendering.image_renderer import EXACT, ImageOutput, render_image
from insertnerf_cli.rendering.options import RenderOptions
from insertnerf_cli.rendering.prior_blend import blend_at_prior
from insertnerf_cli.scenes import Scene
from insertnerf_cli.scenes.views import nearest_views, view_rule
from insertnerf_cli.sfm.depth_prior import covering_far, view_prior_splats, well_tracked
from insertnerf_cli.sfm.occlusion_maps import occlusion, reference_map

# Rays per network call by device. CPU: chunks small enough to stay in cache, large enough that torch's per-op cost
# is spread over many rays (image_renderer.render_image). CUDA: a GPU needs far more work per call; 4096 rays of
# 64+64 samples and 10 views hold about 1 GB of per-view tensors.
DEFAULT_CHUNKS = {"cpu": 512, "cuda": 4096}
# Consecutive frames of a path mostly share their reference views: encodings are kept per view, for this many
# times --views views, so a frame encodes only the views its predecessors did not use.
ENCODED_VIEWS_KEPT = 2


def colour_size(size: tuple[int, int], photo: tuple[int, int], scale: float) -> tuple[int, int] | None:
    """(height, width) at which the references' colours are looked up for frames of ``size``: ``scale`` times
    it, at most the photos' own ``photo`` size; None where that is no finer than ``size``."""
    factor = min(scale, photo[0] / size[0], photo[1] / size[1])
    if factor <= 1.0:
        return None
    return round(size[0] * factor), round(size[1] * factor)


def checkpoint_path(checkpoint: Path | None) -> Path:
    """The given weights, or the bundled default generator's file."""
    return Path(checkpoint) if checkpoint is not None else bundled_checkpoint()


def load_model(checkpoint: Path, device: str) -> torch.nn.Module:
    return load_checkpoint(checkpoint, torch.device(device))[0]


class ViewRenderer:
    """Renders target cameras of a normalised scene from their nearest reference views, caching encodings.

    Args:
        model: the generator; scene: the normalised Scene; size: (height, width) of the rendered images.
        views: reference views per image (a render() call may ask for another count).
        device, chunk, exact: as in RenderConfig (chunk None = DEFAULT_CHUNKS of the device; exact replaces
            ``options.shortcuts`` with EXACT).
        sfm_depth: guide the fine samples by the scene's SfM points where it has them (depth_prior.view_prior:
            the points that two views outside a frame's ``exclude`` and one of its nearest references observe),
            blend the references at that depth where they agree there (prior_blend), and, where the points say
            which views observe them, let a reference whose own points put a nearer surface in front of a sample
            stop seeing it (model.occlusion).
        options: the render path's tuned numbers (RenderOptions).
    """

    def __init__(self, model: torch.nn.Module, scene: Scene, size: tuple[int, int], views: int, device: str = "cpu",
                 chunk: int | None = None, exact: bool = False, sfm_depth: bool = True,
                 options: RenderOptions = RenderOptions()) -> None:
        self.model = model
        self.scene, self.size, self.k = scene, size, views
        self.options = replace(options, shortcuts=EXACT) if exact else options
        self.colour_size = colour_size(size, (scene.cameras.height, scene.cameras.width), options.colours.scale)
        self.chunk = chunk or DEFAULT_CHUNKS.get(torch.device(device).type, DEFAULT_CHUNKS["cpu"])
        self.method = view_rule(scene.layout)
        self.object_centric = scene.layout != "forward"  # prior_blend's background plane: these captures only
        self.cache: OrderedDict[int, EncodedViews] = OrderedDict()  # view index -> its EncodedViews (1)
        self.sfm_depth = sfm_depth and scene.points is not None
        self.occlusion = self.sfm_depth and scene.points.observed is not None
        self.maps: dict[int, torch.Tensor] = {}  # view index -> its occlusion map, for the views of maps_pool
        self.maps_pool: tuple[int, ...] = ()
        self.maps_tracked: torch.Tensor | None = None  # [P] bool: depth_prior.well_tracked of maps_pool

    def references(self, target_c2w: torch.Tensor, exclude: list[int], views: int | None = None) -> list[int]:
        refs = nearest_views(target_c2w, self.scene.cameras.c2w, views or self.k, self.method, exclude=exclude)
        if not refs:
            raise UserError(f"{self.scene.root}: no reference views left to render from")
        return refs

    def _encoded(self, refs: list[int]) -> EncodedViews:
        key = sorted(refs)
        missing = [i for i in key if i not in self.cache]
        if missing:
            finer = [] if self.colour_size is None else [self.colour_size]
            images, *photos = self.scene.load_sizes(missing, [self.size, *finer])  # [V, H, W, 3], [V, Hc, Wc, 3]
            param = next(self.model.parameters())
            cams = self.scene.cameras.subset(missing).rescale(*self.size)
            views = SourceViews(images, cams).to(device=param.device, dtype=param.dtype)
            with torch.inference_mode():
                encoded = self.model.encode(views)
            if photos:
                encoded = encoded.with_colours(photos[0].permute(0, 3, 1, 2))
            for row, index in enumerate(missing):
                self.cache[index] = encoded.select([row])
        for index in key:
            self.cache.move_to_end(index)
        while len(self.cache) > ENCODED_VIEWS_KEPT * max(self.k, len(key)):
            self.cache.popitem(last=False)
        return EncodedViews.join([self.cache[i] for i in key])

    def render(self, camera: Cameras, near: float, far: float, exclude: list[int],
               views: int | None = None) -> tuple[ImageOutput, list[int]]:
        """(ImageOutput of ``camera`` (1), the reference indices used) from its ``views`` (default: the
        renderer's count) nearest references; never uses an index in ``exclude``. The samples lie within
        ``near`` and far_bound(): ``far``, raised where the frame's SfM points lie past it. The references'
        blend at the SfM depth is mixed into the pixels a point lands on, by how well they agree there against
        the rendered depth, and taken where a filled pixel's agree much better (prior_blend)."""
        opts = self.options
        refs = self.references(camera.c2w[0], exclude, views)
        prior, splatted = self._prior_splats(camera, refs, exclude) or (None, None)
        encoded, far = self._encoded(refs), covering_far(far, prior, opts.prior, opts.guide)
        if self.occlusion:
            encoded = encoded.with_occlusion(self._occlusion(sorted(refs), exclude))
        frame = render_image(self.model, encoded, camera, near, far, self.chunk, opts.shortcuts, prior, opts.guide)
        if prior is not None:
            frame = blend_at_prior(frame, encoded, camera, prior, far, splatted, self.object_centric, opts.blend,
                                   opts.prior)
        return frame, refs

    def far_bound(self, camera: Cameras, far: float, exclude: list[int], views: int | None = None) -> float:
        """The far bound render() draws ``camera``'s samples within: ``far``, raised where the frame's SfM points lie
        past it (depth_prior.covering_far), so that a caller can size its depth files before the frames exist."""
        refs = self.references(camera.c2w[0], exclude, views)
        return covering_far(far, self._prior(camera, refs, exclude), self.options.prior, self.options.guide)

    def _occlusion(self, refs: list[int], exclude: list[int]) -> Occlusion:
        """The Occlusion of ``refs`` (in this order; as _encoded orders them), their maps made from the points the
        views not in ``exclude`` track (occlusion_maps.reference_map), kept while ``exclude`` stays the same."""
        opts = self.options
        left = set(exclude)
        pool = tuple(i for i in range(len(self.scene)) if i not in left)
        if pool != self.maps_pool:
            self.maps, self.maps_pool = {}, pool
            self.maps_tracked = well_tracked(self.scene.points, pool, opts.prior)
        size = self.scene.size_for(opts.occlusion.map_size)
        for view in refs:
            if view not in self.maps:
                camera = self.scene.cameras.subset([view]).rescale(*size)
                self.maps[view] = reference_map(self.scene.points, camera, view, self.maps_tracked, opts.prior)
        param = next(self.model.parameters())
        return occlusion([self.maps[v] for v in refs], self.scene.cameras.subset(refs), opts.occlusion).to(param)

    def _prior(self, camera: Cameras, refs: list[int], exclude: list[int]) -> torch.Tensor | None:
        """[H, W] the SfM depth prior of ``camera``, or None: _prior_splats' depth."""
        found = self._prior_splats(camera, refs, exclude)
        return None if found is None else found[0]

    def _prior_splats(self, camera: Cameras, refs: list[int],
                      exclude: list[int]) -> tuple[torch.Tensor, torch.Tensor] | None:
        """([H, W] the SfM depth prior of ``camera``, [H, W] bool its pixels a point's own splat covers), or None:
        depth_prior.view_prior_splats of the frame's references ``refs`` (nearest first), its tracks counted over
        the views not in ``exclude`` (so eval's held-out photo lends no observation)."""
        if not self.sfm_depth:
            return None
        left = set(exclude)
        return view_prior_splats(self.scene.points, camera, refs,
                                 [i for i in range(len(self.scene)) if i not in left], self.options.prior)
