"""The typed containers that cross the generator's boundaries (glossary: V views, R rays, S samples, C channels)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape
from insertnerf_cli.model.compositing import Composite
from insertnerf_cli.model.occlusion import Occlusion
from insertnerf_cli.model.sampling import RaySamples


@dataclass(frozen=True)
class SourceViews:
    """The reference views a scene is rendered from.

    Attributes:
        images: [V, H, W, 3] float RGB in [0, 1].
        cameras: V cameras of size H x W (OpenCV c2w).
    """

    images: Tensor  # [V, H, W, 3]
    cameras: Cameras

    def __post_init__(self) -> None:
        check_shape("images", self.images, (len(self.cameras), self.cameras.height, self.cameras.width, 3))

    def __len__(self) -> int:
        return len(self.cameras)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "SourceViews":
        return SourceViews(self.images.to(device=device, dtype=dtype), self.cameras.to(device=device, dtype=dtype))


@dataclass(frozen=True)
class EncodedViews:
    """Reference views after the U-Net, with everything projection needs precomputed once per frame.

    The images are zero-padded on the right and bottom to a multiple of the U-Net's total stride, so that one
    normalised grid (relative to the padded size) addresses the images and every feature scale exactly.

    Attributes:
        features: per scale, coarse to fine: [V, C_l, Hp / 8, Wp / 8], [V, C_l, Hp / 4, Wp / 4],
            [V, C_l, Hp / 2, Wp / 2].
        images: [V, 3, Hp, Wp] padded reference colours (channels first, as grid_sample wants them).
        projection: [V, 3, 4] K [R | t]: world point (homogeneous) -> (u z, v z, z) in pixels.
        centers: [V, 3] camera centres.
        height, width: the real image size H, W (pixels beyond it are padding and count as outside).
        reconstruction: [V, 3, H, W] the backbone decoder's rebuild of the images (training only, else None).
        colours: [V, 3, Hc, Wc] the same photos at a finer size (unpadded) where the reference colours that the
            output colour blends are looked up, or None to look them up in ``images``. Render and eval pass the
            photos at up to twice the frame's size: a bilinear lookup at the frame's own size blurs each colour
            over two of the frame's pixels, while the photo the render is scored against is an area average over
            one. The network's inputs still read ``images``, as in training (Projected.finer).
        occlusion: the nearer surfaces each view's own SfM points show (occlusion.Occlusion), which mask the
            samples hidden from it; None (training, scenes without points): every view sees what lies in front
            of it. Set per frame (with_occlusion); ``join`` drops it.
    """

    features: tuple[Tensor, ...]
    images: Tensor  # [V, 3, Hp, Wp]
    projection: Tensor  # [V, 3, 4]
    centers: Tensor  # [V, 3]
    height: int
    width: int
    reconstruction: Tensor | None = None  # [V, 3, H, W]
    colours: Tensor | None = None  # [V, 3, Hc, Wc]
    occlusion: Occlusion | None = None

    def __post_init__(self) -> None:
        if self.colours is not None:
            check_shape("colours", self.colours, (len(self.images), 3, None, None))
        if self.occlusion is not None:
            check_shape("occlusion.depth", self.occlusion.depth, (len(self.images), 1, None, None))

    def __len__(self) -> int:
        return self.images.shape[0]

    @property
    def padded_size(self) -> tuple[int, int]:
        return self.images.shape[-2], self.images.shape[-1]

    def source_images(self) -> Tensor:
        """The unpadded reference images [V, 3, H, W]."""
        return self.images[..., : self.height, : self.width]

    def select(self, index: Sequence[int]) -> "EncodedViews":
        """The views at ``index`` (the U-Net treats every view on its own, so a view's encoding does not depend
        on the others it was encoded with); the training-only reconstruction is dropped."""
        rows = list(index)
        return EncodedViews(features=tuple(f[rows] for f in self.features), images=self.images[rows],
                            projection=self.projection[rows], centers=self.centers[rows], height=self.height,
                            width=self.width, colours=None if self.colours is None else self.colours[rows],
                            occlusion=None if self.occlusion is None else self.occlusion.select(rows))

    def with_colours(self, colours: Tensor) -> "EncodedViews":
        """These views with the reference colours looked up in ``colours`` [V, 3, Hc, Wc] (the same photos at a
        finer size; see ``colours``)."""
        return replace(self, colours=colours.to(self.images))

    def with_occlusion(self, occlusion: Occlusion | None) -> "EncodedViews":
        """These views with ``occlusion`` (its views in this order), or none."""
        return replace(self, occlusion=occlusion)

    @staticmethod
    def join(parts: Sequence["EncodedViews"]) -> "EncodedViews":
        """The views of ``parts`` (same image size, and colours of one size or none) in order, as one
        EncodedViews."""
        first = parts[0]
        colours = None if any(p.colours is None for p in parts) else torch.cat([p.colours for p in parts])
        return EncodedViews(features=tuple(torch.cat(scale) for scale in zip(*(p.features for p in parts))),
                            images=torch.cat([p.images for p in parts]),
                            projection=torch.cat([p.projection for p in parts]),
                            centers=torch.cat([p.centers for p in parts]), height=first.height, width=first.width,
                            colours=colours)


@dataclass(frozen=True)
class SampleFeatures:
    """What the reference views say about the R x S samples of one pass, aggregated per scale.

    Attributes:
        points: [R, S, 3] world positions.
        conds: per scale, coarse to fine, [R, S, D_l] aggregated descriptors (the HyperNet conditions).
        dynamic: [V, 1, R * S] view weights of the reference colour: the dynamic weights averaged over the scales
            (times the angular prior with ``colour_prior_views``), summing to 1 where a view sees the sample.
        colours: [V, 3, R * S] reference colours at the samples' projections that the output colour blends
            (Projected.blend_colours; zero where a view cannot see).
        colour_variance: [R, S] how much the nearest views disagree on each sample's colour
            (consistency.colour_variance), or None where the config uses no photo-consistency.
    """

    points: Tensor  # [R, S, 3]
    conds: tuple[Tensor, ...]  # [R, S, D_l] each
    dynamic: Tensor  # [V, 1, R * S]
    colours: Tensor  # [V, 3, R * S]
    colour_variance: Tensor | None = None  # [R, S]

    def reference_colour(self) -> Tensor:
        """[R, S, 3] the reference colours blended by the dynamic weights."""
        return (self.dynamic * self.colours).sum(dim=0).T.reshape(*self.points.shape[:2], 3)


@dataclass(frozen=True)
class RenderOutput:
    """Both passes of the generator over R rays.

    Attributes:
        coarse, fine: composites of the stratified and the importance-sampled pass.
        dynamic_coarse, dynamic_fine: [R, 3] the reference colours blended by the dynamic weights and composited
            with the pass's (detached) weights, supervised by the dynamic-weight loss.
        coarse_samples, fine_samples: the samples (depths and bins) of each pass, for the geometry losses.
    """

    coarse: Composite
    fine: Composite
    dynamic_coarse: Tensor  # [R, 3]
    dynamic_fine: Tensor  # [R, 3]
    coarse_samples: RaySamples
    fine_samples: RaySamples


@dataclass(frozen=True)
class LossTerms:
    """The training objective and its parts (each a scalar tensor; only ``total`` carries gradients to use).

    ``depth`` and ``distortion`` are the geometry terms of both passes (0 when their weights are 0 or, for depth,
    when no ray of the batch has a known depth)."""

    total: Tensor
    mse_coarse: Tensor
    mse_fine: Tensor
    backbone: Tensor
    dynamic: Tensor
    psnr_fine: Tensor
    depth: Tensor
    distortion: Tensor
