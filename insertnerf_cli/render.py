"""Volume compositing (density -> alpha -> weights -> rgb, depth, opacity) and the chunked whole-image renderer."""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterator

import torch
from torch import Tensor

from .cameras import Cameras, check_shape
from .rays import Rays, rays_for_image

if TYPE_CHECKING:
    from .model import EncodedViews, InsertNeRF


@dataclass(frozen=True)
class Composite:
    """One volume-rendering pass over R rays of S samples.

    Attributes:
        rgb: [R, 3] colour composited over the background.
        depth: [R] expected depth of the visible content, sum(w t) / opacity (stays within [near, far]).
        opacity: [R] sum of the weights, in [0, 1].
        weights: [R, S] compositing weights w_k = T_k (1 - exp(-sigma_k delta_k)).
        t: [R, S] sample depths the weights belong to.
    """

    rgb: Tensor  # [R, 3]
    depth: Tensor  # [R]
    opacity: Tensor  # [R]
    weights: Tensor  # [R, S]
    t: Tensor  # [R, S]


@dataclass(frozen=True)
class ImageOutput:
    """A rendered frame: rgb [H, W, 3] in [0, 1], depth [H, W] (camera z), opacity [H, W]."""

    rgb: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W]
    opacity: Tensor  # [H, W]


def composite_weights(density: Tensor, edges: Tensor, ray_scale: Tensor) -> Tensor:
    """Weights [R, S] from densities [R, S] on bins with ``edges`` [R, S + 1] in t.

    ``ray_scale`` [R] converts a step in t into world distance (|d|, since directions have camera-z = 1), so the
    density is per world unit whatever the ray's angle. Transmittance is exp(-cumsum) of the optical depth of the
    bins before each sample, which is stabler than a cumulative product of (1 - alpha).
    """
    check_shape("edges", edges, (density.shape[0], density.shape[1] + 1))
    delta = (edges[:, 1:] - edges[:, :-1]) * ray_scale[:, None]  # [R, S]
    optical = density * delta  # [R, S]
    alpha = 1.0 - torch.exp(-optical)
    before = torch.cumsum(optical, dim=-1) - optical  # exclusive cumsum [R, S]
    return alpha * torch.exp(-before)


def composite(weights: Tensor, colour: Tensor, t: Tensor, background: Tensor) -> Composite:
    """Composite per-sample colours [R, S, 3] with weights [R, S] over ``background`` [3] (or [R, 3])."""
    opacity = weights.sum(dim=-1)  # [R]
    rgb = torch.einsum("rs,rsc->rc", weights, colour) + (1.0 - opacity)[:, None] * background  # [R, 3]
    # Normalising by the opacity gives the depth of what is seen; an empty ray falls back to its mean sample.
    depth = (weights * t).sum(dim=-1) / opacity.clamp(min=1e-6)
    empty = opacity < 1e-6
    if bool(empty.any()):
        depth = torch.where(empty, t.mean(dim=-1), depth)
    return Composite(rgb=rgb, depth=depth, opacity=opacity, weights=weights, t=t)


def render_image(model: "InsertNeRF", encoded: "EncodedViews", camera: Cameras, near: float | Tensor,
                 far: float | Tensor, chunk: int = 128) -> ImageOutput:
    """Render one full frame of ``camera`` (a Cameras of length 1) from the encoded reference views.

    Rays go through the network ``chunk`` at a time without autograd, so peak memory is bounded by the chunk
    size, not by the image size. The fine pass is returned.
    Args:
        model: the generator (its mode is left unchanged; the forward runs with train=False).
        encoded: model.encode(...) of the reference views, computed once per frame or per sequence.
        camera: the target camera (1), same device as the model.
        near, far: scalar depth bounds of the target view.
        chunk: rays per network call. Small chunks keep each per-view tensor (chunk x samples x views x channels
            floats) inside the CPU caches: with 10 views and 64 samples, 128 rays per call rendered 30% faster than
            512 and 2x faster than 1024 (bench/model_speed.py); above glibc's 32 MB mmap threshold every
            allocation also page-faults.
    """
    if len(camera) != 1:
        raise ValueError(f"render_image renders one camera, got {len(camera)}")
    height, width = camera.height, camera.width
    param = next(model.parameters())
    camera = camera.to(device=param.device, dtype=param.dtype)
    bounds = torch.as_tensor([near, far], dtype=param.dtype, device=param.device).reshape(2)
    rays = rays_for_image(camera, bounds[:1], bounds[1:])

    def render_chunk(start: int) -> Composite:
        with torch.inference_mode():  # thread-local: entered in the worker that runs the chunk
            return model.render(encoded, rays[start:start + chunk])

    with _chunk_workers(param.device) as workers:
        with ThreadPoolExecutor(workers) as pool:
            outs = list(pool.map(render_chunk, range(0, len(rays), chunk)))
    return ImageOutput(rgb=torch.cat([o.rgb for o in outs]).reshape(height, width, 3).clamp(0.0, 1.0),
                       depth=torch.cat([o.depth for o in outs]).reshape(height, width),
                       opacity=torch.cat([o.opacity for o in outs]).reshape(height, width))


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


def psnr(mse: Tensor) -> Tensor:
    """Peak signal-to-noise ratio in dB of colours in [0, 1] from their mean squared error."""
    return -10.0 * torch.log10(mse.clamp(min=1e-10)) if torch.is_tensor(mse) else -10.0 * math.log10(mse)
