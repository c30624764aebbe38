"""The Scene every reader returns: posed images, loaded on demand."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes.images import Distortion, read_rgb, resize, undistort
from insertnerf_cli.scenes.points import ScenePoints

Layout = Literal["object", "forward"]


@dataclass(frozen=True)
class Scene:
    """Posed images of one scene.

    Attributes:
        root: the scene folder; every path below lies inside it.
        cameras: N cameras at the images' full resolution, OpenCV c2w (float64).
        image_paths: N image files, in camera order.
        near, far: [N] scene bounds along each camera's z axis, in world units.
        splits: index lists per split ("train", "val", "test") when the format has them, else {}.
        layout: "object" for object-centric / 360-degree captures, "forward" for forward-facing ones.
        format: name of the reader that produced it ("blender", "nerfstudio", "llff", "colmap", "dtu", ...).
        background: RGB in [0, 1] that transparent pixels are composited on.
        depth_paths: optional ground-truth depth per view (synthetic scenes), else None.
        depth_scale: scene units per stored depth unit (e.g. 1e-3 for uint16 millimetres of a metre scene).
        distortion: per view, the lens distortion removed on load (None entries for pinhole views), or None.
        points: the sparse 3D points of a structure-from-motion model (COLMAP, `insertnerf poses`), or None.
    """

    root: Path
    cameras: Cameras
    image_paths: list[Path]
    near: Tensor  # [N]
    far: Tensor  # [N]
    splits: dict[str, list[int]] = field(default_factory=dict)
    layout: Layout = "object"
    format: str = "unknown"
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    depth_paths: list[Path] | None = None
    depth_scale: float = 1.0
    distortion: list[Distortion | None] | None = None
    points: ScenePoints | None = None

    def __post_init__(self) -> None:
        n = len(self.cameras)
        if len(self.image_paths) != n or self.near.shape != (n,) or self.far.shape != (n,):
            raise SceneError(
                f"{self.root}: {n} cameras but {len(self.image_paths)} images and {tuple(self.near.shape)} bounds")

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def names(self) -> list[str]:
        """Image file names relative to the scene folder (posix style)."""
        return [p.relative_to(self.root).as_posix() if p.is_relative_to(self.root) else p.name
                for p in self.image_paths]

    def split(self, name: str) -> list[int]:
        """Indices of a split; without one, "test" is every 8th view and "train" the rest (LLFF habit)."""
        if name in self.splits:
            return list(self.splits[name])
        every8 = list(range(0, len(self), 8))
        if name == "test":
            return every8
        if name == "train":
            return [i for i in range(len(self)) if i not in set(every8)]
        raise SceneError(f"{self.root}: no split named {name!r}")

    def size_for(self, long_side: int | None) -> tuple[int, int]:
        """(height, width) with the given long side and the images' aspect ratio (None = full size)."""
        h, w = self.cameras.height, self.cameras.width
        if long_side is None or long_side >= max(h, w):
            return h, w
        s = long_side / max(h, w)
        return max(1, round(h * s)), max(1, round(w * s))

    def load_image(self, index: int, height: int | None = None, width: int | None = None) -> np.ndarray:
        """Image ``index`` as float32 RGB [H, W, 3] in [0, 1], resized to height x width if given."""
        img = self._decoded(index)
        if height is not None and width is not None:
            img = resize(img, height, width)
        return img

    def _decoded(self, index: int) -> np.ndarray:
        """Image ``index`` as float32 RGB [H, W, 3] at the cameras' size, undistorted where the scene says so."""
        img = read_rgb(self.image_paths[index], self.background)
        if self.distortion is not None and self.distortion[index] is not None:
            # Undistort at the file's own resolution, where K (the undistorted camera) is scaled to the file.
            K = self.cameras.rescale(img.shape[0], img.shape[1]).K[index].cpu().numpy()
            img = undistort(img, K, self.distortion[index])
        # Mixed sizes of one aspect ratio: the cameras were scaled to the common size.
        return resize(img, self.cameras.height, self.cameras.width)

    def load_sizes(self, indices: Sequence[int], sizes: Sequence[tuple[int, int]]) -> list[Tensor]:
        """Images [V, H, W, 3] (float32) at each (H, W) of ``sizes``, each file read and decoded once."""
        per_view = [[resize(img, h, w) for h, w in sizes] for img in map(self._decoded, indices)]
        return [torch.from_numpy(np.stack([view[k] for view in per_view])) for k in range(len(sizes))]

    def subset(self, indices: Sequence[int]) -> "Scene":
        """The views at ``indices`` (in that order); splits are re-indexed and keep only the chosen views."""
        indices = list(indices)
        where = {old: new for new, old in enumerate(indices)}
        pick = (lambda xs: None if xs is None else [xs[i] for i in indices])
        splits = {k: [where[i] for i in v if i in where] for k, v in self.splits.items()}
        splits = {k: v for k, v in splits.items() if v}
        return replace(self, cameras=self.cameras.subset(indices), image_paths=pick(self.image_paths),
                       near=self.near[indices], far=self.far[indices], splits=splits,
                       depth_paths=pick(self.depth_paths), distortion=pick(self.distortion),
                       points=None if self.points is None else self.points.subset_views(indices))

    def with_cameras(self, cameras: Cameras, near: Tensor, far: Tensor) -> "Scene":
        """The same images with other cameras and bounds (used by normalisation)."""
        return replace(self, cameras=cameras, near=near, far=far)
