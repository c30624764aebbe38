"""Overfitting one tiny analytic scene: a few hundred Adam steps on CPU must clearly raise the PSNR of a held-out
view rendered from the training views (the model generalises across viewpoints of the scene it saw)."""
from __future__ import annotations

import time

import pytest
import torch

from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.cameras.rays import rays_for_image
from insertnerf_cli.metrics import psnr
from insertnerf_cli.rendering.image_renderer import render_image
from model_fixtures import FAR, NEAR, TINY, orbit_cameras, sphere_images  # noqa: F401

pytestmark = pytest.mark.usefixtures("one_thread")

SIZE, VIEWS, STEPS, BATCH = 24, 6, 200, 128


def _held_out_psnr(model: InsertNeRF, views: SourceViews, camera, truth: torch.Tensor) -> float:
    model.eval()
    with torch.no_grad():
        image = render_image(model, model.encode(views), camera, NEAR, FAR, chunk=1024)
    model.train()
    return psnr(image.rgb, truth)


@pytest.mark.slow
def test_few_hundred_steps_raise_held_out_psnr():
    torch.manual_seed(0)
    cams = orbit_cameras(VIEWS, SIZE)
    images = sphere_images(cams)
    views = SourceViews(images, cams)
    held_cam = orbit_cameras(1, SIZE, phase=0.5)  # halfway between two training views
    held_truth = sphere_images(held_cam)[0]
    model = InsertNeRF(TINY).train()
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    before = _held_out_psnr(model, views, held_cam, held_truth)
    start = time.perf_counter()
    for step in range(STEPS):
        target = step % VIEWS
        others = [i for i in range(VIEWS) if i != target]
        encoded = model.encode(SourceViews(images[others], cams.subset(others)))
        rays = rays_for_image(cams.subset([target]), torch.tensor([NEAR]), torch.tensor([FAR]))
        pick = torch.randint(0, len(rays), (BATCH,))
        out = model(encoded, rays[pick], train=True)
        loss = model.losses(out, images[target].reshape(-1, 3)[pick], encoded).total
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    after = _held_out_psnr(model, views, held_cam, held_truth)
    print(f"held-out PSNR {before:.2f} -> {after:.2f} dB after {STEPS} steps in {time.perf_counter() - start:.1f} s")
    assert after > before + 4.0
