"""Rendered depth against the capture's own SfM points: how right the generator's geometry is on real photos.

For each held-out view of a capture that holds a COLMAP model (`sparse/0`: beer, room), eval's render (10
references, 256 px, the shipped fast generator or --checkpoint) is read at every 2D feature of that photo that
COLMAP triangulated, against the point's depth in the photo's camera. Scene normalisation scales depth by one
factor per capture, so each view prints the median ratio (should be that factor) and the median absolute relative
error after dividing by it, in the image's top and bottom halves, and the share of points off by > 25 %. SfM points
sit on textured features (corners, edges, the can's print); textureless floor and wall get none, so this says
nothing about them.

    OMP_NUM_THREADS=2 python3 bench/sfm_depth.py --captures beer,room
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pycolmap

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
OFF = 0.25  # relative error counted as off


def sfm_features(reconstruction: pycolmap.Reconstruction, name: str) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Pixel positions [N, 2] (COLMAP's full-size pixels) and camera-z depths [N] of a photo's triangulated
    features, and the (width, height) of its camera."""
    image = next(im for im in reconstruction.images.values() if im.name == name)
    camera = reconstruction.cameras[image.camera_id]
    pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
    xy, z = [], []
    for feature in image.points2D:
        if feature.has_point3D():
            xy.append(feature.xy)
            z.append((pose * reconstruction.points3D[feature.point3D_id].xyz)[2])
    return np.array(xy), np.array(z), (camera.width, camera.height)


def probe(capture: Path, checkpoint: Path | None, views: int) -> None:
    reconstruction = pycolmap.Reconstruction(str(capture / "sparse" / "0"))
    scene, _ = normalize_scene(load_scene(capture))
    held = held_out_views(scene)
    size = scene.size_for(256)
    renderer = ViewRenderer(load_model(checkpoint_path(checkpoint), "cpu"), scene, size, views)
    errors = []
    for index in held:
        camera = scene.cameras.subset([index]).rescale(*size)
        out, _ = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, views)
        xy, z, (width, height) = sfm_features(reconstruction, Path(scene.names[index]).name)
        h, w = size
        col = np.clip((xy[:, 0] / width * w).astype(int), 0, w - 1)
        row = np.clip((xy[:, 1] / height * h).astype(int), 0, h - 1)
        ratio = out.depth.double().cpu().numpy()[row, col] / z
        rel = np.abs(ratio / np.median(ratio) - 1.0)
        errors.append(rel)
        top, bottom = (float(np.median(part)) if len(part) else float("nan") for part in (rel[row < h / 2],
                                                                                          rel[row >= h / 2]))
        print(f"{capture.name} {Path(scene.names[index]).name}: {len(z)} SfM points, depth ratio "
              f"{np.median(ratio):.3f}, median |rel. error| {np.median(rel):.3f} (top half {top:.3f}, bottom "
              f"{bottom:.3f}), off by > {OFF:.0%}: {(rel > OFF).mean():.0%}", flush=True)
    every = np.concatenate(errors)
    print(f"{capture.name}: {len(every)} points over {len(held)} views, median |rel. error| {np.median(every):.3f}, "
          f"off by > {OFF:.0%}: {(every > OFF).mean():.0%}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer,room")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    args = parser.parse_args()
    for name in args.captures.split(","):
        probe(args.root / name, args.checkpoint, args.views)


if __name__ == "__main__":
    main()
