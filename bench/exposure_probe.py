"""How far a held-out photo's exposure lies from its references', and what a global gain would buy (round 33).

    OMP_NUM_THREADS=2 python3 bench/exposure_probe.py /work/shared/realdata/mold_gold_cape --eval-json E.json \
        --side-by-sides D

E.json and D come from `insertnerf eval SCENE --views 10 --json E.json --out D` (one count). The probe
triangulates every view of SCENE at its poses (the library's triangulate_points), reads each point's colour
(a 3x3 mean) where each observing photo sees it, and fits one log-gain per photo and channel: a point's colour in
a photo is its own colour times the photo's gain (alternating point means and per-photo medians, the mean gain
fixed at 1). It does this twice: over every point, and over the grey ones only (saturation under 0.25), since a
shiny surface's colour changes with the view as a gain does. It prints, per held-out view, its gain and its
references' mean gain (stops, mean over channels); with --side-by-sides, also the PSNR each frame would have with
the one per-channel gain (and the affine map) that brings the render nearest the photo: what exposure costs, an
upper bound no renderer that reads only the references can reach.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from insertnerf_cli.scenes import load_scene, normalize_scene
from insertnerf_cli.triangulate import triangulate_points

GREY_SATURATION = 0.25
FIT_ROUNDS = 20


def observed_colours(scene, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(view [O], point [O], colour [O, 3]) of every observation whose colour is neither clipped nor black."""
    views, ids, colours = [], [], []
    for view, observed in enumerate(points.observed):
        if len(observed) == 0:
            continue
        image = scene.load_image(view).astype(np.float64)
        height, width = image.shape[:2]
        uv, _ = scene.cameras.subset([view]).rescale(height, width).project(points.xyz[observed])
        x = np.clip(uv[0, :, 0].numpy().astype(int), 1, width - 2)
        y = np.clip(uv[0, :, 1].numpy().astype(int), 1, height - 2)
        colours.append(sum(image[y + dy, x + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9)
        views.append(np.full(len(observed), view))
        ids.append(observed.numpy())
    view, point, colour = np.concatenate(views), np.concatenate(ids), np.concatenate(colours)
    usable = (colour.max(1) < 0.95) & (colour.min(1) > 0.03)
    return view[usable], point[usable], colour[usable]


def photo_gains(view: np.ndarray, point: np.ndarray, colour: np.ndarray, views: int, points: int) -> np.ndarray:
    """[views, 3] log2 gain of each photo (0 where it observes too few points), mean 0 over the photos."""
    log = np.log(colour)
    gain = np.zeros((views, 3))
    counts = np.maximum(np.bincount(point, minlength=points), 1)[:, None]
    for _ in range(FIT_ROUNDS):
        mean = np.zeros((points, 3))
        np.add.at(mean, point, log - gain[view])
        residual = log - (mean / counts)[point]
        for v in range(views):
            here = view == v
            if here.sum() > 20:
                gain[v] = np.median(residual[here], axis=0)
        gain -= gain.mean(axis=0)
    return gain / np.log(2.0)


def corrected_psnr(side_by_side: Path) -> tuple[float, float, float]:
    """(PSNR, with the best per-channel gain, with the best per-channel affine map) of a render | truth | error
    side-by-side."""
    image = iio.imread(side_by_side).astype(np.float64) / 255.0
    width = image.shape[1] // 3
    render, truth = image[:, :width, :3].reshape(-1, 3), image[:, width:2 * width, :3].reshape(-1, 3)
    gain = (render * truth).sum(0) / np.maximum((render * render).sum(0), 1e-12)
    affine = np.stack([np.polyval(np.polyfit(render[:, c], truth[:, c], 1), render[:, c]) for c in range(3)], 1)

    def psnr(x: np.ndarray) -> float:
        return float(-10.0 * np.log10(np.mean((x - truth) ** 2)))
    return psnr(render), psnr(render * gain), psnr(affine)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene")
    parser.add_argument("--eval-json", required=True, help="`insertnerf eval --json` of one count")
    parser.add_argument("--side-by-sides", default=None, help="its `--out` folder")
    args = parser.parse_args()
    scene, _ = normalize_scene(load_scene(Path(args.scene)))
    points = triangulate_points(scene)
    view, point, colour = observed_colours(scene, points)
    grey = (colour.max(1) - colour.min(1)) / colour.max(1) < GREY_SATURATION
    fits = {"all": photo_gains(view, point, colour, len(scene), len(points)).mean(1),
            "grey": photo_gains(view[grey], point[grey], colour[grey], len(scene), len(points)).mean(1)}
    for name, stops in fits.items():
        print(f"{name} points: photo gain spread {stops.std():.3f} stops (sd), {stops.min():+.3f}..{stops.max():+.3f}, "
              f"median step between photos next in name order {np.median(np.abs(np.diff(stops))):.3f}")
    rows = []
    for entry in json.loads(Path(args.eval_json).read_text())["views"]:
        index, refs = entry["index"], entry["references"]
        line = f"{entry['name']}: PSNR {entry['psnr']:.2f}"
        for name, stops in fits.items():
            line += f" | {name}: photo {stops[index]:+.3f}, references {stops[refs].mean():+.3f} stops"
        if args.side_by_sides is not None:
            scores = corrected_psnr(Path(args.side_by_sides) / f"{index:05d}.png")
            rows.append(scores)
            line += " | with gain %.2f, affine %.2f" % scores[1:]
        print(line)
    if rows:
        print("mean PSNR %.2f, with the best gain %.2f, with the best affine map %.2f" % tuple(np.mean(rows, 0)))


if __name__ == "__main__":
    main()
