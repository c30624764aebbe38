"""Where along the ray the generator puts a surface, signed: in front of the true depth, at it, or behind it.

For each held-out view (eval's split and reference rule, 10 views, 256 px long side) the fine pass is run on rays
through pixels whose true depth is known, and its compositing weights are split into the mass more than 5 % in
front of that depth, within 5 %, and more than 5 % behind it; the heaviest sample's depth over the true depth is
the peak ratio. It also prints the median relative error of two depths of those rays: the weights' mean
(render's depth until round 17) and the render's own (Composite.depth, their median since round 17). The truth is
- for a capture with a COLMAP model (``sparse/0``: beer; or a scene written by ``insertnerf poses``, whose model
  is ``colmap/sparse/0``): the camera-z depth of every feature COLMAP triangulated in the photo (textured points
  only; the same cameras render, so the scale is the normalisation's);
- for a synth scene: its depth files, at up to 600 surface pixels per view; with ``--versus DIR``, only pixels
  whose colour differs by over 0.1 from the same view of DIR/<scene's folder name> (its twin from
  bench/mirror_data.py: where the mirror coats show).

Round 17 (docs/model-card.md) used it to show that on the reflective 360-degree captures the weight sits behind the
surface:

    OMP_NUM_THREADS=2 python3 bench/depth_bias.py /tmp/mold_auto /tmp/beer_auto ../shared/realdata/room
    OMP_NUM_THREADS=2 python3 bench/depth_bias.py scratch/syn_obj/scene_0000? [--checkpoint W.pt]
    OMP_NUM_THREADS=2 python3 bench/depth_bias.py D/mirror/scene_0000? --versus D/plain   # and the reverse
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pycolmap
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.rays import rays_from_pixels  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.scenes.colmap_model import find_model  # noqa: E402
from insertnerf_cli.training.depth import read_scene_depth  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402
from sfm_depth import sfm_features  # noqa: E402  (bench/, the script's folder)

TOLERANCE = 0.05  # relative depth counted as "at the surface"
SYNTH_PIXELS = 600
DIFFERS = 0.1  # colour difference that marks a pixel where the twin scenes differ


def colmap_model(scene_dir: Path) -> pycolmap.Reconstruction | None:
    """The scene's COLMAP model (find_model: sparse/0 or sparse; under colmap/ in a scene `insertnerf poses`
    wrote), or None."""
    found = find_model(scene_dir) or find_model(scene_dir / "colmap")
    return pycolmap.Reconstruction(str(found)) if found is not None else None


def sfm_truth(model: pycolmap.Reconstruction, name: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions [N, 2] at ``size`` (height, width) and camera-z depths [N] (the model's units) of the
    photo's triangulated features."""
    xy, z, (width, height) = sfm_features(model, name)
    h, w = size
    return xy.reshape(-1, 2) * np.array([w / width, h / height]), z


def synth_truth(scene, index: int, size: tuple[int, int], twin=None) -> tuple[np.ndarray, np.ndarray]:
    """Up to SYNTH_PIXELS pixel centres [N, 2] with a surface (and a colour unlike ``twin``'s, a Scene) and their
    depths [N] (the scene's units)."""
    truth = read_scene_depth(scene, index, *size)
    keep = truth > 0
    if twin is not None:
        own, other = (s.load_image(index, *size).astype(np.float64) for s in (scene, twin))
        keep &= np.abs(own - other).max(axis=-1) > DIFFERS
    rows, cols = np.nonzero(keep)
    pick = np.random.default_rng(index).choice(len(rows), min(SYNTH_PIXELS, len(rows)), replace=False)
    rows, cols = rows[pick], cols[pick]
    return np.stack([cols + 0.5, rows + 0.5], axis=1), truth[rows, cols].astype(np.float64)


def weight_split(weights: np.ndarray, t: np.ndarray, truth: np.ndarray) -> tuple[float, float, float, float]:
    """(peak depth / truth median, mass in front, at, behind) of weights and depths [N, S] against truth [N]."""
    ratio = t / truth[:, None]
    peak = t[np.arange(len(t)), weights.argmax(1)] / truth
    front = (weights * (ratio < 1 - TOLERANCE)).sum(1).mean()
    behind = (weights * (ratio > 1 + TOLERANCE)).sum(1).mean()
    at = (weights * (np.abs(ratio - 1) <= TOLERANCE)).sum(1).mean()
    return float(np.median(peak)), float(front), float(at), float(behind)


def probe(scene_dir: Path, model, views: int, resolution: int, versus: Path | None = None,
          near_scale: float = 1.0) -> np.ndarray:
    scene, similarity = normalize_scene(load_scene(scene_dir))
    twin = load_scene(versus / scene_dir.name) if versus is not None else None
    reconstruction = colmap_model(scene_dir) if scene.depth_paths is None else None
    if scene.depth_paths is None and reconstruction is None:
        raise SystemExit(f"{scene_dir}: neither depth files nor a COLMAP model")
    held = held_out_views(scene)
    size = scene.size_for(resolution)
    renderer = ViewRenderer(model, scene, size, views)
    rows, errors = [], ([], [])  # relative depth errors of the weighted mean and of the render's depth
    for index in held:
        if reconstruction is not None:
            uv, truth = sfm_truth(reconstruction, Path(scene.names[index]).name, size)
            truth = truth * similarity.scale
        else:
            uv, truth = synth_truth(scene, index, size, twin)
        if len(truth) == 0:
            continue
        camera = scene.cameras.subset([index]).rescale(*size)
        rays = rays_from_pixels(camera, torch.from_numpy(uv).float()[None], scene.near[index:index + 1] * near_scale,
                                scene.far[index:index + 1])
        encoded = renderer._encoded(renderer.references(camera.c2w[0], held, views))
        with torch.inference_mode():
            out = model.render(encoded, rays)
        weights, t = out.weights.double().numpy(), out.t.double().numpy()
        rows.append(weight_split(weights, t, truth))
        mean_depth = (weights * t).sum(1) / np.maximum(weights.sum(1), 1e-12)
        errors[0].extend(np.abs(mean_depth / truth - 1))
        errors[1].extend(np.abs(out.depth.double().numpy() / truth - 1))
        print(f"  {Path(scene.names[index]).name}: {len(truth)} pixels, peak/true depth {rows[-1][0]:.3f}, weight "
              f"in front {rows[-1][1]:.2f}, at the surface {rows[-1][2]:.2f}, behind {rows[-1][3]:.2f}", flush=True)
    mean = np.concatenate([np.mean(rows, axis=0), [np.median(errors[0]), np.median(errors[1])]])
    print(f"{scene_dir} ({scene.layout}, {len(rows)} views): peak/true depth {mean[0]:.3f}, weight in front "
          f"{mean[1]:.2f}, at the surface (+-{TOLERANCE:.0%}) {mean[2]:.2f}, behind {mean[3]:.2f}; median |rel. "
          f"error| of the weighted mean depth {mean[4]:.4f}, of the render's depth {mean[5]:.4f}", flush=True)
    return mean


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", type=Path, nargs="+")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--versus", type=Path, default=None, help="folder of the synth scenes' twins")
    parser.add_argument("--near-scale", type=float, default=1.0, help="multiply every view's near bound")
    args = parser.parse_args()
    model = load_model(checkpoint_path(args.checkpoint), "cpu")
    means = [probe(scene_dir, model, args.views, args.resolution, args.versus, args.near_scale)
             for scene_dir in args.scenes]
    if len(means) > 1:
        mean = np.mean(means, axis=0)
        print(f"mean of {len(means)}: peak/true depth {mean[0]:.3f}, in front {mean[1]:.2f}, at {mean[2]:.2f}, "
              f"behind {mean[3]:.2f}; depth error: weighted mean {mean[4]:.4f}, the render's {mean[5]:.4f}")


if __name__ == "__main__":
    main()
