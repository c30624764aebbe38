"""A reference whose own SfM points put a nearer surface in front of a sample stops seeing it (model.occlusion,
occlusion_maps; issue 27, round 32)."""
from __future__ import annotations

import math

import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.model.occlusion import Occlusion, visible
from insertnerf_cli.model.projection import Projected
from insertnerf_cli.sfm.depth_prior import well_tracked
from insertnerf_cli.sfm.occlusion_maps import OcclusionOptions, near_angle, reference_map

OPTIONS = OcclusionOptions()
MAP_SIZE = OPTIONS.map_size
from insertnerf_cli.scenes.points import ScenePoints

WIDTH = HEIGHT = 8


def _occlusion(surface: list[float], near: float = 0.0) -> Occlusion:
    depth = torch.tensor(surface, dtype=torch.float64)[:, None, None, None].expand(-1, 1, 4, 4).clone()
    return Occlusion(depth, torch.full((len(surface),), near, dtype=torch.float64), OPTIONS.tolerance,
                     OPTIONS.min_visible)


def _visible(occlusion: Occlusion, depth: list[float], angle: list[float] | None = None) -> torch.Tensor:
    views = len(depth)
    uv = torch.full((views, 2, 1), WIDTH / 2, dtype=torch.float64)  # the centre pixel of every view
    z = torch.tensor(depth, dtype=torch.float64)[:, None, None]
    ang = torch.tensor(angle or [0.5] * views, dtype=torch.float64)[:, None, None]
    return visible(occlusion, uv, z, torch.ones_like(z), ang, WIDTH, HEIGHT)[:, 0, 0]


def test_a_sample_past_a_views_nearer_surface_is_masked_and_one_in_front_is_not():
    # Views 0 and 1 see the sample 2.0 away in front of their surfaces; view 2's surface lies at 1.0.
    seen = _visible(_occlusion([3.0, 3.0, 1.0]), [2.0, 2.0, 2.0])
    assert seen.tolist() == [1.0, 1.0, 0.0]


def test_the_tolerance_keeps_a_sample_just_behind_the_surface():
    inside, past = 1.0 + 0.9 * OPTIONS.tolerance, 1.0 + 1.1 * OPTIONS.tolerance
    assert _visible(_occlusion([3.0, 3.0, 1.0]), [2.0, 2.0, inside]).tolist() == [1.0, 1.0, 1.0]
    assert _visible(_occlusion([3.0, 3.0, 1.0]), [2.0, 2.0, past]).tolist() == [1.0, 1.0, 0.0]


def test_a_view_nearly_along_the_query_ray_is_never_masked():
    occlusion = _occlusion([3.0, 3.0, 1.0], near=0.1)
    assert _visible(occlusion, [2.0, 2.0, 2.0], angle=[0.5, 0.5, 0.05]).tolist() == [1.0, 1.0, 1.0]
    assert _visible(occlusion, [2.0, 2.0, 2.0], angle=[0.5, 0.5, 0.15]).tolist() == [1.0, 1.0, 0.0]


def test_a_sample_too_few_views_pass_keeps_every_view():
    # Behind every view's surface (a sample behind a forward-facing scene's wall): the test would leave it unseen.
    assert OPTIONS.min_visible >= 2
    seen = _visible(_occlusion([1.0, 1.0, 1.0]), [2.0, 2.0, 2.0])
    assert seen.tolist() == [1.0, 1.0, 1.0]
    one = _visible(_occlusion([3.0, 1.0, 1.0]), [2.0, 2.0, 2.0])
    assert one.tolist() == [1.0, 1.0, 1.0]


def test_the_choice_of_views_ranks_the_views_that_see_the_sample_and_unoccluded_applies_it():
    views, points = 3, 2
    cos = torch.tensor([0.9, 0.5, 0.99])[:, None, None].expand(views, 1, points)
    ray_diff = torch.cat([torch.zeros(views, 3, points), cos], dim=1)
    mask = torch.ones(views, 1, points)
    vis = torch.tensor([[1.0, 1.0], [1.0, 1.0], [0.0, 1.0]])[:, None]  # view 2 hidden from sample 0 only
    seen = Projected((), torch.rand(views, 3, points), mask, ray_diff, None, vis).nearest_in_angle(2)
    # Sample 0: view 2, nearest in angle, is hidden and gives its place to view 1; sample 1 keeps views 2 and 0.
    assert torch.allclose(seen.cos[:, 0, 0], torch.tensor([0.9, 0.5]))
    assert torch.allclose(seen.cos[:, 0, 1], torch.tensor([0.99, 0.9]))
    assert seen.mask.flatten().tolist() == [1.0] * 4
    assert seen.unoccluded().mask.flatten().tolist() == [1.0] * 4
    assert seen.unoccluded().visible is None
    # Without an Occlusion the plain mask ranks: view 2 stays first for both samples.
    plain = Projected((), torch.rand(views, 3, points), mask, ray_diff).nearest_in_angle(2)
    assert torch.allclose(plain.cos[:, 0], torch.tensor([[0.99, 0.99], [0.9, 0.9]]))


def _camera(x: float, size: int = 64, focal: float | None = None) -> Cameras:
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[0, 3] = x
    f = float(focal or size)
    K = torch.tensor([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return Cameras(K=K[None], c2w=c2w[None], height=size, width=size)


def test_a_views_map_holds_the_well_tracked_points_it_observes():
    # Point 0 at depth 2 is observed by views 0, 1, 2; point 1 at depth 5 by views 0 and 1 only (a two-view track).
    xyz = torch.tensor([[0.0, 0.0, 2.0], [0.3, 0.0, 5.0]], dtype=torch.float64)
    observed = (torch.tensor([0, 1]), torch.tensor([0, 1]), torch.tensor([0]))
    points = ScenePoints(xyz, observed)
    depth = reference_map(points, _camera(0.0), 0, well_tracked(points, [0, 1, 2]))
    assert depth.shape == (1, 64, 64)  # the camera's size
    assert math.isclose(float(depth[0, 32, 32]), 2.0, rel_tol=1e-6)
    assert not bool((depth == 5.0).any())  # the two-view track is left out
    far = reference_map(points, _camera(0.0), 0, well_tracked(points, [0, 1]))  # then no point has 3 observers
    assert bool(torch.isinf(far).all())


def test_near_angles_follow_the_lens():
    big = _camera(0.0, size=4 * MAP_SIZE)
    # focal = long side: a 53-degree lens; twice the focal length halves the angle.
    assert torch.allclose(near_angle(big), torch.tensor([OPTIONS.near_parallax]))
    long_lens = _camera(0.0, size=4 * MAP_SIZE, focal=8 * MAP_SIZE)
    assert torch.allclose(near_angle(long_lens), torch.tensor([OPTIONS.near_parallax / 2]))


@pytest.mark.slow
def test_render_hands_the_generator_each_references_map_in_their_order(tmp_path, monkeypatch):
    from cli_fixtures import make_checkpoint

    import insertnerf_cli.rendering.view_renderer as render_module
    from insertnerf_cli.scenes import load_scene, normalize_scene
    from insertnerf_cli.rendering.view_renderer import ViewRenderer, load_model
    from scene_fixtures import known_scene, write_colmap

    scene, _ = normalize_scene(load_scene(write_colmap(tmp_path / "scene", known_scene(9))))
    model = load_model(make_checkpoint(tmp_path / "w.pt"), "cpu")
    handed = []
    real = render_module.render_image
    monkeypatch.setattr(render_module, "render_image", lambda m, encoded, *a, **k: handed.append(encoded) or real(
        m, encoded, *a, **k))
    camera = scene.cameras.subset([4]).rescale(16, 16)
    with torch.inference_mode():
        for sfm_depth in (True, False):  # the maps come with the SfM points
            renderer = ViewRenderer(model, scene, (16, 16), views=3, sfm_depth=sfm_depth)
            _, refs = renderer.render(camera, float(scene.near[4]), float(scene.far[4]), [4])
    with_maps, without = handed
    assert without.occlusion is None
    pool = [i for i in range(len(scene)) if i != 4]
    size = scene.size_for(MAP_SIZE)  # the maps are made at their size: MAP_SIZE on the long side, or the photos'
    assert with_maps.occlusion.depth.shape[-2:] == size
    for row, view in enumerate(sorted(refs)):  # the encoding's order
        camera = scene.cameras.subset([view]).rescale(*size)
        own = reference_map(scene.points, camera, view, well_tracked(scene.points, pool))
        torch.testing.assert_close(with_maps.occlusion.depth[row], own.to(with_maps.occlusion.depth))
    assert bool(torch.isfinite(with_maps.occlusion.depth).any())
