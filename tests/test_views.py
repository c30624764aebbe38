"""Nearest reference views: analytic answers on a circle of cameras looking at its centre."""
import math

import numpy as np
import pytest
import torch

from insertnerf_cli.scenes.views import ViewSampling, nearest_views, sample_training_views, view_distances


def look_at(eye: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """OpenCV c2w [4, 4] at ``eye`` looking at ``target`` with world +z up (image y down = world -z)."""
    forward = (target - eye) / (target - eye).norm()
    right = torch.linalg.cross(forward, torch.tensor([0.0, 0.0, 1.0], dtype=eye.dtype))
    right = right / right.norm()
    down = torch.linalg.cross(forward, right)
    c2w = torch.eye(4, dtype=eye.dtype)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def circle(degrees: list[float], radius: float = 4.0, center=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Cameras [N, 4, 4] on a horizontal circle, each looking at the centre."""
    c = torch.tensor(center, dtype=torch.float64)
    eyes = [c + radius * torch.tensor([math.cos(math.radians(d)), math.sin(math.radians(d)), 0.0],
                                      dtype=torch.float64) for d in degrees]
    return torch.stack([look_at(e, c) for e in eyes])


REFS = [30.0 * i for i in range(12)]  # 0, 30, ..., 330 degrees


def test_vector_method_orders_by_angle_on_a_circle():
    target = circle([10.0])[0]
    dist = view_distances(target, circle(REFS), "vector")
    expected = [math.radians(min(abs(d - 10.0), 360.0 - abs(d - 10.0))) for d in REFS]
    torch.testing.assert_close(dist, torch.tensor(expected, dtype=torch.float64))
    assert nearest_views(target, circle(REFS), 5) == [0, 1, 11, 2, 10]


@pytest.mark.parametrize("method", ["dist", "matrix"])
def test_distance_and_rotation_methods_agree_with_geometry(method):
    target = circle([10.0])[0]
    delta = torch.tensor([math.radians(min(abs(d - 10.0), 360.0 - abs(d - 10.0))) for d in REFS],
                         dtype=torch.float64)
    # Chord length 2 r sin(delta / 2); the relative rotation of two look-at cameras is delta about the up axis.
    expected = 2 * 4.0 * torch.sin(delta / 2) if method == "dist" else delta
    torch.testing.assert_close(view_distances(target, circle(REFS), method), expected)
    assert nearest_views(target, circle(REFS), 3, method=method) == [0, 1, 11]


def test_vector_method_uses_the_given_scene_center():
    center = (5.0, -2.0, 1.0)
    refs, target = circle(REFS, center=center), circle([100.0], center=center)[0]
    expected = torch.tensor([math.radians(min(abs(d - 100.0), 360.0 - abs(d - 100.0))) for d in REFS],
                            dtype=torch.float64)
    torch.testing.assert_close(view_distances(target, refs, "vector", center=center), expected)
    assert nearest_views(target, refs, 3, center=center) == [3, 4, 2]
    # Measured from the origin instead, the angles are not the ones around the circle's centre.
    assert not torch.allclose(view_distances(target, refs, "vector"), expected)


def test_excluded_views_are_never_returned_and_k_is_clipped():
    refs = circle(REFS)
    target = refs[4]
    first = nearest_views(target, refs, 3, exclude=[4])
    assert set(first[:2]) == {3, 5} and first[2] in (2, 6)  # 30 degrees away on each side, then 60
    everything = nearest_views(target, refs, 100, exclude=[4, 7, 99])
    assert sorted(everything) == [i for i in range(12) if i not in (4, 7)]
    assert nearest_views(target, refs, 0) == []
    assert nearest_views(target, refs, 5, exclude=range(12)) == []
    with pytest.raises(ValueError):
        nearest_views(target, refs, 2, method="euclid")


def test_training_draw_comes_from_the_nearest_pool_and_skips_the_target():
    refs = circle([10.0 * i for i in range(36)])
    rng = np.random.default_rng(0)
    sampling = ViewSampling(pool_factors=(2,), pool_probs=(1.0,), max_pool=20, keep_target_prob=0.0)
    pool = set(nearest_views(refs[0], refs, 8, exclude=[0]))  # 2 * 4: the 4 nearest on each side
    seen = set()
    for _ in range(50):
        views = sample_training_views(rng, 0, refs, 4, sampling=sampling)
        assert len(views) == len(set(views)) == 4
        assert set(views) <= pool and 0 not in views
        seen.update(views)
    assert seen == pool  # over many draws every pool member shows up


def test_training_draw_keeps_the_target_when_asked_and_clips_k():
    refs = circle(REFS[:4])
    rng = np.random.default_rng(1)
    always = ViewSampling(keep_target_prob=1.0)
    views = sample_training_views(rng, 2, refs, 3, sampling=always)
    assert 2 in views and len(set(views)) == 3
    assert sorted(sample_training_views(rng, 2, refs, 10, sampling=ViewSampling(keep_target_prob=0.0))) == [0, 1, 3]


def test_training_draw_is_reproducible_from_the_generator_state():
    refs = circle([10.0 * i for i in range(36)])
    a = [sample_training_views(np.random.default_rng(7), t, refs, 8) for t in range(5)]
    b = [sample_training_views(np.random.default_rng(7), t, refs, 8) for t in range(5)]
    assert a == b
