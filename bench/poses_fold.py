"""A walk around a symmetric object, folded by SfM as beer's was: does `insertnerf poses` keep the walk?

    python3 bench/poses_fold.py                          # auto: every pair matched, then a chain if the walk tears
    python3 bench/poses_fold.py --matcher exhaustive     # every pair only (warns about the tears it finds)

Scene (beer's, made exact): a box whose opposite sides carry the same texture stands on a floor whose texture is
the same after a half turn about the box's axis, inside a room whose walls are textured uniquely. The cameras
walk a full circle around the box, named in walk order. Views half a turn apart see the same box and floor and
different walls; matched as pairs, they pull the far half of the walk onto the near half (the scene is
tests/textured_scenes.py's fold_mesh, which tests/test_poses.py maps too). The script prints the true pose errors
next to what `poses` reported (the torn links it found, the matcher it kept).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the package, and the scenes the tests share (textured_scenes)

from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses  # noqa: E402
from textured_scenes import fold_mesh, half_turn_colouring, orbit_cameras, pose_errors, render  # noqa: E402


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
