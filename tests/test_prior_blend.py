"""Pixels whose references agree better at the SfM depth take their blend there (rendering/prior_blend.py)."""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.model.occlusion import Occlusion
from insertnerf_cli.rendering.prior_blend import (BlendOptions, background_plane, blend, blend_at_prior,
                                                  feathered, mix_share, patch_mean, reference_colours, smooth_fill,
                                                  window_max)
from insertnerf_cli.cameras.rays import rays_for_image
from insertnerf_cli.rendering.image_renderer import ImageOutput
from insertnerf_cli.sfm.occlusion_maps import OcclusionOptions
from model_fixtures import FAR, TINY, orbit_cameras, sphere_hit, sphere_images

pytestmark = pytest.mark.usefixtures("one_thread")

BLEND = BlendOptions()
OCCLUSION = OcclusionOptions()

SIZE = 32


def sphere_depth(camera) -> torch.Tensor:
    """[H, W] camera-z depth of the sphere where a pixel's ray hits it, NaN elsewhere."""
    one = torch.ones(1)
    rays = rays_for_image(camera, one, one)  # z = 1 directions: the ray parameter is camera z
    return sphere_hit(rays.origins, rays.directions).float().reshape(camera.height, camera.width)


def encoded_ring(size: int):
    """The encoded sphere views of ``size`` px that render would pick for the target camera (orbit phase 0.3):
    the 4 of 16 around the sphere nearest it, so none sees the target's side of the sphere from behind."""
    torch.manual_seed(0)
    ring = orbit_cameras(16, size)
    nearest = [15, 0, 1, 2]
    with torch.no_grad():
        return InsertNeRF(TINY).eval().encode(SourceViews(sphere_images(ring)[nearest], ring.subset(nearest)))


@pytest.fixture(scope="module")
def scene():
    """encoded_ring(SIZE), the target camera between two of its views, its photo and true depth."""
    camera = orbit_cameras(1, SIZE, phase=0.3)
    return encoded_ring(SIZE), camera, sphere_images(camera)[0], sphere_depth(camera)


def frame(rgb: torch.Tensor, depth: torch.Tensor) -> ImageOutput:
    return ImageOutput(rgb=rgb.clone(), depth=depth.clone(), opacity=torch.ones_like(depth))


def test_a_true_prior_replaces_a_wrong_depth_with_the_references_colour_there(scene):
    encoded, camera, photo, depth = scene
    grey = torch.full_like(photo, 0.5)
    wrong = frame(grey, torch.nan_to_num(depth * 1.3, nan=4.0))
    out = blend_at_prior(wrong, encoded, camera, depth, FAR)
    on_sphere = torch.isfinite(depth)
    taken = (out.depth == depth) & on_sphere
    assert taken.sum() >= 0.7 * on_sphere.sum()  # not all: a smooth texture also agrees off the surface
    # The blend of the references at the true depth is the sphere's own texture, up to bilinear lookups (and the
    # silhouette's pixels, which some of them see half off the sphere).
    error = (out.rgb[taken] - photo[taken]).abs()
    assert error.median() < 0.02
    assert error.mean() < 0.3 * (grey[taken] - photo[taken]).abs().mean()
    assert torch.equal(out.rgb[~on_sphere], grey[~on_sphere])  # no prior: the frame's own pixels
    assert torch.equal(out.opacity, wrong.opacity)


def test_a_wrong_prior_barely_moves_a_right_frame(scene):
    encoded, camera, photo, depth = scene
    right = frame(photo, torch.nan_to_num(depth, nan=4.0))
    out = blend_at_prior(right, encoded, camera, depth * 1.3, FAR)
    on_sphere = torch.isfinite(depth)
    one = torch.ones(1)
    rays = rays_for_image(camera.to(dtype=encoded.images.dtype), one, one)
    blended = blend(reference_colours(encoded, rays, (depth * 1.3).reshape(-1))).reshape(photo.shape)
    # The fill's steep mix gives the wrong prior's blend a small share at most (round 28's rule: none).
    assert (out.rgb - photo).abs()[on_sphere].mean() < 0.1 * (blended - photo).abs()[on_sphere].mean()
    assert (out.depth == depth * 1.3).float()[on_sphere].mean() < 0.05
    assert torch.equal(out.rgb[~on_sphere], photo[~on_sphere])


def test_no_prior_changes_nothing(scene):
    encoded, camera, photo, depth = scene
    given = frame(torch.full_like(photo, 0.5), torch.nan_to_num(depth * 1.3, nan=4.0))
    out = blend_at_prior(given, encoded, camera, torch.full_like(depth, torch.nan), FAR)
    assert torch.equal(out.rgb, given.rgb) and torch.equal(out.depth, given.depth)


def test_a_prior_past_the_far_bound_is_left_out(scene):
    encoded, camera, photo, depth = scene
    wrong = frame(torch.full_like(photo, 0.5), torch.nan_to_num(depth * 1.3, nan=4.0))
    nearest = float(depth[torch.isfinite(depth)].min())
    out = blend_at_prior(wrong, encoded, camera, depth, far=nearest * 0.99)  # every surface lies past it
    assert torch.equal(out.rgb, wrong.rgb) and torch.equal(out.depth, wrong.depth)


def test_a_prior_point_fewer_than_two_references_see_is_never_taken():
    # At 128 px the agreement is averaged over a 5-px patch: one pixel whose prior no reference sees (a point just
    # in front of the target camera) sits in a patch that agrees, and must still keep the frame's colour.
    size = 128
    encoded = encoded_ring(size)
    camera = orbit_cameras(1, size, phase=0.3)
    depth = sphere_depth(camera)
    prior = depth.clone()
    prior[size // 2, size // 2] = 0.05
    # The frame's depth in front of the sphere, where the references disagree far more than the patch's one
    # unseen pixel costs.
    wrong = frame(torch.full((size, size, 3), 0.5), torch.nan_to_num(depth * 0.7, nan=4.0))
    out = blend_at_prior(wrong, encoded, camera, prior, FAR)
    assert (out.depth == depth).float().mean() > 0.1  # the patch around it is taken
    assert torch.equal(out.rgb[size // 2, size // 2], wrong.rgb[size // 2, size // 2])
    assert out.depth[size // 2, size // 2] == wrong.depth[size // 2, size // 2]


def test_the_mix_weighs_each_depth_inversely_to_its_variance_squared():
    at_prior = torch.tensor([1.0, 1.0, 2.0, 0.0, 0.0, 3.0])
    at_render = torch.tensor([1.0, 2.0, 1.0, 0.0, 5.0, 0.0])
    expected = torch.tensor([0.5, 0.8, 0.2, 0.0, 1.0, 0.0])  # both agree perfectly: the frame's colour
    torch.testing.assert_close(mix_share(at_prior, at_render, BLEND.mix_power), expected)


def test_the_fills_mix_passes_one_half_at_the_margin_and_is_steep_around_it():
    ratio = torch.tensor([0.25, 0.5, 1.0, 2.0, 4.0])  # v_render / (BLEND.margin v_prior)
    share = mix_share(torch.full_like(ratio, 0.01), 0.01 * BLEND.margin * ratio, BLEND.fill_power, BLEND.margin)
    torch.testing.assert_close(share, ratio ** BLEND.fill_power / (ratio ** BLEND.fill_power + 1))
    assert share[2] == pytest.approx(0.5)
    assert share[1] < 0.15 and share[3] > 0.85  # a factor 2 either side: nearly the all-or-nothing rule


def test_on_the_splats_a_true_prior_pulls_a_wrong_frame_toward_the_photo(scene):
    encoded, camera, photo, depth = scene
    grey = torch.full_like(photo, 0.5)
    wrong = frame(grey, torch.nan_to_num(depth * 1.3, nan=4.0))
    on_sphere = torch.isfinite(depth)
    out = blend_at_prior(wrong, encoded, camera, depth, FAR, splatted=on_sphere)
    error, before = ((out.rgb - photo).abs()[on_sphere], (grey - photo).abs()[on_sphere])
    assert error.mean() < 0.3 * before.mean()
    assert ((out.depth == depth) & on_sphere).sum() >= 0.7 * on_sphere.sum()  # the blend's share passes one half
    assert torch.equal(out.rgb[~on_sphere], grey[~on_sphere])


def test_on_the_splats_a_wrong_prior_barely_moves_a_right_frame(scene):
    encoded, camera, photo, depth = scene
    right = frame(photo, torch.nan_to_num(depth, nan=4.0))
    on_sphere = torch.isfinite(depth)
    mixed = blend_at_prior(right, encoded, camera, depth * 1.3, FAR, splatted=on_sphere)
    # What the wrong prior's blend alone paints: the frame's colour moves a small share of the way there.
    one = torch.ones(1)
    rays = rays_for_image(camera.to(dtype=encoded.images.dtype), one, one)
    blended = blend(reference_colours(encoded, rays, (depth * 1.3).reshape(-1))).reshape(photo.shape)
    assert (mixed.rgb - photo).abs()[on_sphere].mean() < 0.25 * (blended - photo).abs()[on_sphere].mean()
    assert (mixed.depth == depth * 1.3).float()[on_sphere].mean() < 0.1  # 0.04: the silhouette's pixels


def test_pixels_no_point_lands_on_keep_the_fills_rule(scene):
    encoded, camera, photo, depth = scene
    wrong = frame(torch.full_like(photo, 0.5), torch.nan_to_num(depth * 1.3, nan=4.0))
    plain = blend_at_prior(wrong, encoded, camera, depth, FAR)
    none = blend_at_prior(wrong, encoded, camera, depth, FAR, splatted=torch.zeros_like(depth, dtype=torch.bool))
    assert torch.equal(plain.rgb, none.rgb) and torch.equal(plain.depth, none.depth)


def test_a_lone_mixed_pixel_moves_its_window_by_the_part_it_covers_and_nothing_else():
    size = (128, 96)  # the feather window: 5/256 of 128 px, 3 px
    mixed = torch.zeros(size, dtype=torch.bool)
    mixed[40, 50] = True
    window = torch.zeros_like(mixed)
    window[39:42, 49:52] = True
    for hard, mix in ((0.0, 1.0), (1.0, 0.25)):
        share = feathered(torch.full((128 * 96,), hard), torch.full((128 * 96,), mix), mixed).reshape(size)
        torch.testing.assert_close(share[window], torch.full((9,), hard + (mix - hard) / 9))
        assert torch.equal(share[~window], torch.full((128 * 96 - 9,), hard))  # no rim


def test_a_fill_is_smooth_where_every_splat_it_could_come_from_lies_on_one_surface():
    # At 64 px the fill reaches 3 px (12/256): a pixel's window is 7 px square.
    prior = torch.full((64, 64), torch.nan)
    splatted = torch.zeros(64, 64, dtype=torch.bool)
    for col, depth in ((10, 2.0), (14, 2.2), (40, 2.0), (44, 3.0)):  # a gentle slope, then a step
        splatted[32, col] = True
        prior[32, col] = depth
    prior[30:35, 8:17] = torch.where(splatted[30:35, 8:17], prior[30:35, 8:17], torch.tensor(2.1))  # filled
    prior[30:35, 38:47] = torch.where(splatted[30:35, 38:47], prior[30:35, 38:47], torch.tensor(2.5))
    smooth = smooth_fill(prior, splatted)
    assert smooth[32, 12] and smooth[30, 8]  # both points within 10 %
    assert not smooth[32, 42]  # the fill between 2 and 3 crosses a step
    assert smooth[32, 38]  # ... but the step's far point is 6 px off: out of this pixel's window
    assert not smooth[splatted].any()  # a splat is not a fill
    assert not smooth[0, 0]  # no prior


def test_between_splats_on_one_smooth_surface_the_fill_is_mixed_like_a_splat(scene):
    # A frame at the true depth agrees there exactly as the prior does: the all-or-nothing rule keeps its colour, the
    # mix moves it half way to the blend. Splats every 4th pixel, filled between.
    encoded, camera, photo, depth = scene
    grey = frame(torch.full_like(photo, 0.5), torch.nan_to_num(depth, nan=4.0))
    on_sphere = torch.isfinite(depth)
    splatted = torch.zeros_like(on_sphere)
    splatted[::4, ::4] = True
    splatted &= on_sphere
    out = blend_at_prior(grey, encoded, camera, depth, FAR, splatted=splatted)
    fills = on_sphere & ~splatted & smooth_fill(depth, splatted)
    assert fills.sum() > 0.5 * on_sphere.sum()
    moved = (out.rgb - grey.rgb).abs().amax(dim=-1)
    assert (moved[fills] > 0.01).float().mean() > 0.8
    assert torch.equal(out.rgb[~on_sphere], grey.rgb[~on_sphere])


def test_the_blends_lookup_drops_a_reference_whose_map_shows_a_nearer_surface(scene):
    encoded, camera, photo, depth = scene
    views = encoded.images.shape[0]
    surface = torch.full((views, 1, 4, 4), torch.inf, dtype=torch.float64)
    surface[0] = 0.1  # view 0's own points: a surface right in front of it everywhere
    hidden = encoded.with_occlusion(Occlusion(surface, torch.zeros(views, dtype=torch.float64), OCCLUSION.tolerance,
                                                     OCCLUSION.min_visible))
    one = torch.ones(1)
    rays = rays_for_image(camera.to(dtype=encoded.images.dtype), one, one)
    prior = depth.reshape(-1)
    plain, occluded = (reference_colours(e, rays, prior).mask[:, 0] for e in (encoded, hidden))  # [V, R]
    # Where fewer than OCCLUSION.min_visible views would be left, every view that sees it keeps it (model.occlusion.visible).
    sees = (plain[0] > 0) & (plain[1:].sum(dim=0) >= OCCLUSION.min_visible)
    assert sees.sum() > 0.2 * torch.isfinite(prior).sum()
    assert not occluded[0][sees].any()
    assert torch.equal(occluded[1:], plain[1:])


def test_the_background_plane_is_a_high_quantile_of_the_priors_depths_within_the_far_bound():
    prior = torch.full((10, 20), torch.nan)
    prior.view(-1)[:100] = torch.arange(1, 101, dtype=torch.float32)
    assert background_plane(prior, far=50.0) == pytest.approx(round(BLEND.background_quantile * 50))
    assert background_plane(prior, far=0.5) is None
    assert background_plane(torch.full((4, 4), torch.nan), far=10.0) is None


def test_in_an_object_capture_pixels_without_a_prior_mix_in_the_blend_at_the_background_plane(scene):
    encoded, camera, photo, depth = scene
    grey = frame(torch.full_like(photo, 0.5), torch.nan_to_num(depth * 0.7, nan=1.0))
    prior = depth.clone()
    prior[:, SIZE // 2:] = torch.nan  # half the sphere has no point, as a frame whose points miss a surface
    bare = ~torch.isfinite(prior)
    left_alone = blend_at_prior(grey, encoded, camera, prior, FAR)
    assert torch.equal(left_alone.rgb[bare], grey.rgb[bare])  # forward-facing: no plane
    out = blend_at_prior(grey, encoded, camera, prior, FAR, background=True)
    before, after = (grey.rgb - photo).abs()[bare].mean(), (out.rgb - photo).abs()[bare].mean()
    assert after < 0.7 * before
    # Where the plane's blend takes over, the depth map holds the plane.
    plane = background_plane(prior, FAR)
    assert ((out.depth == plane) & bare).any()
    assert torch.equal(out.rgb[~bare], left_alone.rgb[~bare])  # the pixels with a prior as before


@pytest.mark.parametrize("height, width, window", [(7, 9, 1), (7, 9, 3), (5, 4, 9), (40, 33, 81), (64, 80, 17)])
def test_window_max_equals_max_pool_along_either_axis(height, width, window):
    torch.manual_seed(window)
    values = torch.randn(height, width, dtype=torch.double)
    values[torch.rand(height, width) < 0.3] = -torch.inf  # the pixels without a splat
    for dim, kernel in ((0, (window, 1)), (1, (1, window))):
        pooled = F.max_pool2d(values[None, None], kernel, stride=1, padding=tuple(k // 2 for k in kernel))[0, 0]
        brute = torch.stack([values.movedim(dim, 0)[max(0, i - window // 2):i + window // 2 + 1].amax(dim=0)
                             for i in range(values.shape[dim])]).movedim(0, dim)
        got = window_max(values, window, dim)
        assert torch.equal(got, brute) and torch.equal(got, pooled)
    with pytest.raises(ValueError):
        window_max(values, 4, 0)


@pytest.mark.parametrize("fraction", [0.05, 0.3, 1.0])
def test_patch_mean_is_the_mean_over_the_square_inside_the_frame(fraction):
    height, width = 11, 17
    cost = torch.rand(height * width, dtype=torch.double)
    window = max(1, round(fraction * width)) | 1
    grid = cost.reshape(height, width)
    expected = torch.stack([grid[max(0, r - window // 2):r + window // 2 + 1,
                                 max(0, c - window // 2):c + window // 2 + 1].mean()
                            for r in range(height) for c in range(width)])
    torch.testing.assert_close(patch_mean(cost, (height, width), fraction), expected)
