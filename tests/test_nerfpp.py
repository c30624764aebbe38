"""The NeRF++ backbone: inverted-sphere coordinates, the foreground / background split and its compositing, and a
checkpoint of either backbone through `render`."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from insertnerf_cli.cameras.rays import Rays
from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model.insertnerf import InsertNeRF
from insertnerf_cli.model.inverted_sphere import (
    MIN_INVERSE_DISTANCE,
    Sphere,
    background_samples,
    from_inverted,
    inverted_sphere,
)
from insertnerf_cli.model.types import SourceViews
from insertnerf_cli.scenes.normalize import OBJECT_RADIUS
from cli_fixtures import TINY, make_checkpoint, make_scene, render_command, ring_cameras

SPHERE = Sphere(torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64), torch.tensor(3.0, dtype=torch.float64))


def test_inverted_sphere_coordinates_of_known_points() -> None:
    centre, r = SPHERE.centre, SPHERE.radius
    points = torch.stack([centre + torch.tensor([2 * r, 0, 0]), centre + torch.tensor([0, 0, -4 * r]),
                          centre + torch.tensor([r, 0, 0])])
    expected = torch.tensor([[1.0, 0, 0, 0.5], [0, 0, -1.0, 0.25], [1.0, 0, 0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(inverted_sphere(points, SPHERE), expected)
    inside = centre + torch.tensor([0.5, 0.0, 0.0])  # maps onto the surface, in its direction
    torch.testing.assert_close(inverted_sphere(inside[None], SPHERE), torch.tensor([[1.0, 0, 0, 1.0]],
                                                                                  dtype=torch.float64))


def test_inverted_sphere_coordinates_invert_outside_the_sphere() -> None:
    torch.manual_seed(0)
    direction = torch.nn.functional.normalize(torch.randn(500, 3, dtype=torch.float64), dim=-1)
    distance = SPHERE.radius / torch.rand(500, dtype=torch.float64).clamp_min(1e-3)  # from r out to 1000 r
    points = SPHERE.centre + direction * distance[:, None]
    coords = inverted_sphere(points, SPHERE)
    torch.testing.assert_close(coords[:, :3].norm(dim=-1), torch.ones(500, dtype=torch.float64))
    assert bool(((coords[:, 3] > 0) & (coords[:, 3] <= 1)).all())
    torch.testing.assert_close(from_inverted(coords, SPHERE), points)


def test_background_samples_lie_at_their_inverse_distance_out_to_nearly_infinity() -> None:
    torch.manual_seed(1)
    origins = SPHERE.centre + 0.5 * torch.randn(64, 3, dtype=torch.float64)  # inside the sphere
    rays = Rays(origins, torch.randn(64, 3, dtype=torch.float64), torch.zeros(64, dtype=torch.float64),
                torch.ones(64, dtype=torch.float64))
    for jitter in (False, True):
        samples = background_samples(rays, SPHERE, 8, jitter=jitter)
        assert bool((samples.inverse[:, 1:] < samples.inverse[:, :-1]).all())  # near to far
        assert bool((samples.t[:, 1:] > samples.t[:, :-1]).all())
        distance = (samples.points(rays) - SPHERE.centre).norm(dim=-1)
        torch.testing.assert_close(distance, SPHERE.radius / samples.inverse)
        assert samples.edges[0, 0] == 1.0 and math.isclose(float(samples.edges[0, -1]), MIN_INVERSE_DISTANCE)


def _solid_model(foreground_opaque: bool) -> InsertNeRF:
    """A NeRF++ model whose fields are constant: the foreground red and opaque (or empty), the background green
    and opaque, reference colours not blended in."""
    torch.manual_seed(0)
    model = InsertNeRF(ModelConfig(**{**TINY, "backbone": "nerfpp", "samples_background": 8,
                                      "blend_reference_colour": False}))
    with torch.no_grad():
        for head, colour, density in ((model.coarse_head, (1.0, 0.0, 0.0), 30.0 if foreground_opaque else -30.0),
                                      (model.background_head, (0.0, 1.0, 0.0), 30.0)):
            head.colour.weight.zero_()
            head.colour.bias.copy_(torch.tensor([30.0 if c else -30.0 for c in colour] + [0.0]))
            head.density.weight.zero_()
            head.density.bias.fill_(density)
    return model.eval()


@pytest.mark.parametrize("opaque", [False, True], ids=["background-only", "opaque-foreground"])
def test_the_foreground_composites_over_the_background_as_nerfpp_does(opaque: bool) -> None:
    model = _solid_model(opaque)
    cameras = ring_cameras(4, radius=2.0)
    views = SourceViews(torch.rand(4, cameras.height, cameras.width, 3), cameras)
    encoded = model.encode(views)
    origins = torch.zeros(16, 3)
    directions = torch.nn.functional.normalize(torch.randn(16, 3), dim=-1)
    rays = Rays(origins, directions, torch.full((16,), 0.1), torch.full((16,), 2.0 * OBJECT_RADIUS))
    with torch.no_grad():
        rgb = model.render(encoded, rays).rgb
    expected = torch.tensor([1.0, 0.0, 0.0]) if opaque else torch.tensor([0.0, 1.0, 0.0])
    torch.testing.assert_close(rgb, expected.expand(16, 3), atol=1e-4, rtol=0)


@pytest.mark.slow
@pytest.mark.parametrize("backbone", ["nerf", "nerfpp"])
def test_a_checkpoint_of_either_backbone_renders(tmp_path: Path, backbone: str) -> None:
    scene = make_scene(tmp_path / "scene", {"train": 6})
    checkpoint = make_checkpoint(tmp_path / f"{backbone}.pt", backbone=backbone, samples_background=8)
    result = render_command(scene, checkpoint, tmp_path / "out", "--frames", 2)
    assert result.exit_code == 0, result.output
    frames = sorted((tmp_path / "out").rglob("*.png"))
    assert frames
