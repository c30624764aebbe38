"""The chunked whole-image renderer: one frame of a camera through the model (compositing lives in compositing.py)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterator

import torch
from torch import Tensor

from .cameras import Cameras
from .compositing import Composite
from .rays import rays_for_image

if TYPE_CHECKING:
    from .model import EncodedViews, InsertNeRF


@dataclass(frozen=True)
class ImageOutput:
    """A rendered frame: rgb [H, W, 3] in [0, 1], depth [H, W] (camera z), opacity [H, W]."""

    rgb: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W]
    opacity: Tensor  # [H, W]


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
