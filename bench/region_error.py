"""Where a capture's error lives: the subject's pixels (picked by colour in the photo) against the rest.

Issue 27 (round 18): mold_gold_cape is the capture furthest from its target, and earlier rounds read its loss as
the specular gold. This splits every held-out view's pixels by an HSV range of the *photo* (OpenCV's hue 0-180;
the default is the cape's gold, closed by a 5 px disc so the punched texture's dark dots stay in), then prints,
per reference-view count, the mask's share of the pixels, the PSNR inside and outside it, the share of the
squared error outside it, and the PSNR of the rest in the image's upper and lower half. The renders are eval's
(ViewRenderer, render's shortcuts, 256 px).

    OMP_NUM_THREADS=2 python3 bench/region_error.py --captures mold_gold_cape --views 3,10 [--checkpoint W]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from coverage_probe import REALDATA, psnr_of  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402

CLOSE_PX = 5


def colour_mask(photo: np.ndarray, hue: tuple[int, int], min_sat: int, min_val: int) -> np.ndarray:
    """[H, W] bool: the photo's pixels (float RGB [H, W, 3] in [0, 1]) inside the HSV range, closed."""
    hsv = cv2.cvtColor((photo * 255).round().astype(np.uint8), cv2.COLOR_RGB2HSV)
    inside = (hsv[..., 0] >= hue[0]) & (hsv[..., 0] <= hue[1]) & (hsv[..., 1] >= min_sat) & (hsv[..., 2] >= min_val)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLOSE_PX, CLOSE_PX))
    return cv2.morphologyEx(inside.astype(np.uint8), cv2.MORPH_CLOSE, disc).astype(bool)


def probe(capture: Path, counts: list[int], checkpoint: Path | None, args: argparse.Namespace) -> None:
    scene, _ = normalize_scene(load_scene(capture))
    held = held_out_views(scene, args.max_views)
    size = scene.size_for(256)
    renderer = ViewRenderer(load_model(checkpoint_path(checkpoint), "cpu"), scene, size, max(counts))
    truths = {i: scene.load_image(i, *size).astype(np.float64) for i in held}
    masks = {i: colour_mask(truths[i], args.hue, args.min_sat, args.min_val) for i in held}
    for n in counts:
        errors = []
        for index in held:
            camera = scene.cameras.subset([index]).rescale(*size)
            out, _ = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, n)
            errors.append(((out.rgb.double().cpu().numpy() - truths[index]) ** 2).mean(-1))
        se = np.concatenate([e.ravel() for e in errors])
        mask = np.concatenate([masks[i].ravel() for i in held])
        upper = np.concatenate([np.broadcast_to(np.arange(size[0])[:, None] < size[0] // 2, size).ravel()
                                for _ in held])
        views = np.mean([psnr_of(e) for e in errors])
        print(f"{capture.name} | {n} views | subject {100 * mask.mean():.0f}% of pixels, {psnr_of(se[mask]):.2f} dB "
              f"| rest {psnr_of(se[~mask]):.2f} dB, {100 * se[~mask].sum() / se.sum():.0f}% of the squared error "
              f"(upper half {psnr_of(se[~mask & upper]):.2f}, lower {psnr_of(se[~mask & ~upper]):.2f} dB) "
              f"| eval's mean over views {views:.2f} dB", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="mold_gold_cape")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", default="3,10")
    parser.add_argument("--max-views", type=int, default=None)
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--hue", type=lambda s: tuple(int(v) for v in s.split(",")), default=(12, 35),
                        help="OpenCV hue range LO,HI (0-180); default: gold")
    parser.add_argument("--min-sat", type=int, default=90)
    parser.add_argument("--min-val", type=int, default=60)
    args = parser.parse_args()
    for name in args.captures.split(","):
        probe(args.root / name, [int(v) for v in args.views.split(",")], args.checkpoint, args)


if __name__ == "__main__":
    main()
