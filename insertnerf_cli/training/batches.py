"""Several scenes per step, drawn on the training device: B target views from B different scenes of one image
size, each with its own V source views (the nearest-pool rule of views.sample_training_views) and R / B pixels.

Every draw comes from one seeded ``torch.Generator`` on the training device, so a step needs no host round
trip; a second generator on the host picks the image-size group (only when the set has several sizes).
"""
from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor, nn

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.cameras.rays import Rays, rays_from_pixels
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import InsertNeRF, LossTerms, SourceViews
from insertnerf_cli.model.types import EncodedViews
from insertnerf_cli.scenes.views import ViewSampling
from insertnerf_cli.training.data import ImageCache, TrainBatch
from insertnerf_cli.training.device_data import SizeGroup, TrainingSet, gather_depths, gather_images
from insertnerf_cli.training.feature_prior import FeaturePriors
from insertnerf_cli.training.guide import simulated_prior

_LEVELS = 255.0
_SEED_LIMIT = 1 << 63


@dataclass(frozen=True)
class StepDraw:
    """One step's draw from size group ``group``: B scenes, their targets, sources and target pixels.

    Attributes:
        scenes: [B] int64 rows of the group (distinct); targets: [B] flat view ids; sources: [B, V] flat view
        ids; pixels: [B, R / B] int64 flat pixel indices into H * W of each target.
    """

    group: int
    scenes: Tensor
    targets: Tensor
    sources: Tensor
    pixels: Tensor


class DrawGenerators:
    """The step draws' generators: ``device`` (on the training device) and ``host`` (the size group)."""

    def __init__(self, device: torch.device, seed: int, *stream: int) -> None:
        self.device = torch.Generator(device=device)
        self.host = torch.Generator()
        self.reseed(seed, *stream)

    def reseed(self, seed: int, *stream: int) -> None:
        words = np.random.SeedSequence([seed, *stream, 9]).generate_state(4, np.uint64)
        self.device.manual_seed(int(words[0]) % _SEED_LIMIT)
        self.host.manual_seed(int(words[1]) % _SEED_LIMIT)

    def state(self) -> dict[str, Tensor]:
        return {"draw_device": self.device.get_state(), "draw_host": self.host.get_state()}

    def load_state(self, states: dict[str, Tensor]) -> bool:
        """Restore a saved state; False when the checkpoint has none (written before these generators)."""
        if "draw_device" not in states:
            return False
        self.device.set_state(states["draw_device"].to(torch.uint8))
        self.host.set_state(states["draw_host"].to(torch.uint8))
        return True


def check_batch_scenes(data: TrainingSet, batch_scenes: int, rays: int) -> list[int]:
    """The groups a step can draw from (at least B scenes); a UserError message when none can."""
    if rays % batch_scenes:
        raise UserError(f"--rays {rays} must be a multiple of --batch-scenes {batch_scenes} (rays per scene).")
    usable = [i for i, g in enumerate(data.groups) if len(g.scenes) >= batch_scenes]
    if not usable:
        most = max(len(g.scenes) for g in data.groups)
        raise UserError(f"--batch-scenes {batch_scenes} needs that many training scenes of one image size; the "
                        f"largest group has {most}: lower --batch-scenes.")
    return usable


def draw_step(data: TrainingSet, usable: list[int], gens: DrawGenerators, batch_scenes: int, num_views: int,
              rays: int, sampling: ViewSampling = ViewSampling()) -> StepDraw:
    """A step's draw; the same distribution per scene as data.draw_training_views, made on the device."""
    index = 0
    if len(usable) > 1:  # a size group in proportion to its scenes
        counts = torch.tensor([float(len(data.groups[i].scenes)) for i in usable])
        index = int(torch.multinomial(counts, 1, generator=gens.host))
    g, gen, dev = data.groups[usable[index]], gens.device, data.device
    scenes = torch.randperm(len(g.scenes), generator=gen, device=dev)[:batch_scenes]  # [B]
    n = g.n_train[scenes]  # [B]
    target = (torch.rand(batch_scenes, generator=gen, device=dev) * n).long().clamp(max=n - 1)  # [B]
    factors, cumulative = _pool_rule(sampling, dev)
    pick = torch.searchsorted(cumulative, torch.rand(batch_scenes, generator=gen, device=dev), right=True)
    factor = factors[pick.clamp(max=len(factors) - 1)]  # [B] drawn with pool_probs
    pool = torch.minimum(factor * num_views, torch.full_like(factor, sampling.max_pool))
    pool = torch.minimum(pool.clamp(min=num_views), n - 1)  # [B] pool sizes, as sample_training_views
    order = g.neighbours[scenes, target]  # [B, N - 1] positions, nearest first
    keys = torch.rand(order.shape, generator=gen, device=dev)
    keys = torch.where(torch.arange(order.shape[1], device=dev) < pool[:, None], keys, 2.0)
    chosen = order.gather(1, keys.argsort(dim=1)[:, :num_views])  # [B, V] a uniform subset of the pool
    keep = torch.rand(batch_scenes, generator=gen, device=dev) < sampling.keep_target_prob
    slot = torch.randint(num_views, (batch_scenes, 1), generator=gen, device=dev)
    swap = keep[:, None] & (torch.arange(num_views, device=dev) == slot)
    chosen = torch.where(swap, target[:, None], chosen)
    pixels = torch.randint(g.height * g.width, (batch_scenes, rays // batch_scenes), generator=gen, device=dev)
    base = g.offsets[scenes]
    return StepDraw(usable[index], scenes, base + target, base[:, None] + chosen, pixels)


@lru_cache(maxsize=8)
def _pool_rule(sampling: ViewSampling, device: torch.device) -> tuple[Tensor, Tensor]:
    """The pool factors and their cumulative probabilities on the device, made once (a copy per step would be a
    sync; so might multinomial's checks, hence the inverse-CDF draw)."""
    return (torch.tensor(sampling.pool_factors, device=device),
            torch.tensor(sampling.pool_probs, dtype=torch.float64, device=device).cumsum(0).float())


def make_step_batch(data: TrainingSet, draw: StepDraw, cache: ImageCache,
                    priors: FeaturePriors | None = None) -> TrainBatch:
    """The model inputs of a step on the training device: B * V source views, B * R / B rays and colours (and
    with ``priors`` each ray's prior depth from its sources' features)."""
    g: SizeGroup = data.groups[draw.group]
    batch, per_scene = draw.pixels.shape
    images = gather_images(data, g, torch.cat([draw.sources, draw.targets[:, None]], dim=1), cache)
    sources = images[:, :-1].reshape(-1, g.height, g.width, 3).float() / _LEVELS  # [B * V, H, W, 3]
    flat_targets = images[:, -1].reshape(batch, -1, 3)  # [B, H * W, 3]
    target_rgb = flat_targets.gather(1, draw.pixels[..., None].expand(-1, -1, 3)).float() / _LEVELS
    uv = torch.stack([draw.pixels % g.width, draw.pixels // g.width], dim=-1).float() + 0.5  # [B, R / B, 2]
    t, s = draw.targets, draw.sources.reshape(-1)
    rays = rays_from_pixels(Cameras(g.K[t], g.c2w[t], g.height, g.width), uv, g.near[t], g.far[t])
    views = SourceViews(sources, Cameras(g.K[s], g.c2w[s], g.height, g.width))
    depth = gather_depths(data, g, t, draw.pixels).reshape(-1) if data.with_depth else None  # [B * R / B]
    guide = None if priors is None else priors.step_prior(draw.group, t, draw.sources, draw.pixels)
    return TrainBatch(views, rays, target_rgb.reshape(batch * per_scene, 3), depth, guide)


def encoded_group(encoded: EncodedViews, index: int, size: int) -> EncodedViews:
    """Views [index * size, (index + 1) * size) of a batch of encoded views: one scene's sources."""
    part = slice(index * size, (index + 1) * size)
    recon = None if encoded.reconstruction is None else encoded.reconstruction[part]
    return replace(encoded, features=tuple(f[part] for f in encoded.features), images=encoded.images[part],
                   projection=encoded.projection[part], centers=encoded.centers[part], reconstruction=recon)


class BatchObjective(nn.Module):
    """The training loss of B scenes: one encoder pass over all B * V source views, then each scene's rays
    rendered from its own V views; the loss terms are the means over the B scenes (equal ray counts, so the
    colour terms equal the mean over all rays). B = 1 is exactly session.Objective."""

    def __init__(self, model: InsertNeRF, guided: bool = False) -> None:
        super().__init__()
        self.model = model
        self.guided = guided  # fine samples guided by a prior simulated from the true depth (training/guide.py)

    def forward(self, views: SourceViews, rays: Rays, target_rgb: Tensor, scenes: int,
                target_depth: Tensor | None = None, guide: Tensor | None = None) -> LossTerms:
        """Loss terms of B = ``scenes`` scenes; ``target_depth`` [R] true depths (None: no depth term);
        ``guide`` [R] the batch's own prior depths (feature priors), which replace the simulated one."""
        encoded = self.model.encode(views)
        per_view, per_ray = len(views) // scenes, len(rays) // scenes
        terms = []
        for b in range(scenes):
            part = encoded_group(encoded, b, per_view)
            chunk = slice(b * per_ray, (b + 1) * per_ray)
            depth = None if target_depth is None else target_depth[chunk]
            if guide is not None:
                ray_guide = guide[chunk]
            else:
                ray_guide = simulated_prior(depth) if self.guided and depth is not None else None
            output = self.model(part, rays[chunk], train=True, guide=ray_guide)
            terms.append(self.model.losses(output, target_rgb[chunk], part, rays[chunk], depth))
        if scenes == 1:
            return terms[0]
        return LossTerms(*(torch.stack(column).mean() for column in zip(*(astuple_shallow(t) for t in terms))))


def astuple_shallow(terms: LossTerms) -> tuple[Tensor, ...]:
    """The loss terms in field order (dataclasses.astuple would deep-copy the tensors)."""
    return tuple(getattr(terms, f.name) for f in fields(terms))


class StepStream:
    """The steps' draws and batches, in order; with ``views_min`` each step draws its number of source views
    uniformly from views_min..num_views (on the host generator, so --resume draws the same).

    With the images on the device a step is drawn and gathered when asked for. Streamed from disk, the next
    step is drawn one step ahead and its images read on a worker thread (into the stream's own ImageCache)
    while the current step computes: a prefetch of one step. The generator state a checkpoint needs is the one
    before that look-ahead draw, so --resume makes the same draw again.
    """

    def __init__(self, data: TrainingSet, usable: list[int], generators: DrawGenerators, batch_scenes: int,
                 num_views: int, rays: int, cache_bytes: int, views_min: int | None = None,
                 priors: FeaturePriors | None = None) -> None:
        self.data, self.usable, self.generators = data, usable, generators
        self.priors = priors
        self.shape = (batch_scenes, num_views, rays)
        self.views_min = views_min
        self._cache = ImageCache(cache_bytes)
        self._pool = None if data.resident else ThreadPoolExecutor(max_workers=1)
        self._pending: tuple[dict[str, Tensor], StepDraw, Future] | None = None

    def next(self) -> tuple[StepDraw, TrainBatch]:
        if self._pool is None:
            draw = self._draw()
            return draw, make_step_batch(self.data, draw, self._cache, self.priors)
        if self._pending is None:
            self._pending = self._prefetch()
        _, draw, batch = self._pending
        self._pending = self._prefetch()
        return draw, batch.result()

    def state(self) -> dict[str, Tensor]:
        """The generator state that reproduces the next step."""
        return self._pending[0] if self._pending is not None else self.generators.state()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def _draw(self) -> StepDraw:
        batch_scenes, num_views, rays = self.shape
        if self.views_min is not None:  # a count per step, so that any count a user asks for was seen in training
            num_views = int(torch.randint(self.views_min, num_views + 1, (1,), generator=self.generators.host))
        return draw_step(self.data, self.usable, self.generators, batch_scenes, num_views, rays)

    def _prefetch(self) -> tuple[dict[str, Tensor], StepDraw, Future]:
        assert self._pool is not None
        before = {k: v.clone() for k, v in self.generators.state().items()}
        draw = self._draw()
        return before, draw, self._pool.submit(make_step_batch, self.data, draw, self._cache, self.priors)
