"""What fine-tuning trains on: one scene's own photos minus the views `insertnerf eval` holds out.

The scene is read, normalised and sized exactly as `render`/`eval` do (training.data.prepare_scene uses
scenes.normalize_scene and Scene.size_for), and the held-out views are views.held_out_views (the test split,
else every 8th view). Those views are removed from the pool the draws pick targets and sources from, so a
fine-tuned checkpoint never saw them and `eval` on it stays an honest score.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from insertnerf_cli.errors import UserError
from insertnerf_cli.model import EncodedViews, InsertNeRF, SourceViews
from insertnerf_cli.rendering.view_renderer import colour_size
from insertnerf_cli.scenes.views import held_out_views, nearest_views
from insertnerf_cli.sfm.depth_prior import PriorOptions, covering_far, view_prior
from insertnerf_cli.training.data import ImageCache, TrainScene, ViewDraw, draw_training_views, prepare_scene, to_uint8

# Views encoded at once when the frozen encoder's features are precomputed (bounds peak memory).
_ENCODE_BATCH = 8


def finetune_scene(scene_dir: Path, resolution: int | None) -> TrainScene:
    """The normalised scene at ``resolution`` (long side; None = full size) with train_ids = the views fine-tuning
    may use and test_ids = the views eval holds out."""
    scene = prepare_scene(Path(scene_dir), resolution, Path(scene_dir).name)
    held = held_out_views(scene.scene)
    usable = tuple(i for i in range(len(scene.scene)) if i not in set(held))
    if len(usable) < 2:
        raise UserError(f"{scene_dir}: only {len(usable)} view(s) are left after holding out eval's {len(held)}; "
                        "fine-tuning needs at least 2 (a target and a source).")
    return dataclasses.replace(scene, train_ids=usable, test_ids=tuple(held))


def draw(rng: np.random.Generator, scene: TrainScene, views: int, rays: int) -> ViewDraw:
    """One target view, its source views and ``rays`` target pixels, all from ``scene.train_ids`` (training's rule:
    sources drawn from a pool of the target's nearest views)."""
    return draw_training_views(rng, [scene], views, rays)


class FrozenFeatures:
    """U-Net features of every usable view, computed once: with the encoder frozen a step only gathers them.

    The encoder treats each image on its own (no normalisation across views), so the features of a view are the
    same whichever other views it is encoded with.
    """

    def __init__(self, model: InsertNeRF, scene: TrainScene, cache: ImageCache, colour_scale: float = 1.0) -> None:
        self.position = {index: p for p, index in enumerate(scene.train_ids)}
        photo = (scene.scene.cameras.height, scene.scene.cameras.width)
        finer = colour_size((scene.cameras.height, scene.cameras.width), photo, colour_scale)
        parts = []
        with torch.no_grad():
            for start in range(0, len(scene.train_ids), _ENCODE_BATCH):
                ids = list(scene.train_ids[start:start + _ENCODE_BATCH])
                colours = None
                if finer is None:
                    stored = [cache.get(scene, i) for i in ids]
                else:  # FinetuneConfig.colour_scale > 1: colours from the photos at a finer size, one decode each
                    small, colours = scene.scene.load_sizes(ids, [(scene.cameras.height, scene.cameras.width), finer])
                    stored = [cache.put(scene, i, to_uint8(image)) for i, image in zip(ids, small)]
                images = torch.stack(stored).to(torch.float32) / 255.0  # [V, H, W, 3]
                views = SourceViews(images, scene.cameras.subset(ids)).to(device=model.background.device)
                encoded = model.encode(views)
                if colours is not None:
                    encoded = encoded.with_colours(colours.permute(0, 3, 1, 2))
                parts.append(encoded)
        self.all = EncodedViews.join(parts)

    def select(self, indices: tuple[int, ...]) -> EncodedViews:
        """The encoded views of scene view ``indices`` (in that order); no backbone reconstruction."""
        return self.all.select([self.position[i] for i in indices])


class TargetPriors:
    """The SfM depth prior of every usable view at the fine-tuning size, made once, so that each step's fine
    samples are placed as render places them (depth_prior): a gain on some captures and no loss on others
    (measured: docs/research-log.md, Fine-tuning).

    A view's prior is made as render makes a novel view's: from the points two of its PriorOptions.views nearest other
    usable views observe, never from the view's own observations. ``far`` [N] holds the scene's far bounds, each
    usable view's raised where its points lie past it, as render raises a frame's (depth_prior.covering_far).
    """

    def __init__(self, scene: TrainScene, device: torch.device) -> None:
        self.flat: dict[int, torch.Tensor | None] = {}
        self.far = scene.far.clone()
        points = scene.scene.points
        for target in scene.train_ids:
            others = [i for i in scene.train_ids if i != target]
            prior = None
            if points is not None and others:
                order = nearest_views(scene.cameras.c2w[target], scene.cameras.c2w[others], PriorOptions().views,
                                      scene.method)
                prior = view_prior(points, scene.cameras.subset([target]), [others[i] for i in order], others)
                self.far[target] = covering_far(float(scene.far[target]), prior)
            self.flat[target] = None if prior is None else prior.reshape(-1).to(device, torch.float32)  # [H * W]

    def guide(self, target: int, pixels: torch.Tensor) -> torch.Tensor | None:
        """[R] the prior depth at the target's flat pixel indices ``pixels`` [R] (NaN where none), or None."""
        prior = self.flat.get(target)
        return None if prior is None else prior[pixels.to(prior.device)]
