"""The pretrained generator shipped in the package loads safely and renders."""
import torch

from insertnerf_cli.cameras import Cameras, intrinsics
from insertnerf_cli.checkpoint import bundled_checkpoint, load_model
from insertnerf_cli.model import SourceViews
from insertnerf_cli.render import render_image

MAX_BYTES = 25 * 2**20


def test_bundled_checkpoint_is_small_and_loads_with_weights_only():
    path = bundled_checkpoint()
    assert path.stat().st_size <= MAX_BYTES
    payload = torch.load(path, map_location="cpu", weights_only=True)
    assert "model" in payload and "train" not in payload  # weights and config only


def test_bundled_model_renders_a_finite_image(one_thread):
    model, config = load_model(bundled_checkpoint(), torch.device("cpu"))
    size, views = 24, 3
    angles = torch.linspace(0, 0.6, views + 1, dtype=torch.float64)
    c2w = torch.eye(4, dtype=torch.float64).repeat(views + 1, 1, 1)
    # Cameras on a small arc, 4 units from the origin, looking at it (OpenCV: z forward).
    for i, a in enumerate(angles):
        rot = torch.tensor([[torch.cos(a), 0, -torch.sin(a)], [0, 1, 0], [torch.sin(a), 0, torch.cos(a)]],
                           dtype=torch.float64)
        c2w[i, :3, :3] = rot
        c2w[i, :3, 3] = -4.0 * rot[:, 2]
    cams = Cameras(intrinsics(30.0, 30.0, 12.0, 12.0).expand(views + 1, 3, 3), c2w, size, size).to(dtype=torch.float32)
    images = torch.rand(views, size, size, 3)
    encoded = model.encode(SourceViews(images, cams.subset(list(range(views)))))
    out = render_image(model, encoded, cams.subset([views]), 2.0, 6.0)
    assert out.rgb.shape == (size, size, 3)
    assert torch.isfinite(out.rgb).all() and torch.isfinite(out.depth).all()
    assert ((out.depth >= 2.0 - 1e-4) & (out.depth <= 6.0 + 1e-4)).all()

