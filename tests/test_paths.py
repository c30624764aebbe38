"""Camera paths: frame counts, cameras looking at the focus point, closed loops, sizes and the layout default."""
import math

import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.errors import UserError
from insertnerf_cli.rendering.camera_paths import (default_path_kind, focus_point, input_path, look_at, make_path, mean_up,
                                  orbit_path, spiral_path, with_reference_bounds)

UP = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)


def _ring(n: int = 12, radius: float = 4.0, height: float = 1.5, focus=(0.3, -0.2, 0.1)) -> Cameras:
    """n cameras on a ring around ``focus`` (world z up), all looking at it: an object-centric capture."""
    focus_t = torch.tensor(focus, dtype=torch.float64)
    angles = torch.arange(n, dtype=torch.float64) * 2 * math.pi / n + 0.4
    eyes = focus_t + torch.stack([radius * torch.cos(angles), radius * torch.sin(angles),
                                  torch.full_like(angles, height)], dim=-1)
    K = intrinsics(50.0, 50.0, 40.0, 30.0).expand(n, 3, 3)
    return Cameras(K, look_at(eyes, focus_t, UP), 60, 80)


def _forward_rig(n: int = 9) -> Cameras:
    """n cameras on a small 3x3 grid in the plane z = 0, all facing +z (OpenCV identity rotation)."""
    c2w = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c2w[:, 0, 3] = torch.linspace(-0.3, 0.3, 3, dtype=torch.float64).repeat_interleave(3)[:n]
    c2w[:, 1, 3] = torch.linspace(-0.2, 0.2, 3, dtype=torch.float64).repeat(3)[:n]
    return Cameras(intrinsics(60.0, 60.0, 40.0, 30.0).expand(n, 3, 3), c2w, 60, 80)


def _bounds(n: int, near: float = 1.0, far: float = 8.0):
    return torch.full((n,), near, dtype=torch.float64), torch.full((n,), far, dtype=torch.float64)


def _assert_looks_at(cameras: Cameras, point: torch.Tensor):
    to_point = torch.nn.functional.normalize(point - cameras.centers, dim=-1)
    torch.testing.assert_close(cameras.forward, to_point)
    # Rotations stay orthonormal and right-handed.
    rot = cameras.c2w[:, :3, :3]
    torch.testing.assert_close(rot @ rot.transpose(1, 2), torch.eye(3, dtype=rot.dtype).expand_as(rot))
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(len(cameras), dtype=rot.dtype))


def test_focus_point_of_a_ring_is_its_centre():
    torch.testing.assert_close(focus_point(_ring()), torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64))


def test_mean_up_of_a_ring_is_world_up():
    up = mean_up(_ring())
    assert float(up @ UP) > 0.9  # cameras tilt down towards the focus, so up is close to (not equal to) +z


def test_orbit_has_n_frames_around_the_focus_and_closes():
    cams = _ring()
    near, far = _bounds(len(cams))
    path = orbit_path(cams, near, far, frames=20, size=(30, 40))
    focus = torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    assert len(path) == 20 and path.kind == "orbit"
    assert (path.cameras.height, path.cameras.width) == (30, 40)
    _assert_looks_at(path.cameras, focus)
    torch.testing.assert_close(path.focus, focus)
    # A circle: every frame at the same distance from the focus as the inputs, evenly stepped, the loop closed.
    dist = (path.cameras.centers - focus).norm(dim=-1)
    torch.testing.assert_close(dist, (cams.centers - focus).norm(dim=-1).mean().expand(20), rtol=1e-3, atol=1e-3)
    steps = (path.cameras.centers.roll(-1, dims=0) - path.cameras.centers).norm(dim=-1)
    torch.testing.assert_close(steps, steps[0].expand(20))
    # Intrinsics: the inputs' focal length rescaled by 0.5 and the principal point at the centre.
    torch.testing.assert_close(path.cameras.K[0], intrinsics(25.0, 25.0, 20.0, 15.0))
    assert float(path.near.min()) == 1.0 and float(path.far.max()) == 8.0


def test_orbit_of_a_capture_from_above_and_below_keeps_the_distance():
    # Two rings at +-45 degrees elevation: the orbit runs at the mean elevation (0) but as far out as the inputs.
    above, below = _ring(8, radius=3.0, height=3.0, focus=(0, 0, 0)), _ring(8, radius=3.0, height=-3.0, focus=(0, 0, 0))
    cams = Cameras.cat([above, below])
    path = orbit_path(cams, *_bounds(16), frames=6, size=(60, 80))
    dist = path.cameras.centers.norm(dim=-1)
    torch.testing.assert_close(dist, torch.full((6,), math.sqrt(18.0), dtype=torch.float64))
    torch.testing.assert_close(path.cameras.centers[:, 2], torch.zeros(6, dtype=torch.float64), atol=1e-9, rtol=0)


def test_orbit_starts_at_the_first_camera_azimuth():
    cams = _ring()
    path = orbit_path(cams, *_bounds(len(cams)), frames=8, size=(60, 80))
    torch.testing.assert_close(path.cameras.centers[0], cams.centers[0], rtol=1e-6, atol=1e-6)


def test_spiral_looks_at_one_focus_in_front_and_closes():
    cams = _forward_rig()
    near, far = _bounds(len(cams), 2.0, 10.0)
    path = spiral_path(cams, near, far, frames=40, size=(60, 80))
    assert len(path) == 40 and path.kind == "spiral"
    _assert_looks_at(path.cameras, path.focus)
    # Parallel axes meet nowhere: the focus sits on the mean optical axis (+z) at 5 x far, so the frames keep
    # (nearly) the inputs' own direction.
    torch.testing.assert_close(path.focus, torch.tensor([0.0, 0.0, 5 * 10.0], dtype=torch.float64))
    assert float(path.cameras.forward[:, 2].min()) > math.cos(math.radians(0.5))
    # Frames stay within the rig's radii (90th percentile of offsets) and the spiral returns to its start.
    offsets = path.cameras.centers - cams.centers.mean(0)
    assert float(offsets[:, 0].abs().max()) <= 0.3 + 1e-9 and float(offsets[:, 1].abs().max()) <= 0.2 + 1e-9
    step = (path.cameras.centers[1] - path.cameras.centers[0]).norm()
    closing = (path.cameras.centers[0] - path.cameras.centers[-1]).norm()
    torch.testing.assert_close(closing, step, rtol=0.1, atol=0.0)


def test_spiral_turns_as_the_inputs_turn():
    # A forward rig whose cameras all look at a point 3 units ahead: the spiral looks at it too (not at LLFF's
    # nearer focus), so its frames turn no further than the inputs do.
    xs, ys = torch.meshgrid(torch.linspace(-0.3, 0.3, 9, dtype=torch.float64),
                            torch.linspace(-0.2, 0.2, 9, dtype=torch.float64), indexing="ij")
    centres = torch.stack([xs.flatten(), ys.flatten(), torch.zeros(81, dtype=torch.float64)], dim=-1)  # a 9 x 9 grid
    K, down = intrinsics(60.0, 60.0, 40.0, 30.0).expand(81, 3, 3), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    target = torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64)
    cams = Cameras(K, look_at(centres, target, down), 60, 80)
    path = spiral_path(cams, *_bounds(len(cams), 2.0, 10.0), frames=12, size=(60, 80))
    # A frame between two cameras is matched with the nearer one, which looks from a little aside: within 3 %.
    torch.testing.assert_close(path.focus, target, atol=0.09, rtol=0)
    # Axes that spread apart (a fan, meeting behind the cameras) give the far focus, like parallel ones.
    fan = Cameras(K, look_at(centres, 2 * centres + target, down), 60, 80)
    torch.testing.assert_close(spiral_path(fan, *_bounds(len(fan), 2.0, 10.0), 12, (60, 80)).focus[2],
                               torch.tensor(50.0, dtype=torch.float64))
    # A focus nearer than 0.9 x near is held there.
    close = spiral_path(cams, *_bounds(len(cams), 5.0, 10.0), frames=12, size=(60, 80))
    torch.testing.assert_close(close.focus[2], torch.tensor(4.5, dtype=torch.float64))


def test_input_path_rescales_and_subsamples_the_inputs():
    cams = _ring(10)
    near, far = _bounds(10)
    path = input_path(cams, near, far, size=(30, 40))
    assert path.source_index == list(range(10))
    torch.testing.assert_close(path.cameras.c2w, cams.c2w)
    assert (path.cameras.height, path.cameras.width) == (30, 40)
    few = input_path(cams, near, far, size=(30, 40), frames=4)
    assert few.source_index == [0, 3, 6, 9]


def test_make_path_dispatch_and_errors():
    cams = _ring()
    near, far = _bounds(len(cams))
    assert make_path("orbit", cams, near, far, 5, (60, 80)).kind == "orbit"
    assert default_path_kind("object") == "orbit" and default_path_kind("forward") == "spiral"
    with pytest.raises(UserError):
        make_path("zigzag", cams, near, far, 5, (60, 80))
    with pytest.raises(UserError):
        make_path("orbit", cams, near, far, 0, (60, 80))
    with pytest.raises(UserError, match="--path orbit"):  # cameras all around the scene: no spiral
        make_path("spiral", cams, near, far, 5, (60, 80))


def test_look_at_axes_are_opencv():
    # A camera at the origin looking along +x with +z up: OpenCV y (down) is -z, x (right) is -y.
    c2w = look_at(torch.zeros(1, 3, dtype=torch.float64), torch.tensor([1.0, 0, 0], dtype=torch.float64), UP)
    torch.testing.assert_close(c2w[0, :3, 2], torch.tensor([1.0, 0, 0], dtype=torch.float64))
    torch.testing.assert_close(c2w[0, :3, 1], torch.tensor([0, 0, -1.0], dtype=torch.float64))
    torch.testing.assert_close(c2w[0, :3, 0], torch.tensor([0, -1.0, 0], dtype=torch.float64))


def test_reference_bounds_give_each_orbit_frame_the_bounds_of_the_views_it_renders_from():
    # Half the ring sees a near wall (bounds 1-5), the other half a far one (2-20): an orbit frame next to a
    # camera of either half takes that half's bounds, not one pair (1-20) for all frames.
    cams = _ring(12, focus=(0.0, 0.0, 0.0))
    half = torch.arange(12) < 6
    near = torch.where(half, 1.0, 2.0).double()
    far = torch.where(half, 5.0, 20.0).double()
    path = orbit_path(cams, near, far, frames=12, size=(60, 80))  # frame i sits at camera i's azimuth
    assert float(path.near.min()) == 1.0 and float(path.far.max()) == 20.0 and path.far.unique().numel() == 1
    bounded = with_reference_bounds(path, cams, near, far, views=3, method="vector")
    torch.testing.assert_close(bounded.near[[2, 3]], torch.ones(2, dtype=torch.float64))
    torch.testing.assert_close(bounded.far[[2, 3]], torch.full((2,), 5.0, dtype=torch.float64))
    torch.testing.assert_close(bounded.near[[8, 9]], torch.full((2,), 2.0, dtype=torch.float64))
    torch.testing.assert_close(bounded.far[[8, 9]], torch.full((2,), 20.0, dtype=torch.float64))
    assert bounded.cameras is path.cameras


def test_reference_bounds_leave_input_frames_their_own():
    cams = _ring(6)
    near, far = torch.arange(1.0, 7.0).double(), torch.arange(10.0, 16.0).double()
    path = input_path(cams, near, far, size=(30, 40))
    assert with_reference_bounds(path, cams, near, far, views=2, method="vector") is path
