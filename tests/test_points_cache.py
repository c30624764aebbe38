"""Triangulated SfM points kept in OUT/points/ and reused by a later render or eval of the same scene."""
from __future__ import annotations

import os
from dataclasses import replace

import pytest
import torch
from cli_fixtures import make_checkpoint, run

import textured_scenes
from insertnerf_cli.scenes import load_scene
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.sfm.points_cache import cache_file, cache_key, load_points, save_points
from insertnerf_cli.sfm.triangulate import TriangulateOptions

pytestmark = pytest.mark.usefixtures("one_thread")
VIEWS, SIZE = 8, 120


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    """(a nerfstudio scene of the textured room at its true poses with no points, a tiny checkpoint)."""
    root = tmp_path_factory.mktemp("points_cache")
    textured_scenes.write_posed_room(root / "scene", VIEWS, SIZE)
    return root / "scene", make_checkpoint(root / "tiny.pt")


def test_points_round_trip_with_their_observations_and_a_bad_file_is_ignored(tmp_path):
    xyz = torch.randn(5, 3, dtype=torch.float64)
    observed = (torch.tensor([0, 2, 4]), torch.tensor([], dtype=torch.int64), torch.tensor([1, 2]))
    path = tmp_path / "p.npz"
    save_points(path, ScenePoints(xyz, observed), 3)
    loaded = load_points(path, 3)
    assert torch.equal(loaded.xyz, xyz) and all(torch.equal(a, b) for a, b in zip(loaded.observed, observed))
    assert load_points(path, 4) is None  # written for a scene of another view count
    assert load_points(tmp_path / "missing.npz", 3) is None
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    assert load_points(tmp_path / "bad.npz", 3) is None


@pytest.mark.slow
def test_the_key_follows_the_photos_the_poses_and_the_views(posed):
    scene = load_scene(posed[0])
    options = TriangulateOptions()
    key = cache_key(scene, range(VIEWS), options)
    assert key == cache_key(load_scene(posed[0]), range(VIEWS), options)
    assert key != cache_key(scene, range(VIEWS - 1), options)
    moved = scene.cameras.c2w.clone()
    moved[0, 0, 3] += 1e-3
    assert key != cache_key(replace(scene, cameras=replace(scene.cameras, c2w=moved)), range(VIEWS), options)
    photo = scene.image_paths[0]
    stat = photo.stat()
    os.utime(photo, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # the photo was replaced
    assert key != cache_key(load_scene(posed[0]), range(VIEWS), options)
    os.utime(photo, ns=(stat.st_atime_ns, stat.st_mtime_ns))


@pytest.mark.slow
def test_a_second_render_at_another_resolution_reuses_the_points(posed, tmp_path):
    scene, ckpt = posed
    out = tmp_path / "views"
    args = ["render", scene, "--out", out, "--checkpoint", ckpt, "--device", "cpu", "--views", 3, "--frames", 1]
    first = run(*args, "--resolution", 32)
    assert first.exit_code == 0, first.output
    assert "triangulating SfM points" in first.output
    stored = sorted((out / "points").glob("*.npz"))
    assert len(stored) == 1 and len(load_points(stored[0], VIEWS)) > 50
    second = run(*args, "--resolution", 24, "--overwrite")
    assert second.exit_code == 0, second.output
    assert "triangulating" not in second.output and "triangulated by an earlier run" in second.output
    assert sorted((out / "points").glob("*.npz")) == stored
    assert stored[0] == cache_file(out / "points", stored[0].stem)


@pytest.mark.slow
def test_eval_with_out_keeps_the_points_of_its_references(posed, tmp_path):
    scene, ckpt = posed
    args = ["eval", scene, "--checkpoint", ckpt, "--device", "cpu", "--views", 3, "--resolution", 24,
            "--out", tmp_path / "report"]
    first = run(*args)
    assert first.exit_code == 0, first.output
    assert len(list((tmp_path / "report" / "points").glob("*.npz"))) == 1
    second = run(*args, "--overwrite")
    assert second.exit_code == 0 and "triangulated by an earlier run" in second.output


@pytest.mark.slow
def test_a_points_cache_folder_serves_renders_into_other_folders_and_outlives_overwrite(posed, tmp_path):
    scene, ckpt = posed
    cache = tmp_path / "shared" / "points"
    args = ["--checkpoint", ckpt, "--device", "cpu", "--views", 3, "--frames", 1, "--points-cache", cache]
    first = run("render", scene, "--out", tmp_path / "a", "--resolution", 32, *args)
    assert first.exit_code == 0, first.output
    assert "triangulating SfM points" in first.output
    stored = sorted(cache.glob("*.npz"))
    assert len(stored) == 1 and not (tmp_path / "a" / "points").exists()
    for out, extra in ((tmp_path / "b", []), (tmp_path / "a", ["--overwrite"])):
        again = run("render", scene, "--out", out, "--resolution", 24, *args, *extra)
        assert again.exit_code == 0, again.output
        assert "triangulating" not in again.output and f"loaded from {stored[0]}" in again.output.replace("\n", "")
    assert sorted(cache.glob("*.npz")) == stored  # --overwrite removed only what render recorded in a/
    evaluated = run("eval", scene, "--views", 3, "--resolution", 24, *args[:4], "--points-cache", cache)
    assert evaluated.exit_code == 0, evaluated.output  # eval triangulates from its references alone: its own key
    assert len(list(cache.glob("*.npz"))) == 2


def test_a_points_cache_inside_the_scene_is_refused_before_any_work(posed, tmp_path):
    scene, ckpt = posed
    before = sorted(p.relative_to(scene) for p in scene.rglob("*"))
    for command in (["render", scene, "--out", tmp_path / "views"], ["eval", scene]):
        result = run(*command, "--checkpoint", ckpt, "--device", "cpu", "--points-cache", scene / "points")
        assert result.exit_code == 1
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and "--points-cache" in lines[0] and "inside the input scene" in lines[0], lines
    assert sorted(p.relative_to(scene) for p in scene.rglob("*")) == before
    assert not (tmp_path / "views").exists()


@pytest.mark.slow
def test_finetune_keeps_its_points_in_the_cache_and_a_second_finetune_loads_them(posed, tmp_path):
    scene, ckpt = posed
    cache = tmp_path / "points"
    args = ["finetune", scene, "--checkpoint", ckpt, "--device", "cpu", "--steps", 1, "--views", 3,
            "--resolution", 32, "--points-cache", cache]
    first = run(*args, "--out", tmp_path / "a.pt")
    assert first.exit_code == 0, first.output
    assert "triangulating SfM points" in first.output and len(list(cache.glob("*.npz"))) == 1
    second = run(*args, "--out", tmp_path / "b.pt")
    assert second.exit_code == 0, second.output
    assert "triangulating" not in second.output and "triangulated by an earlier run" in second.output
    inside = run(*args[:-1], scene / "points", "--out", tmp_path / "c.pt")
    assert inside.exit_code == 1 and "--points-cache" in inside.output and not (tmp_path / "c.pt").exists()
