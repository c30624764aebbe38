"""How accurate are the poses `insertnerf poses` recovers? Render a textured scene with known cameras, run
``estimate_poses`` on the images alone, align the result to the truth with a similarity, print the errors.

    python3 bench/poses_accuracy.py                    # 30 views, 400x400, the issue's figures
    python3 bench/poses_accuracy.py --views 24 --size 320 --keep /tmp/poses_bench
    python3 bench/poses_accuracy.py --scene synth      # a 360 scene of `insertnerf synth` instead

Scene: a textured room (walls, floor, ceiling) around a box and a sphere; cameras on a horizontal circle
looking at the centre (a 360-degree capture). Colours are a solid 3-D value-noise texture of the hit point, so
no patch repeats (repeated texture is a separate trap, see docs/commands/poses.md). Rendered by ray casting
with trimesh + embree; the scene is tests/textured_scenes.py, which the pose tests render too. Targets from the
issue: >= 95 % registered, rotation error <= 1 deg, camera-centre error <= 1 % of the scene radius (the mean
distance of the cameras from their centroid). The pose check runs in warn-only mode so the errors are printed
even when it fails.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the package, and the scene the tests share (textured_scenes)

from insertnerf_cli.cameras.camera import Cameras  # noqa: E402
from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses  # noqa: E402
from textured_scenes import pose_errors, render_scene  # noqa: E402


@dataclass(frozen=True)
class Truth:
    """Images on disk and the cameras they were rendered with."""

    images_dir: Path
    names: list[str]  # file names, in camera order
    cameras: Cameras
    radius: float  # mean distance of the camera centres from their centroid


def _mean_radius(cameras: Cameras) -> float:
    centres = cameras.centers.numpy()
    return float(np.linalg.norm(centres - centres.mean(0), axis=1).mean())


def room_truth(root: Path, views: int, size: int) -> Truth:
    scene = render_scene(views, size)
    images_dir = root / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    names = [f"view_{i:03d}.png" for i in range(views)]
    for name, img in zip(names, scene.images):
        cv2.imwrite(str(images_dir / name), img[..., ::-1])
    return Truth(images_dir, names, scene.cameras, _mean_radius(scene.cameras))


def synth_truth(root: Path, views: int, size: int, seed: int) -> Truth:
    """A 360-layout scene of `insertnerf synth` (its textures tile: a repeated-texture case for SfM)."""
    from insertnerf_cli.scenes import load_scene
    from insertnerf_cli.synth import CaptureOptions, SceneSpec
    from insertnerf_cli.synth.dataset import render_into

    spec = SceneSpec(index=0, seed=seed, layout="360", views=views, test_views=0, resolution=size,
                     aspects=(1.0,), capture=CaptureOptions())
    render_into(root, spec)
    scene = load_scene(root / spec.name)
    return Truth(scene.image_paths[0].parent, [p.name for p in scene.image_paths], scene.cameras,
                 _mean_radius(scene.cameras))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="room", choices=["room", "synth"])
    parser.add_argument("--views", type=int, default=30)
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0, help="synth scene seed")
    parser.add_argument("--matcher", default="auto", choices=["auto", "exhaustive", "sequential"])
    parser.add_argument("--keep", type=Path, help="write images and the scene here instead of a temp folder")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        t0 = time.perf_counter()
        truth = (room_truth(root, args.views, args.size) if args.scene == "room"
                 else synth_truth(root, args.views, args.size, args.seed))
        print(f"rendered {args.views} views at {args.size}x{args.size} in {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        options = PosesOptions(matcher=args.matcher, overwrite=True, allow_inconsistent=True)
        result = estimate_poses(truth.images_dir, root / "scene", options)
        wall = time.perf_counter() - t0
    _print_figures(truth, result, wall)


def _print_figures(truth: Truth, result, wall: float) -> None:
    rot_err, centre_err = pose_errors(truth.cameras.subset([truth.names.index(n) for n in result.registered]),
                                      result.cameras)
    centre_pct = 100 * centre_err / truth.radius
    print(f"registered        {len(result.registered)}/{len(truth.names)} "
          f"({100 * len(result.registered) / len(truth.names):.1f} %)")
    print(f"reprojection      {result.mean_reprojection_error:.3f} px mean")
    print(f"rotation error    median {np.median(rot_err):.3f} deg, max {rot_err.max():.3f} deg")
    print(f"centre error      median {np.median(centre_pct):.3f} %, max {centre_pct.max():.3f} % "
          f"of the scene radius ({truth.radius:.2f})")
    print(f"pose check        {'passed' if result.check.passed else 'FAILED'}: {result.check.summary()}")
    print(f"wall time         {wall:.1f} s for estimate_poses "
          f"({', '.join(f'{s.name} {s.seconds:.1f} s' for s in result.stages)})")


if __name__ == "__main__":
    main()
