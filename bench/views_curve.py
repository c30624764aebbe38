"""Where the views curve breaks: PSNR per image region for several reference-view counts (issue 27, item 1).

For each held-out view of a scene (eval's split and view choice) the frame is rendered from the k nearest views for
every k of --views; the error is then split by region: the near, middle and far third of the pixels by the depth
of the first count's render, and the edges (the top 15 % of the photo's gradient). Also the mean opacity (a low
one means the fixed background colour shows through: haze) and, with --inspect, the view weights on the pixel whose
error grows most from the first count to the last.

    OMP_NUM_THREADS=2 python3 bench/views_curve.py /work/shared/realdata/room --views 3,10,16 [--exact] \
        [--checkpoint W.pt] [--max-views 3] [--inspect]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.checkpoint import bundled_checkpoint, load_model  # noqa: E402
from insertnerf_cli.rendering.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.cameras.rays import rays_from_pixels  # noqa: E402
from insertnerf_cli.metrics import psnr_from_mse  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.scenes.views import held_out_views  # noqa: E402

REGIONS = ("all", "near", "middle", "far", "edges")
EDGE_QUANTILE = 0.85


def region_masks(depth: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean [H, W] masks of each region: depth thirds of ``depth`` [H, W], edges of ``truth`` [H, W, 3]."""
    low, high = np.quantile(depth, [1 / 3, 2 / 3])
    grey = truth.mean(axis=-1)
    gy, gx = np.gradient(grey)
    grad = np.hypot(gx, gy)
    return {"all": np.ones_like(depth, dtype=bool), "near": depth <= low, "middle": (depth > low) & (depth <= high),
            "far": depth > high, "edges": grad >= np.quantile(grad, EDGE_QUANTILE)}


def region_psnr(error: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB) of the squared error [H, W, 3] over the pixels of ``mask``."""
    return psnr_from_mse(float(error[mask].mean()))


def curve(scene_dir: Path, counts: list[int], checkpoint: Path, exact: bool, max_views: int | None,
          inspect: bool) -> None:
    scene, _ = normalize_scene(load_scene(scene_dir))
    held = held_out_views(scene, max_views)
    size = scene.size_for(256)
    model = load_model(checkpoint, torch.device("cpu"))[0]
    table = {k: {r: [] for r in (*REGIONS, "opacity")} for k in counts}
    worst = None
    renderer = ViewRenderer(model, scene, size, max(counts), exact=exact)
    for index in held:
        truth = scene.load_image(index, *size).astype(np.float64)
        camera = scene.cameras.subset([index]).rescale(*size)
        near, far = float(scene.near[index]), float(scene.far[index])
        masks, errors = None, {}
        for k in counts:
            out, refs = renderer.render(camera, near, far, exclude=held, views=k)
            rgb = out.rgb.double().numpy()
            errors[k] = ((rgb - truth) ** 2)
            if masks is None:
                masks = region_masks(out.depth.double().numpy(), truth)
            for region in REGIONS:
                table[k][region].append(region_psnr(errors[k], masks[region]))
            table[k]["opacity"].append(float(out.opacity.mean()))
        grown = errors[counts[-1]].sum(-1) - errors[counts[0]].sum(-1)
        h, w = grown.shape  # only the central part: at the borders most views cannot see the ray at all
        grown[: h // 5], grown[-h // 5:], grown[:, : w // 5], grown[:, -w // 5:] = 0, 0, 0, 0
        pixel = np.unravel_index(np.argmax(grown), grown.shape)
        if worst is None or grown[pixel] > worst[0]:
            worst = (float(grown[pixel]), index, pixel, camera, near, far)
    print(f"{scene_dir.name}: {len(held)} held-out views at {size[1]}x{size[0]}, exact={exact}, "
          f"checkpoint {checkpoint.name}")
    print("views | " + " | ".join(f"{r:>7}" for r in (*REGIONS, "opacity")))
    for k in counts:
        print(f"{k:>5} | " + " | ".join(f"{np.mean(table[k][r]):7.2f}" if r != "opacity" else
                                        f"{np.mean(table[k][r]):7.3f}" for r in (*REGIONS, "opacity")))
    if inspect and worst is not None:
        inspect_ray(model, scene, held, counts[-1], *worst[1:], size)


def inspect_ray(model, scene, held, k, index, pixel, camera, near, far, size) -> None:
    """Per-view dynamic (learnt) and static (angle) weights at the ray's heaviest fine sample, and whether each
    view's colour there matches the photo: the ghosting diagnosis."""
    from insertnerf_cli.model.projection import project_samples

    renderer = ViewRenderer(model, scene, size, k)
    refs = renderer.references(camera.c2w[0], held)
    encoded = renderer._encoded(refs)
    row, col = int(pixel[0]), int(pixel[1])
    uv = torch.tensor([[[col + 0.5, row + 0.5]]], dtype=torch.float32)
    rays = rays_from_pixels(camera.to(dtype=torch.float32), uv, torch.tensor([near]), torch.tensor([far]))
    truth = scene.load_image(index, *size)[row, col]
    with torch.no_grad():
        composite = model.render(encoded, rays)
        heaviest = int(composite.weights[0].argmax())
        t = composite.t[0, heaviest]
        point = (rays.origins + t * rays.directions)[:, None]  # [1, 1, 3]
        seen = project_samples(encoded, point, rays.directions)
        agg = model.aggregators[-1]
        finest = torch.cat([seen.features[-1], seen.colours], dim=1)
        _, dynamic = agg(finest, seen.mask, seen.ray_diff)
        static = agg.static_weights(seen.cos, seen.mask)
    print(f"inspect: view {scene.names[index]} pixel (row {row}, col {col}), photo {np.round(truth, 3).tolist()}, "
          f"render {np.round(composite.rgb[0].numpy(), 3).tolist()}, opacity {float(composite.opacity[0]):.3f}, "
          f"heaviest sample t={float(t):.3f} (weight {float(composite.weights[0, heaviest]):.3f}, near {near:.3f} "
          f"far {far:.3f})")
    rows = sorted(refs)  # the encoded views are in index order; print them nearest first
    for rank, ref in enumerate(refs):
        i = rows.index(ref)
        colour = seen.colours[i, :, 0].numpy()
        print(f"  rank {rank:>2} {scene.names[ref]:>18}: valid {int(seen.mask[i, 0, 0])}, "
              f"cos {float(seen.cos[i, 0, 0]):.4f}, dynamic {float(dynamic[i, 0, 0]):.3f}, "
              f"static {float(static[i, 0, 0]):.3f}, colour {np.round(colour, 3).tolist()}, "
              f"|colour - photo| {float(np.abs(colour - truth).mean()):.3f}")

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--views", default="3,10,16", help="comma-separated reference-view counts")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--exact", action="store_true", help="render without the speed shortcuts")
    parser.add_argument("--max-views", type=int, default=None, help="held-out views scored, evenly spread")
    parser.add_argument("--inspect", action="store_true", help="print the view weights on the worst-growing ray")
    args = parser.parse_args()
    counts = [int(v) for v in args.views.split(",")]
    curve(args.scene, counts, args.checkpoint or bundled_checkpoint(), args.exact, args.max_views, args.inspect)


if __name__ == "__main__":
    main()
