"""The training set as tensors: every training view decoded once to uint8 at the training resolution, with
its camera and bounds, grouped by image size (the scenes of one step are encoded as one batch of one size).

A set that fits ``TrainConfig.data_budget_mb`` is decoded up front, on the machine's cores, and kept on the
training device, so a step gathers its images by indexing a tensor there. A larger set stays on disk and each
step reads its views through the LRU ImageCache (pinned and copied without blocking on CUDA): the draws are the
same, so training is the same, only slower.
"""
from __future__ import annotations

import os
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import torch
from torch import Tensor
from tqdm import tqdm

from insertnerf_cli.scenes.views import nearest_views
from insertnerf_cli.training.data import ImageCache, Say, TrainScene, decode_uint8
from insertnerf_cli.training.depth import decode_depth

_BYTES_PER_MB = 1 << 20
# Bytes of a view's float32 depth map per byte of its uint8 RGB image.
_DEPTH_PER_IMAGE_BYTE = torch.finfo(torch.float32).bits / 8 / 3


@dataclass(frozen=True)
class SizeGroup:
    """The training scenes of one image size H x W; their T training views flattened scene by scene.

    Attributes:
        scenes: indices into the training scene list, one per group scene (S); scene_index: the same as an
            int64 [S] tensor on the training device.
        offsets: [S] int64 flat index of each scene's first training view; n_train: [S] its number of views.
        neighbours: [S, N, N - 1] int64: for each target position, the positions of the scene's other training
            views, nearest first (views.nearest_views); padding beyond n_train - 1 is never drawn.
        K, c2w: [T, 3, 3], [T, 4, 4] float32 cameras at the training size; near, far: [T] float32 bounds.
        images: [T, H, W, 3] uint8 on the training device, or None when the set is streamed from disk.
        depths: [T, H, W] float32 true depths on the training device (training/depth.py: 0 no surface, NaN
            unknown) when the loss uses depth and the set is resident, else None.
        views: (scene index into the training list, image index in that scene) of each flat view (host).
    """

    height: int
    width: int
    scenes: tuple[int, ...]
    scene_index: Tensor
    offsets: Tensor
    n_train: Tensor
    neighbours: Tensor
    K: Tensor
    c2w: Tensor
    near: Tensor
    far: Tensor
    images: Tensor | None
    views: tuple[tuple[int, int], ...]
    depths: Tensor | None = None

    @property
    def nbytes(self) -> int:
        return len(self.views) * self.height * self.width * 3


@dataclass(frozen=True)
class TrainingSet:
    """Every training scene as tensors, by image size; ``resident`` is False when images stream from disk;
    ``with_depth``: steps carry the targets' true depths."""

    groups: tuple[SizeGroup, ...]
    scenes: tuple[TrainScene, ...]
    resident: bool
    device: torch.device
    with_depth: bool = False


def load_training_set(scenes: list[TrainScene], budget_mb: int, device: torch.device, say: Say,
                      show_progress: bool = True, with_depth: bool = False) -> TrainingSet:
    """Group the scenes by size, build their view tables and decode their images (and with ``with_depth`` their
    true depths, 4 bytes a pixel more) when they fit the budget."""
    by_size: dict[tuple[int, int], list[int]] = {}
    for i, scene in enumerate(scenes):
        by_size.setdefault((scene.cameras.height, scene.cameras.width), []).append(i)
    groups = [_group(scenes, members, device) for members in by_size.values()]
    total = sum(g.nbytes for g in groups) * (1.0 + (_DEPTH_PER_IMAGE_BYTE if with_depth else 0.0))
    if total > budget_mb * _BYTES_PER_MB:
        say(f"the training images need {total / _BYTES_PER_MB:,.0f} MB, more than --data-budget-mb {budget_mb}: "
            "reading them from disk each step (slower); raise the budget if memory allows.")
        return TrainingSet(tuple(groups), tuple(scenes), False, device, with_depth)
    jobs = [(scenes[s], i) for g in groups for s, i in g.views]

    def decode(job: tuple[TrainScene, int]) -> tuple[Tensor, Tensor | None]:
        return decode_uint8(*job), decode_depth(*job) if with_depth else None

    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:  # decoders release the GIL
        decoded = list(tqdm(pool.map(decode, jobs), total=len(jobs), unit="view",
                            desc="decoding training views", file=sys.stderr, leave=False,
                            disable=not show_progress))
    start, filled = 0, []
    for g in groups:
        part = decoded[start:start + len(g.views)]
        images = torch.stack([image for image, _ in part]).to(device)  # [T, H, W, 3] uint8
        depths = torch.stack([depth for _, depth in part]).to(device) if with_depth else None  # [T, H, W]
        start += len(g.views)
        filled.append(replace(g, images=images, depths=depths))
    return TrainingSet(tuple(filled), tuple(scenes), True, device, with_depth)


def _group(scenes: list[TrainScene], members: list[int], device: torch.device) -> SizeGroup:
    """The view tables of the scenes ``members`` (all of one image size), images not yet decoded."""
    counts = [len(scenes[s].train_ids) for s in members]
    width = max(counts) - 1
    neighbours = torch.zeros(len(members), max(counts), max(width, 1), dtype=torch.int64)
    K, c2w, near, far, views = [], [], [], [], []
    for row, s in enumerate(members):
        scene, ids = scenes[s], list(scenes[s].train_ids)
        poses = scene.cameras.c2w[ids]  # [n, 4, 4]
        for t in range(len(ids)):
            order = nearest_views(poses[t], poses, len(ids) - 1, scene.method, exclude=[t])
            neighbours[row, t, : len(order)] = torch.tensor(order, dtype=torch.int64)
        K.append(scene.cameras.K[ids])
        c2w.append(scene.cameras.c2w[ids])
        near.append(scene.near[ids])
        far.append(scene.far[ids])
        views.extend((s, i) for i in ids)
    offsets = torch.tensor([0, *counts[:-1]], dtype=torch.int64).cumsum(0)
    first = scenes[members[0]].cameras
    return SizeGroup(first.height, first.width, tuple(members), torch.tensor(members, device=device),
                     offsets.to(device),
                     torch.tensor(counts, dtype=torch.int64, device=device), neighbours.to(device),
                     torch.cat(K).to(device, torch.float32), torch.cat(c2w).to(device, torch.float32),
                     torch.cat(near).to(device, torch.float32), torch.cat(far).to(device, torch.float32),
                     None, tuple(views))


def gather_images(data: TrainingSet, group: SizeGroup, ids: Tensor, cache: ImageCache) -> Tensor:
    """uint8 images [*ids.shape, H, W, 3] of the flat view ids (on the training device)."""
    if group.images is not None:
        return group.images[ids]
    flat = [cache.get(data.scenes[s], i) for s, i in (group.views[v] for v in ids.reshape(-1).tolist())]
    images = torch.stack(flat).reshape(*ids.shape, group.height, group.width, 3)
    if data.device.type == "cuda":
        images = images.pin_memory()
    return images.to(data.device, non_blocking=True)


def gather_depths(data: TrainingSet, group: SizeGroup, ids: Tensor, pixels: Tensor) -> Tensor:
    """True depths [B, P] at the flat pixel indices ``pixels`` [B, P] of the views ``ids`` [B]."""
    if group.depths is not None:
        return group.depths[ids].reshape(len(ids), -1).gather(1, pixels)
    flat = [decode_depth(data.scenes[s], i).reshape(-1) for s, i in (group.views[v] for v in ids.tolist())]
    return torch.stack(flat).to(data.device).gather(1, pixels)
