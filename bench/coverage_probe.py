"""Where on a held-out view the error lives, against how many reference views see each pixel's surface.

Issue 27 (round 13): for each held-out view, eval's render from its N nearest references; each pixel's rendered
depth is lifted to a world point and projected into those references. A reference "sees" the pixel when the point
lands inside its image in front of it (occlusion is not checked, so this is an upper bound). Prints, per capture
and count, the share of pixels and the PSNR of the pixels seen by 0-1, 2-3, 4-6 and 7+ references, and the PSNR of
the top, middle and bottom thirds of the image.

    OMP_NUM_THREADS=1 python3 bench/coverage_probe.py --captures beer,mold_gold_cape --views 3,10 [--checkpoint W]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
BUCKETS = ((0, 1), (2, 3), (4, 6), (7, 99))  # references that see a pixel, inclusive ranges


def seen_by(out_depth: torch.Tensor, camera, refs_cameras) -> np.ndarray:
    """[H, W] how many of ``refs_cameras`` have the pixel's rendered surface point inside their image."""
    h, w = out_depth.shape
    uv = camera.pixel_grid().reshape(1, -1, 2).to(out_depth)
    points = camera.to(dtype=out_depth.dtype).unproject(uv, out_depth.reshape(1, -1))[0]  # [H*W, 3]
    inside = refs_cameras.to(dtype=out_depth.dtype).sees(points)  # [R, H*W]
    return inside.sum(0).reshape(h, w).cpu().numpy()


def psnr_of(se: np.ndarray) -> float:
    return float("nan") if se.size == 0 else float(-10 * np.log10(max(se.mean(), 1e-12)))


def probe(capture: Path, counts: list[int], checkpoint: Path | None, max_views: int | None) -> None:
    scene, _ = normalize_scene(load_scene(capture))
    held = held_out_views(scene, max_views)
    size = scene.size_for(256)
    renderer = ViewRenderer(load_model(checkpoint_path(checkpoint), "cpu"), scene, size, max(counts))
    for n in counts:
        coverage, errors, rows = [], [], []
        for index in held:
            camera = scene.cameras.subset([index]).rescale(*size)
            truth = scene.load_image(index, *size).astype(np.float64)
            out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, n)
            refs_cameras = scene.cameras.subset(refs).rescale(*size)
            coverage.append(seen_by(out.depth.double(), camera.to(dtype=torch.float64), refs_cameras))
            errors.append(((out.rgb.double().cpu().numpy() - truth) ** 2).mean(-1))
            rows.append(np.broadcast_to(np.arange(size[0])[:, None] * 3 // size[0], size))
        cov, se, third = (np.concatenate([a.ravel() for a in x]) for x in (coverage, errors, rows))
        parts = [f"{lo}-{hi if hi < 99 else '+'}: {100 * np.mean((cov >= lo) & (cov <= hi)):.0f}% "
                 f"{psnr_of(se[(cov >= lo) & (cov <= hi)]):.2f} dB" for lo, hi in BUCKETS]
        region = " / ".join(f"{psnr_of(se[third == t]):.2f}" for t in range(3))
        print(f"{capture.name} | {n} views | seen by {' | '.join(parts)} | top / middle / bottom {region} dB "
              f"| all {psnr_of(se):.2f} dB", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer,mold_gold_cape,room,flower")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", default="3,10")
    parser.add_argument("--max-views", type=int, default=None)
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    args = parser.parse_args()
    for name in args.captures.split(","):
        probe(args.root / name, [int(v) for v in args.views.split(",")], args.checkpoint, args.max_views)


if __name__ == "__main__":
    main()
