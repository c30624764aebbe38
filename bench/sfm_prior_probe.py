"""Probe: fine samples placed by the capture's own SfM points instead of the coarse pass alone.

Issue 27 (round 18): on mold_gold_cape the rendered depth is off by a median 13 % at its SfM features (round 17),
which at references 10-30 degrees apart fetches their colours from 10-25 px away: the cape comes out shifted,
doubled and blurred. A scene posed by `insertnerf poses` (or any COLMAP model) holds 3D points that say where the
surfaces are. For each held-out view this projects the points that at least two *other* photos observe (the
held-out photos are never references) into the view, splats them with a z-buffer (discs of --splat px, nearest
wins), fills each pixel from its nearest splat within --reach px, and converts COLMAP's units to the scene's (the
ratio of camera-centre spreads). The inference coarse pass is patched, in this process only, so that the fine
samples follow the mixture (1 - alpha) x coarse weights + alpha x a Gaussian of relative width --sigma at the
prior's depth (same total weight, so render's background test is unchanged); pixels without a prior keep the
coarse weights. alpha 0 is eval as shipped.

    OMP_NUM_THREADS=2 python3 bench/sfm_prior_probe.py /tmp/mold_auto --views 10 --alphas 0,0.5,0.9
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.compositing import composite  # noqa: E402
from insertnerf_cli.evaluate import EvalConfig, run_eval  # noqa: E402
from insertnerf_cli.model.insertnerf import InsertNeRF  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.scenes.colmap_model import find_model  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402

STATE: dict = {"alpha": 0.0, "sigma": 0.05, "surface": 0.0, "camera": None, "prior": None, "priors": {}}
_coarse_weights = InsertNeRF.coarse_weights
_render = ViewRenderer.render
_shade = InsertNeRF.shade


def centres(reconstruction: pycolmap.Reconstruction) -> dict[str, np.ndarray]:
    out = {}
    for image in reconstruction.images.values():
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        rotation = pose.rotation.matrix()
        out[Path(image.name).name] = -rotation.T @ pose.translation
    return out


def unit_scale(scene, reconstruction: pycolmap.Reconstruction) -> float:
    """Scene units per COLMAP unit: the spread of the camera centres about their mean, in both."""
    theirs = centres(reconstruction)
    names = [Path(n).name for n in scene.names]
    ours = scene.cameras.centers.double().numpy()
    pairs = [(ours[i], theirs[n]) for i, n in enumerate(names) if n in theirs]
    a, b = (np.array(x) for x in zip(*pairs))
    return float(np.linalg.norm(a - a.mean(0), axis=1).sum() / np.linalg.norm(b - b.mean(0), axis=1).sum())


def prior_map(reconstruction, name: str, excluded: set[int], size: tuple[int, int], splat: int,
              reach: int) -> np.ndarray:
    """[H, W] depth (COLMAP units, camera z) of the held-out photo ``name`` from the points that at least two
    photos outside ``excluded`` (image ids) observe; NaN where no splat lies within ``reach`` px."""
    h, w = size
    image = next(im for im in reconstruction.images.values() if Path(im.name).name == name)
    camera = reconstruction.cameras[image.camera_id]
    pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()
                    if sum(e.image_id not in excluded for e in p.track.elements) >= 2])
    cam = xyz @ pose.rotation.matrix().T + pose.translation
    cam = cam[cam[:, 2] > 1e-6]
    uv = np.array(camera.img_from_cam(np.ascontiguousarray(cam)))  # full-size pixels, distortion included
    uv = uv * np.array([w / camera.width, h / camera.height])
    depth = np.full((h, w), np.inf, dtype=np.float32)
    for (u, v), z in sorted(zip(uv, cam[:, 2]), key=lambda p: -p[1]):  # far first: nearer splats overwrite
        if 0 <= u < w and 0 <= v < h:
            cv2.circle(depth, (int(u), int(v)), splat, float(z), thickness=-1)
    empty = ~np.isfinite(depth)
    if empty.all():
        return np.full((h, w), np.nan, dtype=np.float32)
    distance, labels = cv2.distanceTransformWithLabels(empty.astype(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
    values = np.zeros(labels.max() + 1, dtype=np.float32)
    values[labels[~empty]] = depth[~empty]
    filled = values[labels]
    filled[distance > reach] = np.nan
    return filled


def render(self, camera, near, far, exclude, views=None):
    STATE["camera"], STATE["prior"] = camera, STATE["priors"].get(round(float(camera.centers[0, 0]), 6))
    return _render(self, camera, near, far, exclude, views)


def ray_prior(rays) -> torch.Tensor:
    """[R, 1] the prior depth at each ray's pixel of the current target (NaN where none)."""
    prior, camera = STATE["prior"], STATE["camera"]
    c2w = camera.c2w[0].to(rays.directions)
    local = rays.directions @ c2w[:3, :3]  # [R, 3] camera frame, z = 1
    k = camera.K[0].to(rays.directions)
    u = (k[0, 0] * local[:, 0] / local[:, 2] + k[0, 2]).floor().long().clamp(0, prior.shape[1] - 1)
    v = (k[1, 1] * local[:, 1] / local[:, 2] + k[1, 2]).floor().long().clamp(0, prior.shape[0] - 1)
    return prior.to(rays.directions)[v, u][:, None]


def coarse_weights(self, encoded, rays):
    samples, weights = _coarse_weights(self, encoded, rays)
    alpha = STATE["alpha"]
    if STATE["prior"] is None or not alpha:
        return samples, weights
    z = ray_prior(rays)  # [R, 1]
    gauss = torch.exp(-0.5 * ((samples.t - z) / (STATE["sigma"] * z)) ** 2)
    gauss = gauss / gauss.sum(-1, keepdim=True).clamp(min=1e-12)
    total = weights.sum(-1, keepdim=True)
    mixed = (1 - alpha) * weights + alpha * gauss * total
    usable = torch.isfinite(z) & (gauss.sum(-1, keepdim=True) > 0)
    return samples, torch.where(usable, mixed, weights)


def shade(self, head, seen, rays, samples, reference, backdrop, temperature=0.0):
    """--surface: the fine weights replaced by a unit Gaussian at the prior's depth where there is one."""
    out = _shade(self, head, seen, rays, samples, reference, backdrop, temperature)
    if STATE["prior"] is None or not STATE["surface"] or samples.t.shape[-1] == self.config.samples_coarse:
        return out
    z = ray_prior(rays)
    gauss = torch.exp(-0.5 * ((samples.t - z) / (STATE["surface"] * z)) ** 2)
    gauss = gauss / gauss.sum(-1, keepdim=True).clamp(min=1e-12)
    usable = torch.isfinite(z) & (gauss.sum(-1, keepdim=True) > 0)
    weights = torch.where(usable, gauss, out.weights)
    field = head(seen.points, rays.directions, seen.conds)
    colour = field.blend * field.colour + (1.0 - field.blend) * reference
    return composite(weights, colour, samples.t, backdrop)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="a scene folder with a COLMAP model (sparse/0, sparse or colmap/)")
    parser.add_argument("--views", default="10")
    parser.add_argument("--alphas", default="0,0.5,0.9")
    parser.add_argument("--sigma", type=float, default=0.05)
    parser.add_argument("--surface", type=float, default=0.0,
                        help="> 0: also composite the fine pass as a Gaussian of this relative width at the prior")
    parser.add_argument("--splat", type=int, default=2)
    parser.add_argument("--reach", type=int, default=12)
    parser.add_argument("--max-views", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="eval's side-by-sides under OUT/alpha<A>")
    args = parser.parse_args()
    model = find_model(args.scene) or find_model(args.scene / "colmap")
    reconstruction = pycolmap.Reconstruction(str(model))
    scene, _ = normalize_scene(load_scene(args.scene))
    held = held_out_views(scene, None)
    size = scene.size_for(256)
    scale = unit_scale(scene, reconstruction)
    names = {Path(im.name).name: im.image_id for im in reconstruction.images.values()}
    excluded = {names[Path(scene.names[i]).name] for i in held if Path(scene.names[i]).name in names}
    covered = []
    for index in held:
        name = Path(scene.names[index]).name
        if name not in names:
            continue
        prior = prior_map(reconstruction, name, excluded, size, args.splat, args.reach) * scale
        covered.append(np.isfinite(prior).mean())
        key = round(float(scene.cameras.subset([index]).rescale(*size).centers[0, 0]), 6)
        STATE["priors"][key] = torch.from_numpy(prior)
    print(f"{args.scene.name}: COLMAP -> scene units x{scale:.4f}; prior covers {100 * np.mean(covered):.0f}% of "
          f"the held-out pixels", flush=True)
    InsertNeRF.coarse_weights = coarse_weights
    ViewRenderer.render = render
    counts = tuple(int(v) for v in args.views.split(","))
    STATE["sigma"], STATE["surface"] = args.sigma, args.surface
    InsertNeRF.shade = shade
    for alpha in (float(a) for a in args.alphas.split(",")):
        STATE["alpha"] = alpha
        out = args.out / f"alpha{alpha:g}" if args.out else None
        run = run_eval(args.scene, EvalConfig(views=counts, max_views=args.max_views, out_dir=out, overwrite=True))
        scores = " | ".join(f"{r.reference_views} views {r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports)
        print(f"{args.scene.name} | alpha {alpha} sigma {args.sigma} | {scores}", flush=True)


if __name__ == "__main__":
    main()
