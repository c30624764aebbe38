"""Rendered depth against synth's exact depth on held-out views (issue 27): median absolute relative error.

Each held-out view of each scene (eval's split, its --views nearest other views, render's shortcuts) is rendered;
its depth, where the render is at least half opaque and the truth has a surface, is compared with the depth file
synth wrote. Also the PSNR of the same renders, and the share of true-surface pixels the render covers.

    OMP_NUM_THREADS=1 python3 bench/depth_error.py scratch/syn_fwd/scene_0000* [--checkpoint W.pt] [--views 10] [--sfm-depth]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.checkpoint import bundled_checkpoint, load_model  # noqa: E402
from insertnerf_cli.metrics import psnr  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.training.depth import read_scene_depth  # noqa: E402
from insertnerf_cli.sfm.triangulate import with_points  # noqa: E402
from insertnerf_cli.rendering.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.scenes.views import held_out_views  # noqa: E402

MIN_OPACITY = 0.5  # as render's depth maps


def score(scene_dir: Path, model, views: int, resolution: int,
          sfm_depth: bool) -> tuple[list[float], list[float], list[float]]:
    """(per-pixel relative errors, per-view PSNRs, per-view coverage) of one scene's held-out views."""
    scene, _ = normalize_scene(load_scene(scene_dir))
    if scene.depth_paths is None:
        raise SystemExit(f"{scene_dir}: no depth files (make the scene with `insertnerf synth`)")
    held = held_out_views(scene)
    if sfm_depth:  # as eval: points triangulated from the references at the scene's poses
        scene = with_points(scene, [i for i in range(len(scene)) if i not in held])
    size = scene.size_for(resolution)
    renderer = ViewRenderer(model, scene, size, views, sfm_depth=sfm_depth)
    errors, psnrs, coverage = [], [], []
    for index in held:
        camera = scene.cameras.subset([index]).rescale(*size)
        out, _ = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), exclude=held)
        truth = read_scene_depth(scene, index, *size).astype(np.float64)
        depth, opacity = out.depth.double().numpy(), out.opacity.double().numpy()
        both = (truth > 0) & (opacity >= MIN_OPACITY)
        errors.extend((np.abs(depth[both] - truth[both]) / truth[both]).tolist())
        coverage.append(float(both.sum() / max((truth > 0).sum(), 1)))
        psnrs.append(psnr(out.rgb.double().numpy(), scene.load_image(index, *size).astype(np.float64)))
    return errors, psnrs, coverage


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", type=Path, nargs="+")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--sfm-depth", action="store_true", help="guide by points triangulated at the scene's poses "
                        "from its references (eval's default since round 19; without it: the matching alone)")
    args = parser.parse_args()
    checkpoint = args.checkpoint or bundled_checkpoint()
    model = load_model(checkpoint, torch.device("cpu"))[0]
    every, all_psnr = [], []
    for scene_dir in args.scenes:
        errors, psnrs, coverage = score(scene_dir, model, args.views, args.resolution, args.sfm_depth)
        every.extend(errors)
        all_psnr.extend(psnrs)
        print(f"{scene_dir}: depth median abs. rel. error {np.median(errors):.4f} on {np.mean(coverage):.0%} of "
              f"the surface pixels; PSNR {np.mean(psnrs):.2f} dB", flush=True)
    print(f"{checkpoint}: {len(args.scenes)} scenes, depth median abs. rel. error {np.median(every):.4f}, "
          f"PSNR {np.mean(all_psnr):.2f} dB ({args.views} views, {args.resolution} px)")


if __name__ == "__main__":
    main()
