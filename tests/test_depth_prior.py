"""The SfM depth prior: points -> a depth map of the target view -> fine samples guided toward it."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.model.guide import GuideOptions, guide_weights
from insertnerf_cli.sfm.depth_prior import (_DIRECTIONS, PriorOptions, _min_along, covering_far, prior_depth,
                                        view_prior, view_prior_splats)
from insertnerf_cli.model.sampling import RaySamples, importance_samples
from insertnerf_cli.scenes import load_scene, normalize_scene
from insertnerf_cli.scenes.points import ScenePoints
from scene_fixtures import known_scene, write_colmap

H, W, F = 32, 48, 40.0


def camera_at_origin() -> Cameras:
    """One camera at the origin looking down +z (OpenCV), identity rotation."""
    K = intrinsics(F, F, W / 2, H / 2)[None].double()
    return Cameras(K, torch.eye(4, dtype=torch.float64)[None], H, W)


def plane_points(z: float, step: float = 0.02) -> torch.Tensor:
    xs = torch.arange(-1.5, 1.5, step, dtype=torch.float64)
    gx, gy = torch.meshgrid(xs, xs, indexing="xy")
    return torch.stack([gx.reshape(-1) * z, gy.reshape(-1) * z, torch.full((gx.numel(),), z)], dim=-1)


def test_a_plane_of_points_gives_its_depth_everywhere_it_covers() -> None:
    depth = prior_depth(plane_points(3.0), camera_at_origin())
    assert depth.shape == (H, W)
    assert torch.isfinite(depth).all()
    torch.testing.assert_close(depth, torch.full((H, W), 3.0, dtype=depth.dtype))


def test_the_nearest_point_wins_and_far_from_any_point_there_is_none() -> None:
    near = torch.tensor([[0.0, 0.0, 2.0]], dtype=torch.float64)  # at the image centre
    far = torch.tensor([[0.0, 0.0, 5.0]], dtype=torch.float64)
    depth = prior_depth(torch.cat([far, near]), camera_at_origin())
    assert float(depth[H // 2, W // 2]) == pytest.approx(2.0)
    assert math.isnan(float(depth[0, 0]))  # the corner is farther than the reach from the one splat
    behind = prior_depth(torch.tensor([[0.0, 0.0, -2.0]], dtype=torch.float64), camera_at_origin())
    assert torch.isnan(behind).all()  # points behind the camera give nothing


def test_a_far_wall_seen_between_the_sparse_points_of_a_nearer_surface_is_left_out() -> None:
    near = plane_points(2.0, step=0.05)  # a point every 2 px: discs of 1 px leave gaps between them
    near = near[(near[:, 0].abs() <= 0.3 * 2.0) & (near[:, 1].abs() <= 0.2 * 2.0)]  # the frame's middle only
    wall = plane_points(6.0)  # dense, behind it and all round it
    points = torch.cat([near, wall])
    inside = (slice(H // 2 - 6, H // 2 + 6), slice(W // 2 - 10, W // 2 + 10))
    kept = prior_depth(points, camera_at_origin(), PriorOptions(enclosed_directions=9))  # 9: never dropped
    assert float(kept[inside].max()) == pytest.approx(6.0)  # the wall shows through the gaps
    depth = prior_depth(points, camera_at_origin())
    torch.testing.assert_close(depth[inside], torch.full_like(depth[inside], 2.0))
    # Beside the surface the wall is all there is, and the wall's pixels next to its edge stay the wall's.
    torch.testing.assert_close(depth[:, :W // 2 - 14], torch.full_like(depth[:, :W // 2 - 14], 6.0))
    assert float(depth[H // 2, W // 2 - 14]) == pytest.approx(6.0)


def test_the_minimum_along_a_direction_is_the_brute_force_one() -> None:
    torch.manual_seed(0)
    values = torch.rand(20, 30)
    for reach in (1, 2, 3, 6, 8, 11):
        padded = torch.nn.functional.pad(values[None, None], (reach,) * 4, value=math.inf)[0, 0]
        for dy, dx in _DIRECTIONS:
            got = _min_along(padded, dy, dx, reach)[reach:reach + 20, reach:reach + 30]
            expected = torch.stack([padded[reach + dy * k:reach + dy * k + 20, reach + dx * k:reach + dx * k + 30]
                                    for k in range(1, reach + 1)]).amin(dim=0)
            assert torch.equal(got, expected), (reach, dy, dx)


def test_guide_weights_moves_a_share_toward_the_prior_and_keeps_the_total() -> None:
    t = torch.linspace(1.0, 5.0, 32).expand(3, 32)
    weights = torch.zeros(3, 32)
    weights[:, 5] = 0.9  # the coarse pass found a surface near t = 1.6
    prior = torch.tensor([4.0, math.nan, 100.0])  # one usable prior, one missing, one outside the samples
    guided = guide_weights(weights, t, prior, GuideOptions(share=0.75, width=0.05))
    torch.testing.assert_close(guided.sum(-1), weights.sum(-1))
    torch.testing.assert_close(guided[1:], weights[1:])  # no prior / no sample in the band: unchanged
    assert float(guided[0, 5]) == pytest.approx(0.25 * 0.9)
    near_prior = (t[0] - 4.0).abs() < 0.3
    assert float(guided[0, near_prior].sum()) > 0.5 * 0.9  # most of the moved 0.75 lies within 1.5 widths
    fine = importance_samples(RaySamples(t[:1].contiguous(), torch.cat([t[:1, :1], t[:1]], -1)), guided[:1], 16,
                              jitter=False, near=t[:1, 0], far=t[:1, -1])
    assert int(((fine.t - 4.0).abs() < 0.4).sum()) >= 10  # most fine samples now sit around the prior
    assert torch.equal(guide_weights(weights, t, prior, GuideOptions(share=0.0)), weights)


def test_the_far_bound_moves_only_for_points_past_it_and_then_covers_them() -> None:
    prior = torch.full((H, W), 3.0)
    assert covering_far(2.0, prior) == pytest.approx(3.0 * GuideOptions().band_reach)  # the band around 3 fits inside
    assert covering_far(10.0, prior) == 10.0
    assert covering_far(3.1, prior) == 3.1  # the points lie inside: the bound stays, though the band reaches past
    assert covering_far(2.0, None) == 2.0 and covering_far(2.0, torch.full((H, W), math.nan)) == 2.0
    stray = prior.clone()
    stray.view(-1)[: H * W // 200] = 100.0  # half a percent of the pixels: stray points do not set the bound
    assert covering_far(2.0, stray) == pytest.approx(3.0 * GuideOptions().band_reach)


@pytest.mark.slow
def test_render_draws_its_samples_out_to_points_past_the_scenes_far_bound(tmp_path: Path) -> None:
    """An LLFF scene whose far bounds stop short of its COLMAP points (mold_gold_cape's, round 26): each frame's
    far bound in cameras.json reaches past the points it sees, and the depth maps' scale holds it."""
    import json
    from dataclasses import replace

    from scene_fixtures import write_llff
    from cli_fixtures import make_checkpoint, run

    known = known_scene(6)
    root = write_colmap(tmp_path / "s", known)
    write_llff(root, replace(known, far=known.near + 0.3 * (known.far - known.near)))
    checkpoint = make_checkpoint(tmp_path / "tiny.pt")
    bounds = {}
    for flag in ("--sfm-depth", "--no-sfm-depth"):
        out = tmp_path / flag
        result = run("render", root, "--out", out, "--checkpoint", checkpoint, "--device", "cpu", "--resolution",
                     16, "--views", 3, "--frames", 3, flag)
        assert result.exit_code == 0, result.output
        cams = json.loads((out / "cameras.json").read_text())
        frames = cams["frames"]
        c2w = np.array([f["transform_matrix"] for f in frames])  # nerfstudio (OpenGL) convention
        depth = -np.einsum("fij,pj->fpi", np.linalg.inv(c2w)[:, :3, :3], known.points)[..., 2] - \
            np.linalg.inv(c2w)[:, None, 2, 3]  # [F, P]: OpenGL cameras look down -z
        far = np.array([f["far"] for f in frames])
        assert far.max() * 1.01 <= 65535 * cams["depth_unit_scale_factor"]  # no valid depth is clipped
        bounds[flag] = far, depth.max(axis=1)
    raised, given = bounds["--sfm-depth"][0], bounds["--no-sfm-depth"][0]
    assert (raised >= given - 1e-9).all() and (raised > given * 1.2).all()  # every frame's bound cut the points
    assert (raised <= GuideOptions().band_reach * bounds["--sfm-depth"][1] + 1e-6).all()  # no farther than they need


def test_points_seen_from_counts_only_the_allowed_views() -> None:
    xyz = torch.arange(12, dtype=torch.float64).reshape(4, 3)
    observed = (torch.tensor([0, 1, 2]), torch.tensor([0, 1]), torch.tensor([0, 3]))
    points = ScenePoints(xyz, observed)
    assert points.seen_mask([0, 1, 2]).tolist() == [True, True, False, False]  # point 2 and 3: one view each
    assert points.seen_mask([1, 2]).tolist() == [True, False, False, False]  # without view 0, point 1 has one left
    assert not points.seen_mask([]).any()
    assert ScenePoints(xyz).seen_mask([0]).tolist() == [True] * 4  # unknown observers: every point
    assert points.subset_views([2, 0]).seen_mask([0, 1]).tolist() == [True, False, False, False]
    # A target's references: only points one of them observes (view 2 sees points 0 and 3; 3 has one observer).
    assert points.seen_mask([0, 1, 2], near=[2]).tolist() == [True, False, False, False]
    assert points.seen_mask([0, 1, 2], near=[0]).tolist() == [True, True, False, False]
    assert not points.seen_mask([0, 1, 2], near=[]).any()


def test_a_frames_prior_uses_only_the_points_two_of_its_references_observe() -> None:
    near, far = plane_points(2.0, 0.05), plane_points(4.0, 0.05)
    n = len(near)
    xyz = torch.cat([near, far])
    # The near plane: seen by reference 0 and by view 5 (not a reference: a far photo, or eval's held-out one).
    # The far plane: seen by references 1 and 2. A z-buffer over every point would paint the near plane.
    observed = tuple(torch.arange(n) if v in (0, 5) else torch.arange(n, 2 * n) if v in (1, 2)
                     else torch.zeros(0, dtype=torch.int64) for v in range(6))
    points = ScenePoints(xyz, observed)
    depth = view_prior(points, camera_at_origin(), [0, 1, 2])
    torch.testing.assert_close(depth, torch.full((H, W), 4.0, dtype=depth.dtype))
    assert view_prior(points, camera_at_origin(), [0, 3]) is None  # one observer among the references: no point
    # With more references than PriorOptions().views, one of the nearest PriorOptions().views must observe the point too.
    many = ScenePoints(xyz, observed + tuple(torch.zeros(0, dtype=torch.int64) for _ in range(PriorOptions().views)))
    others = list(range(6, 6 + PriorOptions().views - 2))  # references that observe nothing
    assert view_prior(many, camera_at_origin(), [3, 4, *others, 1, 2]) is None  # 1 and 2 both beyond the nearest
    depth = view_prior(many, camera_at_origin(), [3, 1, *others, 2])  # 1 among the nearest, 2 beyond
    torch.testing.assert_close(depth, torch.full((H, W), 4.0, dtype=depth.dtype))


@pytest.mark.slow
def test_two_view_tracks_fill_only_where_better_placed_points_leave_the_prior_empty() -> None:
    left = plane_points(2.0, 0.05)
    left = left[left[:, 0] < 0]  # the left half of the frame, nearer
    wide = plane_points(4.0, 0.05)  # the whole frame, farther
    xyz = torch.cat([left, wide])
    n = len(left)
    # The near half is a two-view track (references 0 and 1); the far plane is seen by 0, 1 and view 2 as well.
    observed = (torch.arange(len(xyz)), torch.arange(len(xyz)), torch.arange(n, len(xyz)))
    points = ScenePoints(xyz, observed)
    flat = view_prior(points, camera_at_origin(), [0, 1])  # round 29's rule: the nearest point wins
    assert float(flat[H // 2, 2]) == pytest.approx(2.0) and float(flat[H // 2, W - 3]) == pytest.approx(4.0)
    placed = view_prior(points, camera_at_origin(), [0, 1], pool=[0, 1, 2])  # the far plane has three observers
    torch.testing.assert_close(placed, torch.full((H, W), 4.0, dtype=placed.dtype))
    # Where no better-placed point lies, the two-view track still gives the prior.
    alone = ScenePoints(left, tuple(torch.arange(n) for _ in range(2)) + (torch.zeros(0, dtype=torch.int64),))
    filled = view_prior(alone, camera_at_origin(), [0, 1], pool=[0, 1, 2])
    torch.testing.assert_close(filled, view_prior(alone, camera_at_origin(), [0, 1]), equal_nan=True)
    assert float(filled[H // 2, 2]) == pytest.approx(2.0)
    # A held-out view outside the pool lends no observer: the far plane is then a two-view track too.
    torch.testing.assert_close(view_prior(points, camera_at_origin(), [0, 1], pool=[0, 1]), flat, equal_nan=True)


def test_the_splats_of_a_frames_prior_are_the_pixels_its_points_cover_before_the_fill() -> None:
    # Two points, one per layer (a well-tracked one on the left, a two-view track on the right): each covers its
    # disc, and the fill carries their depths beyond it.
    xyz = torch.tensor([[-0.5, 0.0, 2.0], [0.5, 0.0, 2.0]])
    observed = (torch.tensor([0, 1]), torch.tensor([0, 1]), torch.tensor([0]))
    points = ScenePoints(xyz, observed)
    depth, splatted = view_prior_splats(points, camera_at_origin(), [0, 1], pool=[0, 1, 2])
    torch.testing.assert_close(depth, view_prior(points, camera_at_origin(), [0, 1], pool=[0, 1, 2]), equal_nan=True)
    bare = [prior_depth(xyz[i:i + 1], camera_at_origin(), PriorOptions(reach_fraction=0.0)) for i in range(2)]
    assert torch.equal(splatted, torch.isfinite(bare[0]) | torch.isfinite(bare[1]))
    assert 0 < int(splatted.sum()) < int(torch.isfinite(depth).sum())


def test_a_colmap_scene_carries_its_points_into_normalised_units(tmp_path: Path) -> None:
    known = known_scene(5)
    scene = load_scene(write_colmap(tmp_path / "c", known))
    assert scene.points is not None and len(scene.points) == len(known.points)
    assert all(len(rows) == len(known.points) for rows in scene.points.observed)
    normed, similarity = normalize_scene(scene)
    expected = similarity.apply_points(torch.from_numpy(known.points))
    order = lambda xyz: xyz[torch.argsort(xyz[:, 0])]  # noqa: E731 - COLMAP keeps its points in a hash map
    torch.testing.assert_close(order(normed.points.xyz), order(expected))
    # The prior of a view sits at its points' camera depths.
    camera = normed.cameras.subset([0])
    depth = prior_depth(normed.points.xyz, camera)
    z = (normed.points.xyz @ camera.w2c[0, :3, :3].T + camera.w2c[0, :3, 3])[:, 2]
    seen = depth[torch.isfinite(depth)]
    assert float(seen.min()) >= float(z.min()) - 1e-9 and float(seen.max()) <= float(z.max()) + 1e-9
    assert np.isfinite(depth.numpy()).mean() > 0.2


@pytest.mark.slow
@pytest.mark.parametrize("exact", [True, False])
def test_render_follows_the_prior_only_where_there_is_one(exact: bool) -> None:
    from model_fixtures import FAR, NEAR, RADIUS, tiny_model_and_views

    from insertnerf_cli.rendering.image_renderer import EXACT, Shortcuts, render_image

    model, encoded, camera = tiny_model_and_views(size=12)
    shortcuts = EXACT if exact else Shortcuts()
    plain = render_image(model, encoded, camera, NEAR, FAR, shortcuts=shortcuts)
    none = render_image(model, encoded, camera, NEAR, FAR, shortcuts=shortcuts,
                        prior=torch.full((12, 12), math.nan))
    torch.testing.assert_close(none.rgb, plain.rgb)
    torch.testing.assert_close(none.depth, plain.depth)
    surface = torch.full((12, 12), RADIUS - 1.0)  # the sphere's front, where a trained model would put it
    guided = render_image(model, encoded, camera, NEAR, FAR, shortcuts=shortcuts, prior=surface)
    # The untrained model's depth moves toward the prior.
    assert float((guided.depth - surface).abs().mean()) < float((plain.depth - surface).abs().mean())


@pytest.mark.slow
def test_eval_uses_the_points_unless_told_not_to(tmp_path: Path) -> None:
    from cli_fixtures import make_checkpoint, run

    checkpoint = make_checkpoint(tmp_path / "tiny.pt")
    scene = write_colmap(tmp_path / "c", known_scene(9))
    scores = {}
    for flag in ("--sfm-depth", "--no-sfm-depth"):
        result = run("eval", scene, "--checkpoint", checkpoint, "--device", "cpu", "--views", 3, flag,
                     "--json", tmp_path / f"{flag}.json")
        assert result.exit_code == 0, result.output
        scores[flag] = (tmp_path / f"{flag}.json").read_text()
    assert scores["--sfm-depth"] != scores["--no-sfm-depth"]


def test_fit_similarity_recovers_a_known_one() -> None:
    from insertnerf_cli.scenes.colmap_model import fit_similarity

    gen = torch.Generator().manual_seed(3)
    src = torch.randn(20, 3, generator=gen, dtype=torch.float64)
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=gen, dtype=torch.float64))
    rotation = q * torch.sign(torch.linalg.det(q))  # proper
    translation = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    R, t, s, rms = fit_similarity(src, 2.5 * src @ rotation.T + translation)
    torch.testing.assert_close(R, rotation)
    torch.testing.assert_close(t, translation)
    assert s == pytest.approx(2.5) and rms < 1e-9
    assert fit_similarity(torch.zeros(4, 3, dtype=torch.float64), src[:4]) is None


def test_an_llff_scene_takes_the_points_of_the_colmap_model_beside_it(tmp_path: Path) -> None:
    from scene_fixtures import write_llff

    known = known_scene(6)
    root = write_colmap(tmp_path / "s", known)
    write_llff(root, known)  # poses_bounds.npy is read first; sparse/0 holds the same solution
    scene = load_scene(root)
    assert scene.format == "llff" and scene.points is not None and len(scene.points) == len(known.points)
    # Another solution beside the cameras (two of the model's cameras swapped) is not taken for this one.
    moved = type(known)(known.cameras.subset([1, 0, 2, 3, 4, 5]), *[getattr(known, f) for f in
                                                                   ("points", "images", "names", "near", "far")])
    write_colmap(tmp_path / "m", moved)
    write_llff(tmp_path / "m", known)
    assert load_scene(tmp_path / "m").points is None


def test_poses_output_reads_its_points_with_their_observers(tmp_path: Path) -> None:
    """transforms.json as `insertnerf poses` writes it: colmap_model + each frame's colmap_im_id."""
    from insertnerf_cli.scenes.writers import write_nerfstudio_transforms

    known = known_scene(6)
    root = write_colmap(tmp_path / "p", known)  # sparse/0 with image ids 1..6 in name order
    (root / "sparse").rename(root / "colmap")
    order = [3, 0, 5, 1, 4, 2]  # frames in another order than the model's ids
    write_nerfstudio_transforms(root / "transforms.json", known.cameras.subset(order),
                                [f"images/{known.names[i]}" for i in order], near=known.near[order],
                                far=known.far[order], extra={"colmap_model": "colmap/0"},
                                frame_extras=[{"colmap_im_id": i + 1} for i in order])
    scene = load_scene(root)
    assert scene.format == "nerfstudio" and scene.points.observed is not None
    assert int(scene.points.seen_mask([0, 1]).sum()) == len(known.points)  # every point is seen by every view
    # A frame whose id the model lacks observes nothing.
    write_nerfstudio_transforms(root / "transforms.json", known.cameras.subset(order),
                                [f"images/{known.names[i]}" for i in order], near=known.near[order],
                                far=known.far[order], extra={"colmap_model": "colmap/0"},
                                frame_extras=[{"colmap_im_id": 99 if i == 3 else i + 1} for i in order])
    points = load_scene(root).points
    assert len(points.observed[0]) == 0 and not points.seen_mask([0, 1]).any()
    assert int(points.seen_mask([1, 2]).sum()) == len(known.points)


def test_a_damaged_model_beside_an_llff_scene_is_ignored(tmp_path: Path) -> None:
    from scene_fixtures import write_llff

    root = write_llff(tmp_path / "s", known_scene(5))
    (root / "sparse" / "0").mkdir(parents=True)
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        (root / "sparse" / "0" / name).write_bytes(b"\xff" * 7)
    scene = load_scene(root)
    assert scene.format == "llff" and scene.points is None
