"""How right the SfM depth prior is on synth scenes: points triangulated at the scene's poses from its reference
views, splatted into each held-out view (depth_prior.prior_depth), against synth's exact depth there.

    python3 bench/prior_accuracy.py SCENE [SCENE ...] [--near 3,10,all]

For each rule of which points a frame may use (those one of its K nearest references observes, or all that two
references observe), prints per held-out view the share of pixels the prior covers, the share of those that are
background in the exact depth, and the median relative depth error on the object. Needs scenes written by
`insertnerf synth` (depth/ beside the held-out views).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.depth_prior import prior_depth  # noqa: E402
from insertnerf_cli.outputs import read_depth  # noqa: E402
from insertnerf_cli.scenes import load_scene  # noqa: E402
from insertnerf_cli.triangulate import triangulate_points  # noqa: E402
from insertnerf_cli.views import held_out_views, nearest_views, view_rule  # noqa: E402


def view_figures(scene, points, view: int, near: list[int] | None, refs: list[int]) -> tuple[float, float, float]:
    """(covered share, background share of the covered, median relative error on the object) of one view."""
    prior = prior_depth(points.seen_from(refs, near=near), scene.cameras.subset([view])).numpy()
    true = read_depth(scene.depth_paths[view], scene.depth_scale)
    covered = np.isfinite(prior)
    depth, guess = true[covered], prior[covered]
    on_object = np.isfinite(depth) & (depth > 0)
    error = np.abs(guess[on_object] / depth[on_object] - 1)
    return float(covered.mean()), 1 - float(on_object.mean()) if covered.any() else 0.0, \
        float(np.median(error)) if len(error) else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--near", default="3,10,all", help="nearest-reference counts K, or 'all'")
    args = parser.parse_args()
    rules = [None if k == "all" else int(k) for k in args.near.split(",")]
    for root in args.scenes:
        scene = load_scene(root)
        if scene.depth_paths is None:
            raise SystemExit(f"{root}: no exact depth (make it with `insertnerf synth`)")
        held = held_out_views(scene)
        refs = [i for i in range(len(scene)) if i not in held]
        points = triangulate_points(scene, refs, quiet=True)
        print(f"{root.name}: {len(points)} points from {len(refs)} reference views")
        for k in rules:
            rows = []
            for view in held:
                near = nearest_views(scene.cameras.c2w[view], scene.cameras.c2w, k, view_rule(scene.layout),
                                     exclude=held) if k is not None else None
                rows.append(view_figures(scene, points, view, near, refs))
            cover, background, error = (np.nanmedian([r[i] for r in rows]) for i in range(3))
            print(f"  {'all points' if k is None else f'seen by one of {k} nearest':>26}: covers {cover:.2f} of "
                  f"the pixels, {background:.2f} of them background; median depth error {error:.3f} "
                  f"(per view: {', '.join(f'{r[2]:.3f}' for r in rows)})", flush=True)


if __name__ == "__main__":
    main()
