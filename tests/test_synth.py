"""insertnerf synth: determinism, Blender output read back by load_scene, depth consistency, resume."""
from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.errors import UserError
from insertnerf_cli.scenes import load_scene
from insertnerf_cli.synth import CaptureOptions, SceneSpec, SynthOptions, build_dataset, generate_dataset
from insertnerf_cli.synth.dataset import _init_worker, _remove_temporaries, _single_threaded, render_into
from insertnerf_cli.synth.implicit import mesh_field, sphere_sdf
from insertnerf_cli.synth.layouts import held_out_indices, look_at
from insertnerf_cli.synth.scene import scene_cameras, scene_splits, scene_world
from insertnerf_cli.synth.textures import Texture, sample

# Tiny images keep each scene well under a second.
RES = 40


def _options(**kw) -> SynthOptions:
    base = dict(scenes=2, views=4, test_views=1, resolution=RES, layout="mixed", seed=3)
    return SynthOptions(**{**base, **kw})


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.slow
def test_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path):
    options = _options(capture=CaptureOptions(noise=True, jitter=True, jpeg=True, photo=True))
    generate_dataset(tmp_path / "a", options, workers=1)
    generate_dataset(tmp_path / "b", options, workers=2)  # worker processes must not change a byte
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert len([n for n in a if n.endswith(".png")]) == 2 * 4 * 2  # rgb + depth per view
    assert a == b
    generate_dataset(tmp_path / "c", SynthOptions(**{**options.__dict__, "seed": 4}), workers=1)
    c = _files(tmp_path / "c")
    assert a["scene_00000/train/r_000.png"] != c["scene_00000/train/r_000.png"]


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["object", "forward", "360", "handheld"])
def test_load_scene_reads_back_the_cameras_used_to_render(tmp_path, layout):
    spec = _options(layout=layout, aspects=(4 / 3,)).spec(0)
    render_into(tmp_path, spec)
    scene = load_scene(tmp_path / spec.name)
    cameras, frame = scene_cameras(spec, scene_world(spec))
    order = scene_splits(spec)["train"] + scene_splits(spec)["test"]
    torch.testing.assert_close(scene.cameras.c2w, cameras.c2w[order], atol=1e-6, rtol=0)
    torch.testing.assert_close(scene.cameras.K, cameras.K[order], atol=1e-6, rtol=0)
    assert (scene.cameras.height, scene.cameras.width) in {(30, 40), (40, 30)}
    world = scene_world(spec)
    assert scene.layout == ("forward" if layout == "forward" or world.stage.style == "grid" else "object")
    assert scene.splits == {"train": [0, 1, 2], "test": [3]}
    assert scene.depth_scale == pytest.approx(0.001) and len(scene.depth_paths) == 4
    image = scene.load_image(0)
    assert image.shape == (frame.height, frame.width, 3) and image.std() > 0.01  # not a blank frame
    depth = np.stack([_depth(scene, i) for i in range(len(scene))])
    assert (depth[depth > 0].min() >= float(scene.near[0])) and (depth.max() <= float(scene.far[0]))
    if layout != "object" and world.sky is None:  # rooms: every ray ends on a surface
        assert (depth > 0).all()


def _depth(scene, i: int) -> np.ndarray:
    raw = cv2.imread(str(scene.depth_paths[i]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    return raw.astype(np.float64) * scene.depth_scale


def _sample_depth(depth: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth at pixel coordinates uv [P, 2] (centres at +0.5), and where the 4 surrounding pixels lie on one
    smooth surface.

    Inverse depth is affine in pixel coordinates on a plane, so it is interpolated bilinearly and the 4 taps
    count as one surface when their inverse depths have (almost) no second difference; creases and
    occlusion boundaries fail that test.
    """
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    inside = (x0 >= 0) & (y0 >= 0) & (x0 < depth.shape[1] - 1) & (y0 < depth.shape[0] - 1)
    x0, y0 = np.clip(x0, 0, depth.shape[1] - 2), np.clip(y0, 0, depth.shape[0] - 2)
    taps = np.stack([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]], axis=1)
    valid = inside & (taps.min(axis=1) > 0)
    inverse = 1.0 / np.where(taps > 0, taps, 1.0)
    fx, fy = x - x0, y - y0
    value = (inverse[:, 0] * (1 - fx) + inverse[:, 1] * fx) * (1 - fy) \
        + (inverse[:, 2] * (1 - fx) + inverse[:, 3] * fx) * fy
    curvature = np.abs(inverse[:, 0] + inverse[:, 3] - inverse[:, 1] - inverse[:, 2])
    return 1.0 / value, valid & (curvature < 1e-3 * inverse.mean(axis=1))


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["360", "forward"])
def test_depth_reprojects_onto_the_same_surface_point_in_another_view(tmp_path, layout):
    # 16 views: neighbours on a 360 orbit are ~22 degrees apart and share most of the scene.
    spec = SceneSpec(index=1, seed=5, layout=layout, views=16, test_views=0, resolution=64, aspects=(1.0,),
                     capture=CaptureOptions())
    render_into(tmp_path, spec)
    scene = load_scene(tmp_path / spec.name)
    a, b = scene.cameras[[0]], scene.cameras[[1]]
    depth_a, depth_b = _depth(scene, 0), _depth(scene, 1)
    uv_a = a.pixel_grid().reshape(1, -1, 2)
    points = a.unproject(uv_a, torch.from_numpy(depth_a.reshape(1, -1)))  # [1, P, 3]
    uv_b, z_b = b.project(points[0])
    found, smooth = _sample_depth(depth_b, uv_b[0].numpy())
    # Visible in b: b sees a surface at the depth of a's point (else it is hidden or off-image).
    visible = smooth & (np.abs(found - z_b[0].numpy()) < 0.01 * found) & (depth_a.reshape(-1) > 0)
    assert visible.mean() > 0.2, "the two views should share much of the scene"
    # The surface point that view b sees there, back in view a: the same pixel if depth is consistent.
    seen = b.unproject(uv_b[:, visible], torch.from_numpy(found[visible])[None])
    uv_back, _ = a.project(seen[0])
    error = (uv_back[0] - uv_a[0, visible]).norm(dim=-1)
    assert float(error.max()) < 0.5, f"reprojection error up to {float(error.max()):.3f} px"


@pytest.mark.slow
def test_a_killed_run_is_resumed_without_redoing_finished_scenes(tmp_path):
    options = _options(layout="object")
    out = tmp_path / "data"
    generate_dataset(out, options, workers=1)
    reference = _files(out / "scene_00001")
    finished = (out / "scene_00000" / "train" / "r_000.png").stat().st_mtime_ns
    # Simulate a run killed while writing scene 1: its folder never got its final name.
    (out / "scene_00001").rename(out / ".tmp-scene_00001-12345")
    (out / ".tmp-scene_00001-12345" / "train" / "r_000.png").write_bytes(b"half-written")
    run = build_dataset(out, options, workers=1, progress=False)
    assert (run.rendered, run.skipped) == (1, 1)
    assert not list(out.glob(".tmp-*"))
    assert _files(out / "scene_00001") == reference
    assert (out / "scene_00000" / "train" / "r_000.png").stat().st_mtime_ns == finished


@pytest.mark.slow
def test_refuses_a_folder_with_another_dataset_or_other_files(tmp_path):
    generate_dataset(tmp_path / "d", _options(scenes=1, layout="object"), workers=1)
    with pytest.raises(UserError, match="other options"):
        generate_dataset(tmp_path / "d", _options(scenes=1, layout="object", seed=9), workers=1)
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="not empty"):
        generate_dataset(tmp_path / "e", _options(scenes=1), workers=1)
    assert (tmp_path / "e" / "notes.txt").read_text() == "mine"


@pytest.mark.slow
def test_manifest_rebuilds_a_scene_exactly(tmp_path):
    generate_dataset(tmp_path / "d", _options(scenes=1, layout="forward"), workers=1)
    manifest = json.loads((tmp_path / "d" / "manifest.json").read_text())
    spec = SceneSpec.from_json(manifest["scenes"][0])
    render_into(tmp_path, spec)
    assert _files(tmp_path / spec.name) == _files(tmp_path / "d" / spec.name)


@pytest.mark.slow
def test_cli_renders_and_reports_bad_options_in_one_line(tmp_path):
    runner = CliRunner()
    result = runner.invoke(cli, ["synth", str(tmp_path / "s"), "--scenes", "1", "--views", "3",
                                 "--resolution", str(RES), "--workers", "1", "--layout", "360", "--square"])
    assert result.exit_code == 0, result.output
    assert "Rendered 1 scenes" in result.output
    assert len(load_scene(tmp_path / "s" / "scene_00000")) == 3
    bad = runner.invoke(cli, ["synth", str(tmp_path / "t"), "--scenes", "1", "--views", "3", "--test-views", "3"])
    assert bad.exit_code != 0 and "--test-views" in bad.output and "Traceback" not in bad.output


def test_surface_nets_mesh_a_sphere_closed_and_outward():
    mesh = mesh_field(sphere_sdf(np.zeros(3), 0.5))
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.5 ** 3, rel=0.03)  # positive: faces point outward


def test_textures_tile_and_prefilter():
    rng = np.random.default_rng(0)
    texture = Texture.from_image(rng.random((16, 16, 3)))
    uv = rng.random((100, 2))
    fine = np.zeros(100)
    assert np.allclose(sample(texture, uv, fine), sample(texture, uv + [3.0, -2.0], fine), atol=1e-5)
    coarse = sample(texture, uv, np.full(100, 10.0))  # a pixel covering many tiles sees the mean colour
    assert np.allclose(coarse, texture.atlas[:16, :16].mean(axis=(0, 1)), atol=1e-5)


def test_look_at_is_a_rotation_that_centres_the_target():
    from insertnerf_cli.cameras.camera import Cameras, intrinsics

    eyes = np.array([[3.0, 0.5, 1.0], [0.0, 0.0, -4.0]])
    c2w = look_at(eyes, np.zeros((2, 3)), np.array([0.1, 0.0]))
    rot = c2w[:, :3, :3]
    assert np.allclose(rot @ rot.transpose(0, 2, 1), np.eye(3)) and np.allclose(np.linalg.det(rot), 1.0)
    cameras = Cameras(intrinsics(50, 50, 32, 24).expand(2, 3, 3), torch.from_numpy(c2w), 48, 64)
    uv, depth = cameras.project(torch.zeros(1, 3, dtype=torch.float64))
    torch.testing.assert_close(uv[:, 0], torch.tensor([[32.0, 24.0]] * 2, dtype=torch.float64))
    assert (depth > 0).all()


def test_held_out_views_are_spread_and_counted_exactly():
    assert held_out_indices(50, 8) == sorted(set(held_out_indices(50, 8))) and len(held_out_indices(50, 8)) == 8
    assert held_out_indices(5, 5) == [0, 1, 2, 3, 4] and held_out_indices(5, 0) == []


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["object", "forward", "360", "handheld"])
def test_cameras_stay_inside_the_enclosure_and_outside_every_shape(layout):
    from insertnerf_cli.synth.compose import COMPOSERS
    from insertnerf_cli.synth.layouts import RIGS, random_frame

    enclosure = {"wall", "floor", "ceiling", "ground"}
    # Object scenes 6, 7, 39, 47 have a room or sky around them (39 and 47 once put cameras outside the room).
    for seed in {"object": (6, 7, 39, 47), "handheld": range(6)}.get(layout, range(4)):
        rng = np.random.default_rng(seed)
        world = COMPOSERS[layout](rng)
        eyes = RIGS[layout](rng, world.stage, random_frame(rng, 64, (16 / 9,)), 30).centers.numpy()
        room = [o.world_vertices() for o in world.objects if o.shape.kind in ("wall", "floor", "ceiling")]
        if room:
            corners = np.concatenate(room)
            assert np.all((eyes > corners.min(axis=0)) & (eyes < corners.max(axis=0)))
        for placed in world.objects:
            vertices = placed.world_vertices()
            if placed.shape.kind not in enclosure:  # not even inside the shape's bounding box
                low, high = vertices.min(axis=0), vertices.max(axis=0)
                assert not np.any(np.all((eyes > low) & (eyes < high), axis=1)), placed.shape.kind


def test_synth_workers_leave_ctrl_c_to_the_parent():
    # A terminal sends Ctrl-C to every worker too; one that raised KeyboardInterrupt printed a traceback.
    context = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
    with _single_threaded(), context.Pool(1, initializer=_init_worker) as pool:  # as _run forks its workers
        assert pool.apply(signal.getsignal, (signal.SIGINT,)) == signal.SIG_IGN


@pytest.mark.slow
def test_a_run_with_workers_ends_without_a_stack_trace_from_them(tmp_path):
    # The pool ends its workers with SIGTERM; forked from a parent that imported pycolmap (every command is
    # imported), each printed glog's "*** SIGTERM received ... stack trace" until the worker reset the signal.
    command = "import sys; sys.argv[0] = 'insertnerf'; from insertnerf_cli.cli.main import main; main()"
    done = subprocess.run([sys.executable, "-c", command, "synth", str(tmp_path / "s"), "--scenes", "3", "--views",
                           "2", "--test-views", "1", "--resolution", "16", "--workers", "2"],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    assert "Rendered 3 scenes" in done.stdout
    lines = [line.split("\r")[-1] for line in done.stderr.splitlines()]
    assert not [line for line in lines if line.strip() and not line.startswith("synth:")], done.stderr


def test_leftover_temporary_scene_folders_are_removed_and_nothing_else(tmp_path):
    spec = SceneSpec(index=2, seed=1, layout="object", views=4, test_views=0, resolution=32, aspects=(1.0,),
                     capture=CaptureOptions())
    ours = [tmp_path / ".tmp-scene_00002-123", tmp_path / ".tmp-scene_00002-77"]
    for folder in ours:
        (folder / "images").mkdir(parents=True)
    theirs = [tmp_path / ".tmp-notes", tmp_path / ".tmp-scene_000021-5", tmp_path / "scene_00002"]
    for folder in theirs:
        folder.mkdir()
    _remove_temporaries(tmp_path, [spec])
    assert not any(folder.exists() for folder in ours) and all(folder.is_dir() for folder in theirs)
