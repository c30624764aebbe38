"""Depth files without clipping: the uint16 scale is chosen per render from the path's far bound, in any scene unit;
--depth-format npy keeps float32 depths in the scene's units."""
from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
from cli_fixtures import make_scene, run

from insertnerf_cli.exporters.outputs import (depth_scale_for, depth_to_float, depth_to_uint16, frame_paths, read_depth,
                                    write_frame)

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("unit", [1e-3, 1.0, 1e4])
def test_scale_keeps_every_depth_up_to_far_within_one_step(unit):
    near, far = 0.05 * unit, 50.0 * unit  # a scene whose far bound is 50 of its units, in metres or microns
    scale = depth_scale_for(far)
    depth = np.concatenate([np.linspace(near, far, 10001), [far * (1 + 1e-6)]])[None]  # float rounding past far
    steps, clipped = depth_to_uint16(depth, np.ones_like(depth, bool), scale)
    assert clipped == 0 and steps.max() < np.iinfo(np.uint16).max
    assert np.abs(steps * scale - depth).max() <= scale / 2 * (1 + 1e-9)
    # The step is the finest 1-2-5 value that holds far: at most 2.5x the exact fit (precision ~ far / 26000).
    assert far / 65535 <= scale <= 2.5 * 1.01 * far / 65535
    mantissa = float(f"{scale:e}".split("e")[0])
    assert mantissa in (1.0, 2.0, 5.0)


def test_scale_of_a_millimetre_scene_is_millimetres():
    assert depth_scale_for(50.0) == 1e-3 and depth_scale_for(65.0) == 2e-3


def test_scale_refuses_a_bad_far_bound():
    for far in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            depth_scale_for(far)


def test_npy_depth_round_trips_with_nan_for_invalid(tmp_path):
    depth = np.array([[0.25, 1e4], [3.0, np.inf]])
    valid = np.array([[True, True], [False, True]])
    paths = frame_paths(tmp_path, 0, "npy")
    assert paths.depth.name == "00000.npy"
    write_frame(paths, np.zeros((2, 2, 3)), depth_to_float(depth, valid), np.zeros((2, 2, 3), np.uint8))
    back = np.load(paths.depth)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, np.array([[0.25, 1e4], [np.nan, np.nan]], np.float32))
    np.testing.assert_array_equal(read_depth(paths.depth, 1.0), back)
    assert paths.all_exist()
    paths.depth.write_bytes(paths.depth.read_bytes()[:-4])  # cut short: render again
    assert not paths.all_exist()


@pytest.mark.slow
@pytest.mark.parametrize("unit", [1e-3, 1e4])
def test_render_at_extreme_units_clips_nothing_and_npy_agrees_with_png(checkpoint, tmp_path, unit):
    scene = make_scene(tmp_path / "scene", {"train": 6}, scale=unit)  # bounds 0.5 to 4 times the unit
    common = ("--checkpoint", checkpoint, "--device", "cpu", "--resolution", 16, "--views", 2, "--frames", 2)
    png = run("render", scene, "--out", tmp_path / "png", *common)
    npy = run("render", scene, "--out", tmp_path / "npy", "--depth-format", "npy", *common)
    assert png.exit_code == 0 and npy.exit_code == 0, png.output + npy.output
    assert "clipped" not in png.output and f"steps of {depth_scale_for(4.0 * unit):g} units" in png.output
    cams = json.loads((tmp_path / "png" / "cameras.json").read_text())
    scale = cams["depth_unit_scale_factor"]
    assert scale == depth_scale_for(4.0 * unit)
    assert json.loads((tmp_path / "npy" / "cameras.json").read_text())["frames"][1]["depth_file_path"] == \
        "depth/00001.npy"
    for i in range(2):
        stored = iio.imread(tmp_path / "png" / "depth" / f"{i:05d}.png")
        exact = np.load(tmp_path / "npy" / "depth" / f"{i:05d}.npy")
        assert stored.max() < np.iinfo(np.uint16).max
        np.testing.assert_array_equal(stored == 0, np.isnan(exact))  # the same pixels are invalid
        ok = stored > 0
        assert ok.mean() > 0.5
        # Read back through cameras.json's scale: within one quantisation step (and float32's rounding).
        assert np.abs(stored[ok] * scale - exact[ok]).max() <= scale * 0.5 + 1e-6 * exact[ok].max()
        assert exact[ok].min() >= 0.5 * unit * (1 - 1e-5) and exact[ok].max() <= 4.0 * unit * (1 + 1e-5)
