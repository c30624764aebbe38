"""insertnerf synth (generator synth-5): the sky at infinity has no surface, and the hand-held layout's
cameras spread like real captures."""
from __future__ import annotations

import json

import numpy as np
import pytest

from insertnerf_cli.scenes import load_scene
from insertnerf_cli.scenes.geometry import detect_layout
from insertnerf_cli.errors import UserError
from insertnerf_cli.synth import (GENERATOR_VERSION, CaptureOptions, SceneSpec, SynthOptions, build_dataset,
                                  generate_dataset)
from insertnerf_cli.synth.dataset import render_into
from insertnerf_cli.synth.layouts import RIGS, random_frame
from insertnerf_cli.synth.raycast import build_scene_mesh
from insertnerf_cli.synth.scene import DEPTH_SCALE, scene_cameras, scene_world
from insertnerf_cli.synth.world import Stage

from test_synth import _depth, _files

pytestmark = pytest.mark.usefixtures("one_thread")


def _spec(layout: str, index: int, views: int = 4, resolution: int = 48) -> SceneSpec:
    return SceneSpec(index=index, seed=11, layout=layout, views=views, test_views=1, resolution=resolution,
                     aspects=(1.0,), capture=CaptureOptions())


def _first_hits(caster, camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Through every pixel of ``camera`` (length 1): the triangle hit first [P] (-1: none), its ray
    parameter t [P] (z-depth: directions have camera-z = 1) and the directions [P, 3]."""
    directions = camera.ray_directions(camera.pixel_grid().reshape(1, -1, 2))[0].numpy()
    face, t, _ = caster.first(np.broadcast_to(camera.centers[0].numpy(), directions.shape), directions)
    return face, t, directions


def _misses(spec: SceneSpec) -> list[np.ndarray]:
    """Per view, [P] bool: the pixel's ray hits nothing in the scene's world."""
    world = scene_world(spec)
    caster = build_scene_mesh(world).caster
    cameras, _ = scene_cameras(spec, world)
    return [_first_hits(caster, cameras[[i]])[0] < 0 for i in range(len(cameras))]


def _first_with_sky(layout: str) -> SceneSpec:
    """The first scene of seed 11 whose views see the sky (open skies and streets: ~60% of scenes)."""
    for index in range(30):
        spec = _spec(layout, index)
        if scene_world(spec).sky is not None and any(m.any() for m in _misses(spec)):
            return spec
    raise AssertionError("no sky seen in 30 scenes")


@pytest.mark.slow
def test_sky_pixels_have_depth_zero_exactly_where_rays_leave_the_scene(tmp_path):
    spec = _first_with_sky("forward")
    render_into(tmp_path, spec)
    scene = load_scene(tmp_path / spec.name)
    world = scene_world(spec)
    caster = build_scene_mesh(world).caster
    depths = []
    sky_seen = 0
    for i in range(len(scene)):
        face, t, directions = _first_hits(caster, scene.cameras[[i]])  # the cameras read back from the files
        depth = _depth(scene, i).reshape(-1)
        leaves = face < 0
        # Depth 0 exactly on the rays that hit nothing, a finite positive depth (the hit's z) elsewhere.
        assert np.array_equal(depth == 0, leaves)
        np.testing.assert_allclose(depth[~leaves], t[~leaves], atol=DEPTH_SCALE)
        # The ground reaches 55 units: rays leave the scene only at or above the horizon.
        unit = directions[leaves] / np.linalg.norm(directions[leaves], axis=1, keepdims=True)
        assert (unit[:, 2] > -0.06).all()
        sky_seen += leaves.sum()
        depths.append(depth[~leaves])
    assert sky_seen > 0
    finite = np.concatenate(depths)
    near, far = float(scene.near[0]), float(scene.far[0])
    # near/far come from the finite surfaces only, widened by 10%.
    assert near == pytest.approx(0.9 * finite.min(), rel=1e-3) and far == pytest.approx(1.1 * finite.max(), rel=1e-3)
    record = json.loads((tmp_path / spec.name / "scene.json").read_text())
    assert record["world"]["sky"] == "at infinity (depth 0)"


@pytest.mark.slow
def test_rooms_have_no_sky_and_every_ray_ends_on_a_surface(tmp_path):
    for index in range(20):
        spec = _spec("360", index)
        world = scene_world(spec)
        if world.description["surroundings"] == "room":
            break
    assert world.sky is None
    render_into(tmp_path, spec)
    scene = load_scene(tmp_path / spec.name)
    assert all((_depth(scene, i) > 0).all() for i in range(len(scene)))


def _stages(style: str) -> list[tuple[Stage, np.random.Generator]]:
    """Stages like compose_handheld's (subject distances 2.5-6, scene depths up to 24; orbits inside rooms of
    various sizes), each with the generator its rig draws from."""
    rng = np.random.default_rng(0)
    stages = []
    for seed in range(8):
        if style == "grid":
            distance = rng.uniform(2.5, 6.0)
            stage = Stage(np.array([0.0, 0.0, rng.uniform(0, 0.8)]), min(distance * rng.uniform(2.5, 6.0), 24.0),
                          -1.0, depth=distance, style="grid")
        else:
            stage = Stage(np.zeros(3), 1.0, -rng.uniform(0.3, 1.0), rng.uniform(3.0, 5.0), ceiling=rng.uniform(2.5, 8),
                          style="orbit")
        stages.append((stage, np.random.default_rng(seed)))
    return stages


def test_handheld_grid_is_a_small_forward_facing_baseline():
    for stage, rng in _stages("grid"):
        cameras = RIGS["handheld"](rng, stage, random_frame(rng, 64, (4 / 3,)), 30)
        eyes = cameras.centers.numpy()
        axes = cameras.c2w[:, :3, 2].numpy()
        spread = eyes - eyes.mean(axis=0)
        extent = np.ptp(eyes[:, [0, 2]], axis=0).max()  # across and up: the plane the phone moves in
        # LLFF-like: a baseline of 8-40% of the subject's distance, a few % of the scene's depth.
        assert 0.08 * stage.depth < extent < 0.4 * stage.depth
        assert extent < 0.15 * stage.radius
        singular = np.linalg.svd(spread, compute_uv=False)
        assert singular[2] < 0.5 * singular[0]  # a rough plane, not a cloud
        mean_axis = axes.mean(axis=0) / np.linalg.norm(axes.mean(axis=0))
        assert np.degrees(np.arccos(np.clip(axes @ mean_axis, -1, 1))).max() < 12.0
        assert mean_axis[1] > 0.9  # facing +y, toward the subject
        assert detect_layout(cameras) == "forward"


def test_handheld_orbit_varies_height_and_distance_around_the_subject():
    for stage, rng in _stages("orbit"):
        cameras = RIGS["handheld"](rng, stage, random_frame(rng, 64, (4 / 3,)), 30)
        offset = cameras.centers.numpy() - stage.center
        distance = np.linalg.norm(offset, axis=1)
        elevation = np.degrees(np.arcsin(offset[:, 2] / distance))
        azimuth = np.unwrap(np.arctan2(offset[:, 1], offset[:, 0]))
        assert np.degrees(np.ptp(azimuth)) > 100  # walking around it, not a forward grid
        assert distance.max() / distance.min() > 1.05 and np.ptp(elevation) > 4.0
        assert distance.min() > 1.5 * stage.radius
        # Every camera looks at the subject: its centre projects near the middle of the image.
        uv, z = cameras.project(cameras.c2w.new_tensor(stage.center)[None])
        assert (z > 0).all()
        assert (uv[:, 0] - uv.new_tensor([cameras.width / 2, cameras.height / 2])).abs().max() < cameras.width / 2


@pytest.mark.slow
def test_handheld_photo_scenes_are_identical_whatever_the_workers(tmp_path):
    options = SynthOptions(scenes=2, views=4, test_views=1, resolution=32, layout="handheld", seed=5,
                           capture=CaptureOptions(photo=True))
    generate_dataset(tmp_path / "a", options, workers=1)
    generate_dataset(tmp_path / "b", options, workers=2)
    assert _files(tmp_path / "a") == _files(tmp_path / "b")


@pytest.mark.slow
def test_a_synth_4_dataset_is_recognised_and_refused_without_overwrite(tmp_path):
    options = SynthOptions(scenes=1, views=2, test_views=1, resolution=16, layout="object", seed=1)
    out = tmp_path / "d"
    generate_dataset(out, options, workers=1)
    manifest = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**manifest, "version": "synth-4"}))  # as synth-4 wrote it
    with pytest.raises(UserError, match="another generator version"):
        generate_dataset(out, options, workers=1)
    assert json.loads((out / "manifest.json").read_text())["version"] == "synth-4"  # kept as it was
    build_dataset(out, options, workers=1, overwrite=True, progress=False)
    assert json.loads((out / "manifest.json").read_text())["version"] == GENERATOR_VERSION == "synth-5"
