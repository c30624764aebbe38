"""A walk around a symmetric object, folded by SfM as beer's was: does `insertnerf poses` keep the walk?

    python3 bench/poses_fold.py                          # auto: every pair matched, then a chain if the walk tears
    python3 bench/poses_fold.py --matcher exhaustive     # every pair only (warns about the tears it finds)

Scene (beer's, made exact): a box whose opposite sides carry the same texture stands on a floor whose texture is
the same after a half turn about the box's axis, inside a room whose walls are textured uniquely. The cameras
walk a full circle around the box, named in walk order. Views half a turn apart see the same box and floor and
different walls; matched as pairs, they pull the far half of the walk onto the near half. The script prints the
true pose errors next to what `poses` reported (the torn links it found, the matcher it kept).
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from poses_accuracy import orbit_cameras, pose_errors, render, solid_texture  # noqa: E402

from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses  # noqa: E402

ROOM_HALF, ROOM_HEIGHT, BOX = 8.0, 6.0, (1.2, 0.8, 1.6)  # room half-width and height, box extents (world units)


def fold_mesh() -> trimesh.Trimesh:
    """The box on the floor (z = 0) inside the room (inward walls and ceiling, the floor its bottom face)."""
    box = trimesh.creation.box(extents=BOX)
    box.apply_translation([0.0, 0.0, BOX[2] / 2])
    room = trimesh.creation.box(extents=[2 * ROOM_HALF, 2 * ROOM_HALF, ROOM_HEIGHT])
    room.apply_translation([0.0, 0.0, ROOM_HEIGHT / 2])
    room.invert()
    return trimesh.util.concatenate([box, room])


def half_turn_colouring(hits: np.ndarray, _: np.ndarray) -> np.ndarray:
    """The box and the floor: textured at (x, y, z) as at (-x, -y, z); the walls and ceiling: uniquely."""
    on_walls = (np.abs(hits[:, :2]).max(1) > ROOM_HALF - 1e-3) | (hits[:, 2] > ROOM_HEIGHT - 1e-3)
    canonical = hits.copy()
    flip = (hits[:, 0] < 0) | ((hits[:, 0] == 0) & (hits[:, 1] < 0))
    canonical[flip, :2] *= -1.0
    rgb = solid_texture(canonical, 0)
    rgb[on_walls] = solid_texture(hits[on_walls] * 0.5 + 11.0, 5)
    return rgb


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--size", type=int, default=320, help="image width; the height is 3/4 of it")
    parser.add_argument("--matcher", default="auto", choices=["auto", "exhaustive", "sequential", "chain"])
    parser.add_argument("--chain-overlap", type=int, default=PosesOptions.chain_overlap)
    args = parser.parse_args()
    cameras = orbit_cameras(args.views, (args.size * 3 // 4, args.size), 3.5, fov_deg=60.0, height=lambda a: 1.6)
    images = render(fold_mesh(), cameras, half_turn_colouring)
    lines: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        names = [f"walk_{i:03d}.png" for i in range(args.views)]
        (Path(tmp) / "images").mkdir()
        for name, img in zip(names, images):
            cv2.imwrite(str(Path(tmp) / "images" / name), img[..., ::-1])
        options = PosesOptions(matcher=args.matcher, allow_inconsistent=True, chain_overlap=args.chain_overlap)
        result = estimate_poses(Path(tmp) / "images", Path(tmp) / "scene", options, report=lines.append)
    truth = cameras.subset([names.index(n) for n in result.registered])
    rot_err, centre_err = pose_errors(truth, result.cameras)
    print("\n".join(line for line in lines if "torn" in line or "jump" in line or "chain" in line or "map" in line))
    print(f"matcher kept      {result.matcher}, {len(result.registered)}/{args.views} registered, reprojection "
          f"{result.mean_reprojection_error:.2f} px")
    print(f"true errors       rotation median {np.median(rot_err):.2f} deg (max {rot_err.max():.2f}), centre "
          f"median {100 * np.median(centre_err) / 3.5:.1f} % of the walk's radius (max "
          f"{100 * centre_err.max() / 3.5:.1f} %)")
    print(f"pose check        {'passed' if result.check.passed else 'FAILED'}: {result.check.summary()}")


if __name__ == "__main__":
    main()
