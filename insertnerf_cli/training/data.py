"""Training data: the scenes of a dataset folder, the hold-out split, an image cache and the per-step draw.

Each step draws one scene, one target view of it, its source views from the pool of nearest views
(views.sample_training_views) and a random batch of the target's pixels.
"""
from __future__ import annotations

import sys
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.cameras.rays import Rays, rays_from_pixels
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import SourceViews
from insertnerf_cli.scenes import Scene, load_scene, normalize_scene
from insertnerf_cli.scenes.views import ViewMethod, nearest_views, sample_training_views

Say = Callable[[str], None]
_LEVELS = 255.0  # images are cached as uint8


@dataclass(frozen=True)
class TrainScene:
    """One normalised scene at the training resolution.

    Attributes:
        name: folder name inside the dataset.
        scene: the normalised Scene (images are read from its files).
        cameras: all N cameras, float32, rescaled to the training size.
        near, far: [N] float32 bounds.
        train_ids, test_ids: the scene's view splits.
        method: view-distance rule for its layout ("vector" object-centric, "dist" forward-facing).
    """

    name: str
    scene: Scene
    cameras: Cameras
    near: Tensor  # [N]
    far: Tensor  # [N]
    train_ids: tuple[int, ...]
    test_ids: tuple[int, ...]
    method: ViewMethod


@dataclass(frozen=True)
class TrainBatch:
    """What one step feeds the model: source views, rays of the target, their colours and (when the loss uses
    depth) their true depths (training/depth.py: 0 no surface, NaN unknown)."""

    views: SourceViews  # images [V, H, W, 3]
    rays: Rays  # [R]
    target_rgb: Tensor  # [R, 3]
    target_depth: Tensor | None = None  # [R]
    guide: Tensor | None = None  # [R] a prior depth per ray made from features (training/feature_prior.py)

    def to(self, device: torch.device) -> "TrainBatch":
        depth = None if self.target_depth is None else self.target_depth.to(device)
        guide = None if self.guide is None else self.guide.to(device)
        return TrainBatch(self.views.to(device), self.rays.to(device), self.target_rgb.to(device), depth, guide)


@dataclass(frozen=True)
class ViewDraw:
    """One target view, its sources and the target pixels (flat indices into H * W) of one scene."""

    scene: int
    target: int
    sources: tuple[int, ...]
    pixels: Tensor  # [R] int64


def prepare_scene(path: Path, resolution: int, name: str) -> TrainScene:
    """Load, normalise and size one scene folder; raises UserError (SceneError) when it cannot be read."""
    scene, _ = normalize_scene(load_scene(path))
    height, width = scene.size_for(resolution)
    cameras = scene.cameras.rescale(height, width).to(dtype=torch.float32)
    test = tuple(scene.split("test"))
    train = tuple(scene.split("train"))
    method: ViewMethod = "dist" if scene.layout == "forward" else "vector"
    return TrainScene(name, scene, cameras, scene.near.to(torch.float32), scene.far.to(torch.float32),
                      train, test, method)


def find_scenes(dataset_dir: Path, resolution: int, say: Say, show_progress: bool = True) -> list[TrainScene]:
    """Every scene folder directly inside ``dataset_dir`` (or the folder itself when it is one scene).

    Folders that are not scenes are skipped with a warning; no readable scene at all is a UserError.
    """
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise UserError(f"dataset folder {dataset_dir} does not exist; make one with `insertnerf synth OUT`.")
    try:
        return [prepare_scene(dataset_dir, resolution, dataset_dir.name)]
    except UserError:
        pass  # not a scene itself: a folder of scenes
    try:
        folders = sorted(p for p in dataset_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError as err:
        raise UserError(f"dataset folder {dataset_dir} cannot be listed ({err.strerror}).") from None
    scenes, skipped = [], []
    for folder in tqdm(folders, desc="reading scenes", unit="scene", file=sys.stderr, leave=False,
                       disable=not show_progress):
        try:
            scenes.append(prepare_scene(folder, resolution, folder.name))
        except (UserError, ValueError) as err:  # ValueError: malformed camera data a reader passed on
            skipped.append(folder.name)
            say(f"skipping {folder.name}: {err}")
    if not scenes:
        what = f"{len(skipped)} folder(s) could not be read" if skipped else "it has no scene folders"
        raise UserError(f"no readable scene in {dataset_dir} ({what}); make a dataset with "
                        "`insertnerf synth OUT --scenes N` or point at a folder of scene folders.")
    return scenes


def split_scenes(scenes: list[TrainScene], val_scenes: int, seed: int) -> tuple[list[TrainScene], list[TrainScene]]:
    """(training, held-out) scenes: min(val_scenes, half the dataset) held out, chosen by ``seed``."""
    held = min(val_scenes, len(scenes) // 2)
    order = np.random.default_rng([seed, len(scenes)]).permutation(len(scenes))
    val = sorted(int(i) for i in order[:held])
    return [s for i, s in enumerate(scenes) if i not in val], [scenes[i] for i in val]


def check_view_counts(train: list[TrainScene], val: list[TrainScene], num_views: int) -> None:
    """A training scene needs num_views + 1 training views (sources + target); a held-out one num_views."""
    for scene, need in [(s, num_views + 1) for s in train] + [(s, num_views) for s in val]:
        if len(scene.train_ids) < need:
            raise UserError(f"scene {scene.name} has {len(scene.train_ids)} training views but {num_views} source "
                            f"views need {need}; lower --views or remove the scene from the dataset.")


class ImageCache:
    """Training-size images as uint8 [H, W, 3], least recently used dropped beyond a byte budget."""

    def __init__(self, budget_bytes: int) -> None:
        self.budget = budget_bytes
        self.used = 0
        self._images: OrderedDict[tuple[str, int], Tensor] = OrderedDict()

    def get(self, scene: TrainScene, index: int) -> Tensor:
        key = (scene.name, index)
        if key in self._images:
            self._images.move_to_end(key)
            return self._images[key]
        return self.put(scene, index, decode_uint8(scene, index))

    def put(self, scene: TrainScene, index: int, stored: Tensor) -> Tensor:
        """Keep ``stored`` (uint8 [H, W, 3], as decode_uint8 gives it) as image ``index`` of the scene; returns it."""
        key = (scene.name, index)
        if key in self._images:
            self.used -= self._images.pop(key).numel()
        self._images[key] = stored
        self.used += stored.numel()
        while self.used > self.budget and len(self._images) > 1:
            _, dropped = self._images.popitem(last=False)
            self.used -= dropped.numel()
        return stored


def decode_uint8(scene: TrainScene, index: int) -> Tensor:
    """Image ``index`` of the scene at the training size as uint8 [H, W, 3]."""
    image = scene.scene.load_image(index, scene.cameras.height, scene.cameras.width)  # float32 [H, W, 3]
    return to_uint8(image)


def to_uint8(image: np.ndarray | Tensor) -> Tensor:
    """float RGB in [0, 1] [..., 3] -> the uint8 levels the cache stores."""
    image = np.asarray(image)
    return torch.from_numpy(np.rint(np.clip(image, 0.0, 1.0) * _LEVELS).astype(np.uint8))


def make_batch(scene: TrainScene, cache: ImageCache, draw: ViewDraw) -> TrainBatch:
    """The model inputs of one draw (CPU, float32)."""
    width = scene.cameras.width
    sources = list(draw.sources)
    images = torch.stack([cache.get(scene, i) for i in sources]).to(torch.float32) / _LEVELS  # [V, H, W, 3]
    target = cache.get(scene, draw.target).reshape(-1, 3)[draw.pixels].to(torch.float32) / _LEVELS  # [R, 3]
    rows, cols = draw.pixels // width, draw.pixels % width
    uv = torch.stack([cols, rows], dim=-1).to(torch.float32) + 0.5  # [R, 2] pixel centres
    t = [draw.target]
    rays = rays_from_pixels(scene.cameras.subset(t), uv[None], scene.near[t], scene.far[t])
    return TrainBatch(SourceViews(images, scene.cameras.subset(sources)), rays, target)


def draw_training_views(rng: np.random.Generator, scenes: list[TrainScene], num_views: int, rays: int) -> ViewDraw:
    """A random scene, target view, source views (nearest-pool rule) and ``rays`` random target pixels."""
    s = int(rng.integers(len(scenes)))
    scene = scenes[s]
    ids = scene.train_ids
    target_pos = int(rng.integers(len(ids)))
    c2w = scene.cameras.c2w[list(ids)]  # [N_train, 4, 4]
    sources = sample_training_views(rng, target_pos, c2w, num_views, scene.method)
    pixels = torch.from_numpy(rng.integers(0, scene.cameras.height * scene.cameras.width, size=rays))
    return ViewDraw(s, ids[target_pos], tuple(ids[i] for i in sources), pixels)


def validation_draws(scenes: list[TrainScene], num_views: int, rays: int, seed: int) -> list[ViewDraw]:
    """One fixed unseen target view per scene (from its test split) with its nearest training views as
    sources, as at test time, and a fixed set of ``rays`` pixels."""
    rng = np.random.default_rng([seed, 1])  # its own stream: validation never shifts the training draws
    draws = []
    for s, scene in enumerate(scenes):
        if not scene.test_ids:
            continue  # a scene whose format has an empty test split cannot validate
        target = scene.test_ids[int(rng.integers(len(scene.test_ids)))]
        candidates = [i for i in scene.train_ids if i != target]
        near = nearest_views(scene.cameras.c2w[target], scene.cameras.c2w[candidates], num_views, scene.method)
        pixels = torch.from_numpy(rng.integers(0, scene.cameras.height * scene.cameras.width, size=rays))
        draws.append(ViewDraw(s, target, tuple(candidates[i] for i in near), pixels))
    return draws
