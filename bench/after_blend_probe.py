"""Probe: what is left after round 28's blend at the SfM depth (issue 27, round 29).

Every variant starts from the frame eval renders (ViewRenderer.render: the SfM prior, the raised far bound, the
blend at the prior) and changes one thing, in this process only; each is scored on eval's held-out views (a
--max-views subset, evenly spread) at each count of --views:
  - base: the frame as eval renders it;
  - refine:K:STEP: the references' patch variance (prior_blend's test) at the rendered depth times 1 + k STEP,
    k = -K..K; a pixel takes the blend at the best where it is MARGIN (each of --margins) times lower than at the
    rendered depth (local stereo around the generator's depth);
  - sweep:N:SPAN: the same over N planes even in disparity from near to SPAN x far, for the pixels without an SfM
    prior only (the background the blend cannot reach); also prints, on those pixels, the generator, the blend at
    the rendered depth, the blend at the swept depth, and an oracle (per pixel the plane whose blend is nearest the
    photo over the patch: what the references hold, not a method);
  - far:X: every frame's far bound times X;
  - reach:R: the blend's prior filled R of the long side from its splats (the guide's stays REACH_FRACTION);
  - kblend:K: every pixel a reference sees gets the lumigraph blend of its K views nearest in angle at the
    rendered depth (and "half": the mean of that and the frame's colour);
  - --points own|fresh|union|tracked|flat: the SfM points of a scene that comes with its own (a COLMAP model): those
    (eval's choice), points triangulated anew at its poses from the references (as for a scene without points),
    both, or its own less those that fewer than three of the views not held out observe (two-view tracks);
    flat: the points as they are, with round 29's prior: every point a frame's references see in one layer, where
    render's (round 30) lets those fewer than three usable views observe fill only what the others leave empty.
  - parallax:P: the colour's lumigraph weights (the generator's colour prior and the blend's) times
    exp(-(a f / P)^2 + (a_min f / P)^2), a a view's angle, f the frame's focal length in px: views whose parallax
    per unit of relative depth error passes P px lose their say, so a long lens keeps fewer.

    OMP_NUM_THREADS=2 python3 bench/after_blend_probe.py --captures mold_gold_cape --views 3,10 --max-views 5 \
        --variants base,refine:4:0.01,far:1.5,far:2.5,reach:0.1,reach:0.2,reach:1,parallax:50,parallax:100
    OMP_NUM_THREADS=2 python3 bench/after_blend_probe.py --captures mold_gold_cape --views 3,10 --max-views 3 \
        --variants kblend:2,kblend:3,kblend:8
    OMP_NUM_THREADS=2 python3 bench/after_blend_probe.py --captures mold_gold_cape --views 10 --views-at 56,72,80 \
        --variants sweep:48:3
    OMP_NUM_THREADS=1 python3 bench/after_blend_probe.py --captures room --views 3,6,10,16 --max-views 0 --points fresh
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import insertnerf_cli.model.insertnerf as model_module  # noqa: E402
import insertnerf_cli.prior_blend as pb  # noqa: E402
from insertnerf_cli import depth_prior  # noqa: E402
from insertnerf_cli.model.aggregate import angular_prior  # noqa: E402
from insertnerf_cli.model.projection import ray_angle  # noqa: E402
from insertnerf_cli.rays import rays_for_image  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.scenes.points import ScenePoints  # noqa: E402
from insertnerf_cli.triangulate import triangulate_points, with_points  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import evenly_spread, held_out_views  # noqa: E402

ROOT = Path(__file__).resolve().parents[2] / "shared" / "realdata"
PARALLAX = {"f": 1.0, "P": 0.0}


def parallax_cut(blend_views: int):
    """angular_prior whose weights of K = ``blend_views`` are cut by PARALLAX (others and P = 0: unchanged)."""
    def cut(ray_diff, mask, views, angle=None):
        weights = angular_prior(ray_diff, mask, views, angle)
        if PARALLAX["P"] <= 0 or views != blend_views:
            return weights
        a = (ray_angle(ray_diff) if angle is None else angle) * (PARALLAX["f"] / PARALLAX["P"])
        a = torch.where(mask > 0, a, torch.full_like(a, 1e3))
        weights = weights * torch.exp(-(a ** 2 - a.amin(dim=0, keepdim=True) ** 2))
        return weights / weights.sum(dim=0, keepdim=True).clamp(min=1e-12)
    return cut


def psnr(rgb: torch.Tensor, truth: np.ndarray, where: np.ndarray | None = None) -> float:
    """PSNR of ``rgb`` [.., 3] against ``truth`` [H, W, 3], over the pixels ``where`` [R] (default: all)."""
    err = ((rgb.double().reshape(-1, 3).numpy() - truth.reshape(-1, 3)) ** 2).mean(-1)
    return float(-10.0 * np.log10((err if where is None else err[where]).mean()))


def seen_at(renderer, refs, camera, depth: torch.Tensor):
    """prior_blend's lookups of the frame's pixels at camera-z ``depth`` [R]: (patch variance [R], blend [R, 3])."""
    rays = rays_for_image(camera.to(dtype=torch.float32), torch.ones(1), torch.ones(1))
    seen = pb.reference_colours(renderer._encoded(refs), rays, depth.float())
    return pb.patch_mean(pb.variance(seen), renderer.size), pb.blend(seen), seen


def search(renderer, refs, camera, depths, truth=None):
    """Over candidate depth maps [R] each: (lowest patch variance, its blend, the oracle's blend or None)."""
    pixels = len(depths[0])
    best, colour = torch.full((pixels,), float("inf")), torch.zeros(pixels, 3)
    oracle_err, oracle = best.clone(), colour.clone()
    for depth in depths:
        var, col, _ = seen_at(renderer, refs, camera, depth)
        better = var < best
        best, colour = torch.where(better, var, best), torch.where(better[:, None], col, colour)
        if truth is not None:
            err = pb.patch_mean(((col.double() - torch.from_numpy(truth.reshape(-1, 3))) ** 2).sum(-1).float(),
                                renderer.size)
            take = err < oracle_err
            oracle_err, oracle = torch.where(take, err, oracle_err), torch.where(take[:, None], col, oracle)
    return best, colour, (oracle if truth is not None else None)


def variant_frame(name: str, args, renderer, scene, index, camera, held, n, truth, extra: dict):
    """The frame of ``camera`` at ``n`` views under variant ``name`` (ImageOutput's rgb [H, W, 3])."""
    kind, *rest = name.split(":")
    near, far = float(scene.near[index]), float(scene.far[index])
    if kind == "far":
        return renderer.render(camera, near, float(rest[0]) * far, held, n)[0].rgb
    if kind == "parallax":
        PARALLAX.update(f=float(camera.K[0, 0, 0]), P=float(rest[0]))
        try:
            return renderer.render(camera, near, far, held, n)[0].rgb
        finally:
            PARALLAX["P"] = 0.0
    if kind == "reach":
        renderer.prior_blend = False
        try:
            out, refs = renderer.render(camera, near, far, held, n)
        finally:
            renderer.prior_blend = True
        prior = renderer._prior(camera, refs, held)
        seen = scene.points.seen_from(list(refs), near=list(refs)[:depth_prior.PRIOR_VIEWS])
        if prior is None or not len(seen):
            return out.rgb
        wide = depth_prior.prior_depth(seen, camera, float(rest[0]))
        return pb.blend_at_prior(out, renderer._encoded(refs), camera, wide,
                                 depth_prior.covering_far(far, prior)).rgb
    out, refs = renderer.render(camera, near, far, held, n)
    if kind == "base":
        return out.rgb
    rendered = out.depth.float().reshape(-1)
    own, at_rendered, seen = seen_at(renderer, refs, camera, rendered)
    frame = out.rgb.reshape(-1, 3)
    if kind == "kblend":
        weights = angular_prior(seen.ray_diff, seen.mask, int(rest[0]))
        colour = (seen.blend_colours * weights).sum(dim=0).T.to(frame)
        seen_any = (seen.mask.sum(dim=(0, 1)) > 0)[:, None]
        extra.setdefault(f"{name}:half", []).append(
            psnr(torch.where(seen_any, 0.5 * (colour + frame), frame), truth))
        return torch.where(seen_any, colour, frame)
    if kind == "refine":
        steps, step = int(rest[0]), float(rest[1])
        depths = [rendered * (1.0 + k * step) for k in range(-steps, steps + 1) if k]
        best, colour, _ = search(renderer, refs, camera, depths)
    elif kind == "sweep":
        planes, span = int(rest[0]), float(rest[1])
        depths = [torch.full_like(rendered, float(1.0 / d))
                  for d in torch.linspace(1.0 / near, 1.0 / (span * far), planes)]
        best, colour, oracle = search(renderer, refs, camera, depths, truth)
        prior = renderer._prior(camera, refs, held)
        bare = ~np.isfinite(prior.numpy().reshape(-1)) if prior is not None else np.ones(len(rendered), bool)
        for label, rgb in (("gen", frame), ("blend@rendered", at_rendered),
                           ("blend@swept", colour), ("oracle", oracle)):
            extra.setdefault(f"{name}:bare:{label}", []).append(psnr(rgb, truth, bare))
        best = torch.where(torch.from_numpy(bare), best, torch.full_like(best, float("inf")))
    else:
        raise SystemExit(f"unknown variant {name!r}")
    for margin in args.margins[1:]:
        take = (best * margin < own)[:, None]
        extra.setdefault(f"{name}:m{margin:g}", []).append(psnr(torch.where(take, colour.to(frame), frame), truth))
    return torch.where((best * args.margins[0] < own)[:, None], colour.to(frame), frame)


def scene_points(scene, references: list[int], which: str):
    """``scene`` with the SfM points ``which`` says (--points) for a scene that comes with its own."""
    if which == "flat":
        depth_prior.WELL_TRACKED = 0  # every point of a frame's prior in one layer
    if scene.points is None or which in ("own", "flat"):
        return with_points(scene, references)
    if which == "tracked":
        own = scene.points
        keep = own.observers(references) >= 3
        renumber = torch.cumsum(keep.long(), 0) - 1
        observed = tuple(renumber[rows[keep[rows]]] for rows in own.observed)
        return replace(scene, points=ScenePoints(own.xyz[keep], observed))
    fresh = triangulate_points(scene, references)
    if which == "fresh":
        return replace(scene, points=fresh)
    own, shift = scene.points, len(scene.points)  # union: the fresh points' indices follow the own ones
    observed = tuple(torch.cat([a, b + shift]) for a, b in zip(own.observed, fresh.observed))
    return replace(scene, points=ScenePoints(torch.cat([own.xyz, fresh.xyz.to(own.xyz)]), observed))


def probe(capture: str, args) -> None:
    scene, _ = normalize_scene(load_scene(args.root / capture))
    held = held_out_views(scene)
    size = scene.size_for(256)
    scene = scene_points(scene, [i for i in range(len(scene)) if i not in held], args.points)
    checkpoint = checkpoint_path(args.checkpoint)
    renderer = ViewRenderer(load_model(checkpoint, "cpu"), scene, size, max(args.views))
    model_module.angular_prior = parallax_cut(renderer.model.config.colour_prior_views)  # the colour's prior only
    indices = args.views_at if args.views_at else evenly_spread(held, args.max_views or None)
    scores: dict[str, list[float]] = {}
    for index in indices:
        camera = scene.cameras.subset([index]).rescale(*size)
        truth = scene.load_image(index, *size).astype(np.float64)
        for n in args.views:
            for name in args.variants:
                extra: dict[str, list[float]] = {}
                rgb = variant_frame(name, args, renderer, scene, index, camera, held, n, truth, extra)
                scores.setdefault(f"{name} @{n}", []).append(psnr(rgb, truth))
                for key, values in extra.items():
                    scores.setdefault(f"{key} @{n}", []).extend(values)
    print(f"{capture}: {len(indices)} held-out views, margin {args.margins[0]:g} unless named")
    for key, values in scores.items():
        print(f"  {key:36s} {np.mean(values):6.2f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--captures", default="mold_gold_cape")
    parser.add_argument("--root", type=Path, default=ROOT)
    parser.add_argument("--views", default="3,10")
    parser.add_argument("--max-views", type=int, default=5, help="0: every held-out view")
    parser.add_argument("--views-at", default="", help="these held-out view indices instead (comma-separated)")
    parser.add_argument("--variants", default="base")
    parser.add_argument("--margins", default="1.5,2,3", help="refine/sweep: the first is the variant's own")
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument("--points", choices=("own", "fresh", "union", "tracked", "flat"), default="own")
    args = parser.parse_args()
    args.views = [int(v) for v in args.views.split(",")]
    args.views_at = [int(v) for v in args.views_at.split(",") if v]
    args.variants = args.variants.split(",")
    args.margins = [float(m) for m in args.margins.split(",")]
    pb.angular_prior = parallax_cut(pb.BLEND_VIEWS)
    torch.set_grad_enabled(False)
    for capture in args.captures.split(","):
        probe(capture, args)


if __name__ == "__main__":
    main()
