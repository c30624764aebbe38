"""A scene's sparse 3D points (from structure-from-motion) and which views observe each one."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape

# A point needs two observing views to be triangulated without the others: the rule for "seen from these views".
MIN_OBSERVERS = 2


@dataclass(frozen=True)
class ScenePoints:
    """P points of the scene, in the same world as its cameras.

    Attributes:
        xyz: [P, 3] positions (float64).
        observed: per view (in the scene's camera order), the indices of the points that view observes; None when
            the source does not say (a bare point cloud such as nerfstudio's sparse_pc.ply).
    """

    xyz: Tensor  # [P, 3]
    observed: tuple[Tensor, ...] | None = None

    def __post_init__(self) -> None:
        check_shape("xyz", self.xyz, (None, 3))

    def __len__(self) -> int:
        return self.xyz.shape[0]

    def transformed(self, similarity) -> "ScenePoints":
        """The points in the world that ``similarity`` (scenes.normalize.Similarity) maps to."""
        return ScenePoints(similarity.apply_points(self.xyz), self.observed)

    def subset_views(self, indices: Sequence[int]) -> "ScenePoints":
        """The same points, with the observations of the views at ``indices`` (in that order)."""
        if self.observed is None:
            return self
        return ScenePoints(self.xyz, tuple(self.observed[i] for i in indices))

    def seen_mask(self, views: Sequence[int], near: Sequence[int] | None = None) -> Tensor:
        """[P] bool: the points that at least MIN_OBSERVERS of ``views`` observe, what those views alone would have
        triangulated (every point when the observations are unknown); with ``near``, only those that one of the
        ``near`` views observes too (a target's nearest views: points they see are rarely hidden from it).
        """
        if self.observed is None:
            return torch.ones(len(self), dtype=torch.bool)
        keep = self.observers(views) >= MIN_OBSERVERS
        if near is not None:
            keep &= self.observers(near) >= 1
        return keep

    def observers(self, views: Sequence[int]) -> Tensor:
        """[P] how many of ``views`` observe each point (observations known)."""
        if self.observed is None:
            raise ValueError("observers() needs the points' observations; this cloud has none")
        chosen = [self.observed[v] for v in views]
        if not chosen:
            return torch.zeros(len(self), dtype=torch.int64)
        return torch.bincount(torch.cat(chosen), minlength=len(self))
