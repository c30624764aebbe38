"""SfM points for a posed scene that came without them: triangulated at its own poses, on the true surface."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from insertnerf_cli.scenes import load_scene
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms
from insertnerf_cli.sfm.triangulate import triangulate_points, with_points
import textured_scenes

VIEWS, SIZE = 8, 160


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """(a nerfstudio scene of the textured room at its true poses, with no points; the mesh)."""
    root = tmp_path_factory.mktemp("posed_room")
    textured_scenes.write_posed_room(root, VIEWS, SIZE)
    return root, textured_scenes.scene_mesh()


def _true_depth_ratio(mesh: trimesh.Trimesh, centre: np.ndarray, points: np.ndarray) -> np.ndarray:
    """[P] each point's distance from ``centre`` over the distance to the mesh along the same ray (1: on it)."""
    dirs = points - centre
    dist = np.linalg.norm(dirs, axis=1)
    hit = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    _, ray, locations = hit.intersects_id(np.broadcast_to(centre, dirs.shape), dirs / dist[:, None],
                                          multiple_hits=False, return_locations=True)
    surface = np.full(len(points), np.nan)
    surface[ray] = np.linalg.norm(locations - centre, axis=1)
    return dist / surface


@pytest.mark.slow
def test_points_triangulated_at_the_scene_poses_lie_on_the_surface(room) -> None:
    root, mesh = room
    scene = load_scene(root)
    assert scene.points is None
    points = triangulate_points(scene, quiet=True)
    assert len(points) > 200
    assert all(len(o) > 50 for o in points.observed)
    ratio = _true_depth_ratio(mesh, scene.cameras.centers[0].numpy(), points.xyz[points.observed[0]].numpy())
    assert np.isfinite(ratio).mean() > 0.95
    errors = np.abs(ratio[np.isfinite(ratio)] - 1)
    assert np.median(errors) < 0.005 and np.quantile(errors, 0.9) < 0.02, (np.median(errors), np.quantile(errors, 0.9))
    assert bool(points.seen_mask(range(VIEWS)).all())  # tracks of two views or more


@pytest.mark.slow
def test_only_the_given_views_observe_and_a_held_out_view_lends_nothing(room) -> None:
    scene = load_scene(room[0])
    points = triangulate_points(scene, views=range(VIEWS - 1), quiet=True)
    assert len(points.observed) == VIEWS and len(points.observed[VIEWS - 1]) == 0
    assert len(points) > 200


@pytest.mark.slow
def test_with_points_keeps_a_scenes_own_points_and_warns_where_none_can_be_made(room, tmp_path: Path,
                                                                                capsys) -> None:
    scene = with_points(load_scene(room[0]))
    assert scene.points is not None
    assert with_points(scene) is scene  # a scene that has points is never triangulated again
    flat = tmp_path / "flat"
    (flat / "images").mkdir(parents=True)
    names = [f"images/grey_{i}.png" for i in range(3)]
    for name in names:
        cv2.imwrite(str(flat / name), np.full((SIZE, SIZE, 3), 128, np.uint8))  # no feature to match
    cams = scene.cameras.subset([0, 1, 2])
    write_nerfstudio_transforms(flat / "transforms.json", cams, names, near=0.5, far=8.0)
    plain = load_scene(flat)
    before = sorted(p.relative_to(flat) for p in flat.rglob("*"))
    assert with_points(plain) is plain
    err = capsys.readouterr().err
    assert "without the depth prior" in err and err.count("\n") >= 1
    with pytest.raises(ValueError, match="cannot triangulate"):
        triangulate_points(plain, views=[0], quiet=True)
    assert sorted(p.relative_to(flat) for p in flat.rglob("*")) == before  # COLMAP's SIFT worked in a temporary folder


@pytest.mark.slow
def test_eval_and_render_triangulate_a_posed_scene_without_points(room, tmp_path: Path) -> None:
    from cli_fixtures import make_checkpoint, run

    checkpoint = make_checkpoint(tmp_path / "tiny.pt")
    scores = {}
    for flag in ("--sfm-depth", "--no-sfm-depth"):
        result = run("eval", room[0], "--checkpoint", checkpoint, "--views", 3, "--resolution", 32, flag,
                     "--json", tmp_path / f"{flag}.json")
        assert result.exit_code == 0, result.output
        assert ("at the scene's poses from 7 views" in result.output) == (flag == "--sfm-depth")
        scores[flag] = (tmp_path / f"{flag}.json").read_text()
    assert scores["--sfm-depth"] != scores["--no-sfm-depth"]  # the prior changed the renders
    result = run("render", room[0], "--out", tmp_path / "out", "--checkpoint", checkpoint, "--resolution", 16,
                 "--views", 2, "--frames", 2)
    assert result.exit_code == 0, result.output
    assert "at the scene's poses from 8 views" in result.output


@pytest.mark.slow
def test_photos_colmap_cannot_read_are_triangulated_from_copies(room, tmp_path: Path) -> None:
    """WebP (COLMAP has no decoder for it): copied as PNG into the temporary folder, never beside the scene."""
    source = load_scene(room[0])
    root = tmp_path / "webp"
    (root / "images").mkdir(parents=True)
    names = [f"images/view_{i:02d}.webp" for i in range(VIEWS)]
    for name, path in zip(names, source.image_paths):
        image = cv2.imread(str(path))
        assert cv2.imwrite(str(root / name), image, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
    write_nerfstudio_transforms(root / "transforms.json", source.cameras, names, near=0.5, far=8.0)
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    points = triangulate_points(load_scene(root), quiet=True)
    assert len(points) > 200 and all(len(o) > 50 for o in points.observed)
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before
