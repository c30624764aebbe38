"""Probe: the generator against plain image-based rendering at the SfM depth (issue 27, round 28).

For every held-out view (eval's split, references and SfM prior), the frame is rendered as eval renders it, and
beside it the reference photos (at the frame's size) are reprojected through each pixel at a depth that needs no
network:
  - prior: the frame's SfM depth prior (depth_prior.view_prior), where it has one;
  - rendered: the generator's own rendered depth, everywhere;
  - select: per pixel whichever of the two the references agree on better (their lumigraph-weighted colour
    variance, box-filtered over a --window patch);
  - exact: synth's depth file (scenes made by `insertnerf synth`); sweep: a plane sweep (--sweep N depths).
At that depth the references' colours are blended with the lumigraph weights of the K views nearest in angle
(aggregate.angular_prior, each K of --k), or the nearest one alone, or (an upper bound on any blend of them) the
reference colour nearest the photo's. Prints PSNR over the pixels the prior covers ("@prior") and over the whole
frame (the generator where a variant has no colour), so one sees whether the generator loses against its own
inputs. "mixM": the generator's frame with the blend at the prior depth (K = 8) put in where the references agree
M times better there than at the rendered depth. --variants re-renders the frame with the generator patched in
this process (force, refonly, opaque, lumi, coarsecolour: patched_render) and scores each alone and mixed in alike.

    OMP_NUM_THREADS=2 python3 bench/ibr_baseline.py --captures mold_gold_cape,room --views 10 [--max-views 5]
    OMP_NUM_THREADS=1 python3 bench/ibr_baseline.py --root /tmp/fov/fov_24_30 --captures scene_00000 --k 8
    OMP_NUM_THREADS=1 python3 bench/ibr_baseline.py --captures mold_gold_cape --variants force,lumi --max-views 5
"""
from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.cameras import Cameras  # noqa: E402
from insertnerf_cli.compositing import composite, composite_weights  # noqa: E402
from insertnerf_cli.depth_prior import covering_far, guide_weights  # noqa: E402
from insertnerf_cli.model.consistency import sharpen  # noqa: E402
from insertnerf_cli.model.aggregate import angular_prior  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.training.depth import read_scene_depth  # noqa: E402
from insertnerf_cli.triangulate import with_points  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import evenly_spread, held_out_views  # noqa: E402

WINDOW = 7
SWEEP = 0
MARGINS = (1.0, 1.5, 2.0)
FORCE = 0.02
VARIANTS: list[str] = []
ROOT = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def reproject(camera: Cameras, depth: torch.Tensor, refs: Cameras, photos: torch.Tensor):
    """Reference colours [V, 3, P] at the pixels of ``camera`` (1) lifted to ``depth`` [H, W] (NaN: none), with
    their mask [V, 1, P] and ray_diff [V, 4, P] as the generator's projection gives them."""
    uv = camera.pixel_grid().reshape(1, -1, 2)  # [1, P, 2]
    z = torch.nan_to_num(depth, nan=1.0).reshape(1, -1)
    points = camera.unproject(uv, z)[0]  # [P, 3]
    ref_uv, ref_z = refs.project(points)  # [V, P, 2], [V, P]
    inside = refs.in_image(ref_uv, ref_z) & ~torch.isnan(depth.reshape(1, -1))
    scale = torch.tensor([2.0 / refs.width, 2.0 / refs.height], dtype=ref_uv.dtype)
    grid = (ref_uv * scale - 1.0)[:, None].float()  # [V, 1, P, 2]
    colours = F.grid_sample(photos, grid, mode="bilinear", align_corners=False)[:, :, 0]  # [V, 3, P]
    query = F.normalize(points - camera.centers[0], dim=-1).T[None]  # [1, 3, P]
    ref_dir = F.normalize(points[None] - refs.centers[:, None], dim=-1).transpose(1, 2)  # [V, 3, P]
    cos = (ref_dir * query).sum(dim=1, keepdim=True)
    ray_diff = torch.cat([ref_dir - query, cos], dim=1).float()
    return colours, inside[:, None].float(), ray_diff


def blends(colours, mask, ray_diff, truth, ks: list[int]) -> dict[str, torch.Tensor]:
    """[P, 3] per variant: lumigraph blend of the K nearest in angle (each K of ``ks``), the nearest alone, the
    oracle reference."""
    cos = torch.where(mask > 0, ray_diff[:, 3:], torch.full_like(mask, -2.0))
    nearest = torch.zeros_like(mask).scatter_(0, cos.argmax(dim=0, keepdim=True), 1.0) * mask
    err = ((colours - truth.T[None]) ** 2).sum(dim=1, keepdim=True) + (1.0 - mask) * 1e3  # [V, 1, P]
    best = torch.zeros_like(err).scatter_(0, err.argmin(dim=0, keepdim=True), 1.0)
    weights = [(f"lumigraph{k}", angular_prior(ray_diff, mask, k)) for k in ks]  # [V, 1, P] each
    return {name: (colours * w).sum(dim=0).T for name, w in
            (*weights, ("nearest", nearest), ("oracle", best))}


def consistency(colours, mask, ray_diff, size: tuple[int, int], window: int) -> torch.Tensor:
    """[P] the lumigraph-weighted (K = 4) RGB variance of the references at each pixel, box-filtered over a
    ``window`` x ``window`` patch (a pixel alone matches noise); +inf where fewer than two views see it."""
    weights = angular_prior(ray_diff, mask, 4)
    mean = (colours * weights).sum(dim=0, keepdim=True)
    var = (((colours - mean) ** 2) * weights).sum(dim=(0, 1))  # [P]
    var = torch.where(mask.sum(dim=(0, 1)) >= 2, var, torch.full_like(var, 1.0))
    var = F.avg_pool2d(var.reshape(1, 1, *size), window, stride=1, padding=window // 2, count_include_pad=False)
    return var.reshape(-1)


def sweep_depth(camera, ref_cams, photos, near: float, far: float, planes: int, window: int) -> torch.Tensor:
    """[H, W] plane-sweep depth: of ``planes`` depths even in disparity over [near, far], the one where the
    references agree best (consistency)."""
    size = (camera.height, camera.width)
    best_cost = torch.full((size[0] * size[1],), float("inf"))
    best = torch.full_like(best_cost, float("nan"))
    for disparity in torch.linspace(1.0 / near, 1.0 / far, planes):
        depth = torch.full(size, float(1.0 / disparity))
        colours, mask, ray_diff = reproject(camera, depth, ref_cams, photos)
        cost = consistency(colours, mask, ray_diff, size, window)
        better = cost < best_cost
        best_cost = torch.where(better, cost, best_cost)
        best = torch.where(better, depth.reshape(-1), best)
    return best.reshape(size)


def _reference_only_shade(self, head, seen, rays, samples, reference, backdrop, temperature=0.0):
    """InsertNeRF.shade with the field's colour left out: the composite blends the reference colour alone."""
    field = head(seen.points, rays.directions, seen.conds)
    weights = composite_weights(field.density, samples.edges, rays.directions.norm(dim=-1))
    if temperature:
        weights = sharpen(weights, seen.colour_variance, temperature)
    return composite(weights, reference, samples.t, backdrop)


def _opaque_shade(self, head, seen, rays, samples, reference, backdrop, temperature=0.0):
    """InsertNeRF.shade with each ray's weights scaled to sum to 1: nothing of the backdrop shows through."""
    field = head(seen.points, rays.directions, seen.conds)
    colour = field.blend * field.colour + (1.0 - field.blend) * reference
    weights = composite_weights(field.density, samples.edges, rays.directions.norm(dim=-1))
    if temperature:
        weights = sharpen(weights, seen.colour_variance, temperature)
    total = weights.sum(dim=-1, keepdim=True)
    weights = torch.where(total > 1e-3, weights / total.clamp(min=1e-3), weights)
    return composite(weights, colour, samples.t, backdrop)


def patched_render(renderer, variant: str, *args):
    """renderer.render(*args) with ``variant``'s parts patched in this process: force (every fine sample in a band
    of relative width FORCE around the prior), refonly (the reference colour alone), opaque (no backdrop shows
    through), lumi (the colour's view weights: the angular prior alone), coarsecolour (colours at the frame's
    size), joined by '+'."""
    import insertnerf_cli.model.insertnerf as model_module
    import insertnerf_cli.render as render_module
    from insertnerf_cli.model.insertnerf import InsertNeRF

    kept = render_module.guide_weights, InsertNeRF.shade, model_module.reweigh, renderer.colour_size, renderer.cache
    parts = variant.split("+")
    if "lumi" in parts:  # the colour's view weights: the angular prior alone, not times the learned weights
        model_module.reweigh = lambda weights, prior: prior
    if "coarsecolour" in parts:  # the colours looked up at the frame's size (encodings made anew)
        renderer.colour_size, renderer.cache = None, type(renderer.cache)()
    if "force" in parts:
        render_module.guide_weights = partial(guide_weights, share=1.0, width=FORCE)
    if "refonly" in parts:
        InsertNeRF.shade = _reference_only_shade
    if "opaque" in parts:
        InsertNeRF.shade = _opaque_shade
    try:
        return renderer.render(*args)[0]
    finally:
        render_module.guide_weights, InsertNeRF.shade, model_module.reweigh, renderer.colour_size, renderer.cache \
            = kept


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(-10.0 * torch.log10(((a - b) ** 2).mean().clamp(min=1e-12)))


def probe(capture: str, views: int, max_views: int | None, ks: list[int], root: Path) -> None:
    scene, _ = normalize_scene(load_scene(root / capture))
    held = held_out_views(scene)
    size = scene.size_for(256)
    scene = with_points(scene, [i for i in range(len(scene)) if i not in held])
    # "gen" is the generator's frame alone; "mix" is what prior_blend became.
    renderer = ViewRenderer(load_model(checkpoint_path(None), "cpu"), scene, size, views, prior_blend=False)
    rows = []
    for index in evenly_spread(held, max_views):
        camera = scene.cameras.subset([index]).rescale(*size)
        truth = torch.from_numpy(scene.load_image(index, *size).astype(np.float32)).reshape(-1, 3)
        out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, views)
        gen = out.rgb.float().reshape(-1, 3)
        ref_cams = scene.cameras.subset(refs).rescale(*size)
        photos = torch.from_numpy(np.stack([scene.load_image(i, *size) for i in refs]).astype(np.float32))
        photos = photos.permute(0, 3, 1, 2)
        prior = renderer._prior(camera, refs, held)
        has = ~torch.isnan(prior.reshape(-1)) if prior is not None else torch.zeros(len(gen), dtype=torch.bool)
        row = {"view": scene.names[index], "cover": float(has.float().mean()), "gen": psnr(gen, truth),
               "gen@prior": psnr(gen[has], truth[has]) if has.any() else float("nan")}
        cam32, refs32 = camera.to(dtype=torch.float32), ref_cams.to(dtype=torch.float32)
        rendered = out.depth.float()
        depths = {"prior": prior, "rendered": rendered}
        if prior is not None:
            costs = [consistency(*reproject(cam32, d, refs32, photos), size, WINDOW) for d in (prior.float(), rendered)]
            chosen = (costs[0] < costs[1]) & has
            depths["select"] = torch.where(chosen.reshape(size), prior.float(), rendered)
            colours, mask, ray_diff = reproject(cam32, prior.float(), refs32, photos)
            ibr = (colours * angular_prior(ray_diff, mask, 8)).sum(dim=0).T
            for variant in VARIANTS:  # the generator re-rendered with a change, taken where the prior is chosen
                forced_rgb = patched_render(renderer, variant, camera, float(scene.near[index]),
                                            float(scene.far[index]), held, views).rgb.float().reshape(-1, 3)
                row[f"{variant}@prior"] = psnr(forced_rgb[has], truth[has])
                row[f"{variant}"] = psnr(forced_rgb, truth)
                for margin in MARGINS:
                    use = (costs[0] * margin < costs[1]) & has & (mask.sum(dim=(0, 1)) >= 2)
                    row[f"{variant}:mix{margin}"] = psnr(torch.where(use[:, None], forced_rgb, gen), truth)
            for margin in MARGINS:
                use = (costs[0] * margin < costs[1]) & has & (mask.sum(dim=(0, 1)) >= 2)
                row[f"mix{margin}"] = psnr(torch.where(use[:, None], ibr, gen), truth)
                row[f"mix{margin}:share"] = float(use.float().mean())
        exact = read_scene_depth(scene, index, *size) if scene.depth_paths is not None else None
        if exact is not None:  # synth scenes: the true depth (0 = no surface: none)
            depths["exact"] = torch.from_numpy(np.where(exact > 0, exact, np.nan).astype(np.float32))
        if SWEEP:
            far = covering_far(float(scene.far[index]), prior)
            depths["sweep"] = sweep_depth(cam32, refs32, photos, float(scene.near[index]), far, SWEEP, WINDOW)
        for source, depth in depths.items():
            if depth is None:
                continue
            colours, mask, ray_diff = reproject(cam32, depth.float(), refs32, photos)
            seen = mask.sum(dim=0)[0] > 0
            for name, rgb in blends(colours, mask, ray_diff, truth, ks).items():
                use = has & seen if source == "prior" else seen
                full = torch.where(use[:, None], rgb, gen)
                row[f"{source}:{name}@prior"] = psnr(rgb[has & seen], truth[has & seen]) if (has & seen).any() \
                    else float("nan")
                row[f"{source}:{name}"] = psnr(full, truth)
        rows.append(row)
        print(" ".join(f"{key}={value:.2f}" if isinstance(value, float) else f"{key}={value}"
                       for key, value in row.items()), flush=True)
    keys = [key for key in rows[0] if key != "view"]
    print(f"{capture} {views} views, mean over {len(rows)} views:")
    for key in keys:
        print(f"  {key:28s} {np.nanmean([r.get(key, np.nan) for r in rows]):6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--captures", default="mold_gold_cape", help="folders under --root (comma-separated)")
    parser.add_argument("--root", type=Path, default=ROOT)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--max-views", type=int, default=None)
    parser.add_argument("--k", default="4", help="lumigraph weights over the K views nearest in angle (a list)")
    parser.add_argument("--sweep", type=int, default=0, help="also a plane sweep over this many depths")
    parser.add_argument("--window", type=int, default=7, help="patch side of the consistency cost")
    parser.add_argument("--variants", default="", help="generator re-renders: force, refonly, opaque, joined by +")
    parser.add_argument("--force", type=float, default=0.02, help="relative band width of the force variant")
    args = parser.parse_args()
    global SWEEP, WINDOW, FORCE, VARIANTS
    SWEEP, WINDOW, FORCE = args.sweep, args.window, args.force
    VARIANTS = [v for v in args.variants.split(",") if v]
    torch.set_grad_enabled(False)
    for capture in args.captures.split(","):
        probe(capture, args.views, args.max_views, [int(k) for k in args.k.split(',')], args.root)


if __name__ == "__main__":
    main()
