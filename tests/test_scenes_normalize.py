"""Normalisation: focus at the origin, canonical radius, bounds scaled, and the similarity undoes it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.scenes import Similarity, load_scene, normalize_scene
from insertnerf_cli.scenes.geometry import detect_layout, focus_point, folded_walk_warning, walk_jumps
from insertnerf_cli.scenes.normalize import FORWARD_NEAR_FRACTION, OBJECT_RADIUS
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms
from scene_fixtures import known_scene, look_at, write_images, write_llff

OFFSET = torch.tensor([3.0, -1.0, 7.0], dtype=torch.float64)
SCALE = 0.37


def moved_known(tmp_path: Path):
    """The known scene shifted by OFFSET and shrunk by SCALE, written as nerfstudio."""
    known = known_scene()
    sim = Similarity(torch.eye(3, dtype=torch.float64), OFFSET, SCALE)
    cams = sim.apply_cameras(known.cameras)
    write_images(tmp_path / "images", known)
    write_nerfstudio_transforms(tmp_path / "transforms.json", cams, [f"images/{n}" for n in known.names],
                                near=known.near * SCALE, far=known.far * SCALE)
    return known, load_scene(tmp_path)


def test_object_scene_is_centred_on_the_focus_with_radius_4(tmp_path: Path) -> None:
    known, scene = moved_known(tmp_path)
    torch.testing.assert_close(focus_point(scene.cameras), OFFSET)
    normed, sim = normalize_scene(scene)
    torch.testing.assert_close(focus_point(normed.cameras), torch.zeros(3, dtype=torch.float64))
    radius = normed.cameras.centers.norm(dim=-1)
    torch.testing.assert_close(radius.mean(), torch.tensor(OBJECT_RADIUS, dtype=torch.float64))
    torch.testing.assert_close(normed.cameras.c2w, known.cameras.c2w)  # ring radius 4 around the origin
    torch.testing.assert_close(normed.near, scene.near * sim.scale)
    torch.testing.assert_close(normed.far, scene.far * sim.scale)
    torch.testing.assert_close(normed.cameras.K, scene.cameras.K)
    assert normed.depth_scale == pytest.approx(scene.depth_scale * sim.scale)


def test_similarity_inverse_and_json_round_trip(tmp_path: Path) -> None:
    _, scene = moved_known(tmp_path)
    normed, sim = normalize_scene(scene)
    back = sim.inverse().apply_cameras(normed.cameras)
    torch.testing.assert_close(back.c2w, scene.cameras.c2w)
    points = torch.randn(10, 3, dtype=torch.float64)
    again = Similarity.from_json(sim.to_json())
    torch.testing.assert_close(again.apply_points(points), sim.apply_points(points))
    torch.testing.assert_close(sim.inverse().apply_points(sim.apply_points(points)), points)
    # Projections do not change under the similarity: pixels of a point and of its image agree.
    uv, depth = scene.cameras.project(points)
    uv2, depth2 = normed.cameras.project(sim.apply_points(points))
    torch.testing.assert_close(uv2, uv)
    torch.testing.assert_close(depth2, depth * sim.scale)


def test_similarity_with_rotation_inverts() -> None:
    angle = 0.7
    R = torch.tensor([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]],
                     dtype=torch.float64)
    sim = Similarity(R, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64), 2.0)
    cams = known_scene().cameras
    torch.testing.assert_close(sim.inverse().apply_cameras(sim.apply_cameras(cams)).c2w, cams.c2w)
    with pytest.raises(ValueError):
        Similarity(R, torch.zeros(3, dtype=torch.float64), -1.0)


def test_forward_scene_is_centred_on_the_cameras(tmp_path: Path) -> None:
    known = known_scene()
    down = np.array([0.0, -1.0, 0.0])
    poses = [look_at(np.array([x, y, 0.0]) + 5.0, np.array([x, y, 10.0]) + 5.0, down) for x in (-1, 1) for y in (-1, 1)]
    cams = Cameras(known.cameras.K[:4], torch.from_numpy(np.stack(poses)), known.cameras.height, known.cameras.width)
    assert detect_layout(cams) == "forward"
    write_images(tmp_path / "images", known)
    write_nerfstudio_transforms(tmp_path / "transforms.json", cams, [f"images/{n}" for n in known.names[:4]],
                                near=[2.0, 3.0, 4.0, 5.0], far=[20.0] * 4)
    normed, sim = normalize_scene(load_scene(tmp_path))
    torch.testing.assert_close(normed.cameras.centers.mean(0), torch.zeros(3, dtype=torch.float64))
    assert abs(float(normed.near.min()) * FORWARD_NEAR_FRACTION - 1.0) < 1e-12
    torch.testing.assert_close(normed.far / normed.near, torch.tensor([10.0, 20 / 3, 5.0, 4.0], dtype=torch.float64))


def test_llff_layout_detection_on_the_known_ring(tmp_path: Path) -> None:
    known = known_scene()
    scene = load_scene(write_llff(tmp_path, known))
    assert scene.layout == "object"  # LLFF files can hold 360-degree captures too
    assert detect_layout(known.cameras.subset([0])) == "forward"


def _walk(azimuths_deg: list[float]) -> Cameras:
    """Cameras at these azimuths (in this order) on a ring of radius 4, 20 degrees up, looking at the origin."""
    c2w = []
    for a in np.radians(azimuths_deg):
        centre = 4.0 * np.array([np.cos(a) * np.cos(0.35), np.sin(a) * np.cos(0.35), np.sin(0.35)])
        c2w.append(look_at(centre, np.zeros(3)))
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]], dtype=torch.float64).expand(len(c2w), 3, 3)
    return Cameras(K.clone(), torch.tensor(np.stack(c2w)), 48, 64)


def test_a_folded_walk_is_flagged_and_an_honest_one_is_not() -> None:
    """Beer's poses: 1.5 turns in 7-degree steps laid on one 150-degree arc, each pass jumping back. A walk in
    order, the same walk in a random order, and two clips (one jump) give no warning."""
    walk = [7.0 * i for i in range(72)]  # 1.4 turns
    folded = [(-110.0 + (a % 150.0)) for a in walk]  # every pass of 150 degrees starts the arc again
    names = [f"{i:04d}.jpg" for i in range(72)]
    centre = torch.zeros(3, dtype=torch.float64)
    jumps = walk_jumps(_walk(folded), centre)
    assert [i for i, _ in jumps] == [21, 42, 64] and all(step > 100 for _, step in jumps)
    warning = folded_walk_warning(names, _walk(folded), centre)
    assert warning is not None and "0021.jpg | 0022.jpg" in warning and "insertnerf poses" in warning
    assert walk_jumps(_walk(walk), centre) == [] and folded_walk_warning(names, _walk(walk), centre) is None
    shuffled = list(np.random.default_rng(0).permutation(walk))
    assert folded_walk_warning(names, _walk(shuffled), centre) is None  # unordered photos: large median step
    two_clips = walk[:36] + [a + 150.0 for a in walk[:36]]
    assert len(walk_jumps(_walk(two_clips), centre)) == 1
    assert folded_walk_warning(names, _walk(two_clips), centre) is None
