"""Contact sheet of `insertnerf synth` scenes: the first training view of a few scenes per layout, each with
its depth map underneath (inverse depth, near = bright; black = no surface: the sky at infinity or a plain
background). Renders through the library call behind the command, into a temporary folder.

    python3 bench/synth_sheet.py docs/images/synth5.jpg --scenes 6 --resolution 128 --seed 2024 --photo
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from insertnerf_cli.synth import LAYOUTS, CaptureOptions, SceneSpec, render_scene


def tile(scene_dir: Path, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The first training view [size, size, 3] (BGR) and its depth map drawn as an image of the same size."""
    image = cv2.imread(str(scene_dir / "train" / "r_000.png"))
    depth = cv2.imread(str(scene_dir / "depth" / "train" / "r_000.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    inverse = np.where(depth > 0, 1.0 / np.maximum(depth, 1.0), 0.0)
    scale = np.percentile(inverse[depth > 0], 99) if (depth > 0).any() else 1.0
    shade = np.clip(inverse / scale, 0, 1)
    colored = cv2.applyColorMap((shade * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    colored[depth == 0] = 0
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA), \
        cv2.resize(colored, (size, size), interpolation=cv2.INTER_NEAREST)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="image file to write (.jpg or .png)")
    parser.add_argument("--scenes", type=int, default=6, help="scenes per layout")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--photo", action="store_true", help="with the --photo capture effects")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for layout in LAYOUTS:
            images, depths = [], []
            for index in range(args.scenes):
                spec = SceneSpec(index=index, seed=args.seed, layout=layout, views=2, test_views=0,
                                 resolution=args.resolution, aspects=(1.0,), capture=CaptureOptions(photo=args.photo))
                folder = Path(tmp) / f"{layout}-{index}"
                render_scene(spec, folder)
                image, depth = tile(folder, args.resolution)
                images.append(image)
                depths.append(depth)
            rows += [np.concatenate(images, axis=1), np.concatenate(depths, axis=1)]
    if not cv2.imwrite(str(args.out), np.concatenate(rows, axis=0), [cv2.IMWRITE_JPEG_QUALITY, 85]):
        raise SystemExit(f"could not write {args.out}")
    print(f"wrote {args.out}: {len(LAYOUTS)} layouts ({', '.join(LAYOUTS)}) x {args.scenes} scenes")


if __name__ == "__main__":
    main()
