"""Choosing reference (source) views for a target camera, with the rules of IBRNet and GNT (docs/method.md, Frames
and references).

At test time the model sees exactly the k nearest views. In training the k views are drawn at random from a
larger pool of nearest views, so that the model also learns from less ideal neighbours, and very rarely the
target itself is kept among the sources.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Literal, Sequence

import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape
from insertnerf_cli.errors import UserError
from insertnerf_cli.scenes.base import Scene

ViewMethod = Literal["vector", "dist", "matrix"]
VIEW_METHODS: tuple[str, ...] = ("vector", "dist", "matrix")


def view_rule(layout: str) -> ViewMethod:
    """The rule that picks reference views at test time: camera distance for forward-facing captures, angle about
    the centre for object-centric ones (IBRNet's choices for LLFF and for 360-degree scenes)."""
    return "dist" if layout == "forward" else "vector"


def view_distances(target_c2w: Tensor, ref_c2w: Tensor, method: ViewMethod = "vector",
                   center: Tensor | Sequence[float] | None = None) -> Tensor:
    """How far each reference camera is from the target, by one of the IBRNet rules.

    Args:
        target_c2w: [4, 4] camera-to-world of the target.
        ref_c2w: [N, 4, 4] camera-to-world of the candidates.
        method: "vector": angle (radians) between the centre-minus-scene-centre vectors (object-centric scenes);
            "dist": Euclidean distance between camera centres (forward-facing scenes);
            "matrix": angle (radians) of the relative rotation.
        center: [3] scene centre for "vector"; None = the world origin (where normalised scenes put it).
    Returns:
        [N] float64 distances (smaller = nearer).
    """
    check_shape("target_c2w", target_c2w, (4, 4))
    check_shape("ref_c2w", ref_c2w, (None, 4, 4))
    target = target_c2w.detach().to("cpu", torch.float64)
    refs = ref_c2w.detach().to("cpu", torch.float64)
    if method == "dist":
        return torch.linalg.norm(refs[:, :3, 3] - target[:3, 3], dim=-1)
    if method == "matrix":
        relative = target[:3, :3].T @ refs[:, :3, :3]  # [N, 3, 3]
        cos = (relative.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0
        return torch.arccos(cos.clamp(-1.0, 1.0))
    if method == "vector":
        c = torch.zeros(3, dtype=torch.float64) if center is None else torch.as_tensor(center, dtype=torch.float64)
        t = _unit(target[:3, 3] - c)  # [3]
        r = _unit(refs[:, :3, 3] - c)  # [N, 3]
        return torch.arccos((r @ t).clamp(-1.0, 1.0))
    raise ValueError(f"unknown view-distance method {method!r}; expected one of {VIEW_METHODS}")


def nearest_views(target_c2w: Tensor, ref_c2w: Tensor, k: int, method: ViewMethod = "vector",
                  center: Tensor | Sequence[float] | None = None, exclude: Iterable[int] | None = None) -> list[int]:
    """Indices of the k reference cameras nearest to the target, nearest first.

    Args:
        target_c2w: [4, 4]; ref_c2w: [N, 4, 4]; method, center: see :func:`view_distances`.
        k: how many to return; clipped to the number of candidates left after ``exclude``.
        exclude: indices never returned (typically the target's own index among the references).
    Returns:
        up to k distinct indices into ``ref_c2w``; ties keep the lower index first.
    """
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    dist = view_distances(target_c2w, ref_c2w, method, center)
    banned = sorted({int(i) for i in (exclude or ()) if 0 <= int(i) < dist.shape[0]})
    dist[banned] = math.inf
    order = torch.sort(dist, stable=True).indices  # stable: equal distances keep index order
    available = dist.shape[0] - len(banned)
    return order[: min(k, available)].tolist()


@dataclass(frozen=True)
class ViewSampling:
    """How training draws its source views (IBRNet/GNT defaults).

    Attributes:
        pool_factors, pool_probs: the pool holds the nearest k*s views, s drawn from pool_factors with pool_probs.
        max_pool: upper bound on the pool size (never below k).
        keep_target_prob: probability of swapping the target itself in for one source view.
    """

    pool_factors: tuple[int, ...] = (1, 2, 3)
    pool_probs: tuple[float, ...] = (0.2, 0.45, 0.35)
    max_pool: int = 20
    keep_target_prob: float = 0.005

    def __post_init__(self) -> None:
        if len(self.pool_factors) != len(self.pool_probs) or not math.isclose(sum(self.pool_probs), 1.0):
            raise ValueError("pool_probs must match pool_factors and sum to 1")


def sample_training_views(rng: np.random.Generator, target_index: int, c2w: Tensor, k: int,
                          method: ViewMethod = "vector", center: Tensor | Sequence[float] | None = None,
                          sampling: ViewSampling = ViewSampling()) -> list[int]:
    """Source views for training on target ``target_index``: k drawn at random from a pool of its nearest views.

    Args:
        rng: the caller's generator (its state is part of the training checkpoint).
        target_index: the target's index into ``c2w``.
        c2w: [N, 4, 4] cameras of the scene's training views (the target among them).
        k: number of source views; clipped to N - 1.
    Returns:
        min(k, N - 1) distinct indices into ``c2w``; the target is excluded except, with probability
        ``sampling.keep_target_prob``, in place of one of them.
    """
    check_shape("c2w", c2w, (None, 4, 4))
    factor = int(rng.choice(np.asarray(sampling.pool_factors), p=np.asarray(sampling.pool_probs)))
    pool_size = max(k, min(k * factor, sampling.max_pool))
    pool = nearest_views(c2w[target_index], c2w, pool_size, method, center, exclude=[target_index])
    chosen = rng.choice(len(pool), size=min(k, len(pool)), replace=False)
    views = [pool[i] for i in chosen]
    if views and rng.random() < sampling.keep_target_prob:
        views[int(rng.integers(len(views)))] = target_index
    return views


def held_out_views(scene: Scene) -> list[int]:
    """The views `eval` scores and that neither eval's references nor `finetune` ever use: the test split when the
    scene has one, else every 8th view."""
    test = scene.split("test")
    if not test or len(test) == len(scene):
        raise UserError(f"{scene.root}: {len(scene)} views leave no held-out/reference split to evaluate")
    return sorted(set(test))


def evenly_spread(views: Sequence[int], count: int | None) -> list[int]:
    """At most ``count`` (>= 1) of ``views`` (sorted), evenly spread over them; all of them for None."""
    if count is not None and count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    views = sorted(views)
    if count is None or count >= len(views):
        return views
    return sorted({views[round(i * (len(views) - 1) / max(count - 1, 1))] for i in range(count)})


def _unit(v: Tensor) -> Tensor:
    """Vectors [..., 3] scaled to unit length; a zero vector (camera at the centre) stays zero."""
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)
