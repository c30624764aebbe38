"""Where a washed-out thin dark structure's colour goes: a plane sweep on the pixels the generator paints pale.

Issue 27 (round 14): beer's railing and table legs are dark in the photo and a pale wash in the render. For each
held-out view (eval's render, 10 references, 256 px or --resolution) this takes the "washed" pixels of the top
third: dark in the photo (luminance < DARK) and at least WASH brighter in the render. For each one it sweeps SWEEP
depths along the pixel's ray (even in inverse depth, from half the near bound to four times the far one), projects
them into the references and reads their colours. It prints, over all washed pixels:

- eval's mean PSNR, and the same with these pixels painted as in the photo (what they cost);
- at the rendered depth, whether the references' mean colour matches the photo (within MATCH): if so, the blend
  lost it; at the sweep's most consistent depth (lowest colour spread, >= MIN_SEEN references seeing it) likewise;
- how many references show the photo's colour at the rendered depth and at the best depth for it along the ray,
  against chance (each reference's matches shifted along the sweep by its own offset: agreement on one depth
  lost). Far above chance means the references hold a photo-consistent surface for the structure.

--pixels kept runs the same on the dark pixels the render gets right (the check that the sweep's geometry is
sound); --pixels wrong on every pixel the render misses by more than WRONG in some channel, anywhere.

    OMP_NUM_THREADS=2 python3 bench/sweep_probe.py --captures beer [--pixels washed|kept|wrong] [--checkpoint W]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DARK, WASH, MATCH = 0.3, 0.2, 0.1  # luminance of a dark photo pixel, how much paler the render, colour tolerance
WRONG = 0.25  # --pixels wrong: the render's error in some channel
SWEEP = 192
MIN_SEEN = 3
LUMA = torch.tensor([0.299, 0.587, 0.114], dtype=torch.float64)


def reference_colours(images: torch.Tensor, cameras, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Colours [R, P, 3] of world points [P, 3] in reference images [R, H, W, 3], and [R, P] which refs see them."""
    uv, depth = cameras.project(points)
    seen = cameras.in_image(uv, depth)
    h, w = images.shape[1:3]
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1)[:, :, None]  # [R, P, 1, 2]
    colours = F.grid_sample(images.permute(0, 3, 1, 2), grid, mode="bilinear", align_corners=False)  # [R, 3, P, 1]
    return colours[..., 0].permute(0, 2, 1), seen


def sweep(images, cameras, camera, uv: torch.Tensor, near: float, far: float, rendered: torch.Tensor,
          truth: torch.Tensor) -> dict:
    """Per washed pixel (uv [P, 2], rendered depth [P], photo colour [P, 3]): the references' colours at the
    rendered depth and at the best sweep depth, and the most references that show the photo's colour at one
    depth of the sweep."""
    depths = 1.0 / torch.linspace(1.0 / (0.5 * near), 1.0 / (4.0 * far), SWEEP, dtype=torch.float64)  # [D]
    p = uv.shape[0]
    all_depths = torch.cat([rendered[:, None], depths[None].expand(p, -1)], 1)  # [P, 1 + D]
    points = camera.unproject(uv[None].repeat_interleave(1 + SWEEP, 1).reshape(1, -1, 2),
                              all_depths.reshape(1, -1))[0]  # [P * (1 + D), 3]
    colours, seen = reference_colours(images, cameras, points)
    colours = colours.reshape(len(cameras), p, 1 + SWEEP, 3)
    seen = seen.reshape(len(cameras), p, 1 + SWEEP).to(torch.float64)
    count = seen.sum(0)  # [P, 1 + D]
    mean = (colours * seen[..., None]).sum(0) / count.clamp(min=1)[..., None]  # [P, 1 + D, 3]
    spread = ((colours - mean) ** 2 * seen[..., None]).sum((0, 3)) / count.clamp(min=1)  # [P, 1 + D]
    spread = torch.where(count >= MIN_SEEN, spread, torch.full_like(spread, float("inf")))
    best = spread[:, 1:].argmin(1) + 1  # [P]
    rows = torch.arange(p)
    showing = (((colours - truth[None, :, None]).abs().amax(-1) < MATCH) & (seen > 0)).sum(0)  # [P, 1 + D]
    # Chance level: each reference's matches shifted along the sweep by its own random offset (runs kept), so only
    # the agreement of the references on one depth is lost.
    hits = ((colours - truth[None, :, None]).abs().amax(-1) < MATCH) & (seen > 0)  # [R, P, 1 + D]
    offsets = torch.randint(0, SWEEP, (len(cameras),), generator=torch.Generator().manual_seed(0))
    shifted = torch.stack([hits[r, :, 1:].roll(int(o), 1) for r, o in enumerate(offsets)])
    chance = shifted.sum(0).amax(1)
    return {"at_rendered": mean[:, 0], "best": mean[rows, best], "best_depth": all_depths[rows, best],
            "best_seen": count[rows, best], "rendered_seen": count[:, 0],
            "showing": showing[:, 1:].amax(1).to(torch.float64), "showing_rendered": showing[:, 0].to(torch.float64),
            "chance": chance.to(torch.float64)}


def probe(capture: Path, checkpoint: Path | None, views: int, pixels: str = "washed", resolution: int = 256) -> None:
    scene, _ = normalize_scene(load_scene(capture))
    held = held_out_views(scene)
    size = scene.size_for(resolution)
    renderer = ViewRenderer(load_model(checkpoint_path(checkpoint), "cpu"), scene, size, views)
    found: dict[str, list[torch.Tensor]] = {}
    truths, renders, fars, depths = [], [], [], []
    scores: list[tuple[float, float]] = []  # per view: PSNR, PSNR with these pixels set to the photo's
    for index in held:
        camera = scene.cameras.subset([index]).rescale(*size).to(dtype=torch.float64)
        truth = torch.from_numpy(scene.load_image(index, *size).astype(np.float64))  # [H, W, 3]
        near, far = float(scene.near[index]), float(scene.far[index])
        out, refs = renderer.render(camera, near, far, held, views)
        render = out.rgb.double().cpu()
        if pixels == "kept":  # the check: dark pixels the render gets right, anywhere in the image
            washed = (truth @ LUMA < DARK) & ((render - truth).abs().amax(-1) < MATCH)
        elif pixels == "wrong":
            washed = (render - truth).abs().amax(-1) > WRONG
        else:
            washed = (truth @ LUMA < DARK) & (render @ LUMA > truth @ LUMA + WASH)  # [H, W]
            washed[size[0] // 3:] = False  # the top third: where beer's railing and table legs are
        mse = ((render - truth) ** 2).mean()
        mended = torch.where(washed[..., None], truth, render)
        scores.append((float(-10 * torch.log10(mse)), float(-10 * torch.log10(((mended - truth) ** 2).mean()))))
        if not washed.any():
            continue
        rows, cols = torch.nonzero(washed, as_tuple=True)
        uv = torch.stack([cols, rows], 1).to(torch.float64) + 0.5
        images = torch.from_numpy(np.stack([scene.load_image(r, *size) for r in refs]).astype(np.float64))
        cameras = scene.cameras.subset(refs).rescale(*size).to(dtype=torch.float64)
        result = sweep(images, cameras, camera, uv, near, far, out.depth.double().cpu()[rows, cols],
                       truth[rows, cols])
        for key, value in result.items():
            found.setdefault(key, []).append(value)
        truths.append(truth[rows, cols])
        renders.append(render[rows, cols])
        fars.append(torch.full((len(rows),), far, dtype=torch.float64))
        depths.append(out.depth.double().cpu()[rows, cols])
    if not truths:
        print(f"{capture.name}: no such pixels")
        return
    r = {k: torch.cat(v) for k, v in found.items()}
    truth, render, far, rendered = torch.cat(truths), torch.cat(renders), torch.cat(fars), torch.cat(depths)
    close = lambda colour: ((colour - truth).abs().amax(-1) < MATCH).double().mean().item() * 100  # noqa: E731
    n = len(truth)
    what = {"kept": "dark pixels rendered right", "wrong": f"pixels missed by > {WRONG}",
            "washed": "washed pixels in the top third"}[pixels]
    print(f"{capture.name} | {views} views | {n} {what} of {len(held)} held-out views "
          f"(photo luminance {float((truth @ LUMA).mean()):.2f}, render {float((render @ LUMA).mean()):.2f})")
    as_is, mended = np.mean(scores, axis=0)
    print(f"  eval's mean PSNR {as_is:.2f} dB; with these pixels painted as in the photo {mended:.2f} dB")
    print(f"  at the rendered depth the references' mean colour matches the photo for {close(r['at_rendered']):.0f}% "
          f"(luminance {float((r['at_rendered'] @ LUMA).mean()):.2f}; seen by {float(r['rendered_seen'].mean()):.1f} "
          f"references)")
    print(f"  at the most consistent depth of the sweep: matches for {close(r['best']):.0f}% (luminance "
          f"{float((r['best'] @ LUMA).mean()):.2f}; seen by {float(r['best_seen'].mean()):.1f}); that depth / the "
          f"rendered one: median {float((r['best_depth'] / rendered).median()):.2f}; beyond the far bound for "
          f"{float((r['best_depth'] > far).double().mean()) * 100:.0f}%")
    print(f"  references showing the photo's colour (within {MATCH}) at the rendered depth: mean "
          f"{float(r['showing_rendered'].mean()):.1f}; at the best depth for it along the ray: mean "
          f"{float(r['showing'].mean()):.1f}, share with >= 3: {float((r['showing'] >= 3).double().mean()) * 100:.0f}% "
          f"(chance, each reference shifted along the sweep: {float(r['chance'].mean()):.1f}, "
          f"{float((r['chance'] >= 3).double().mean()) * 100:.0f}%)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--pixels", choices=("washed", "kept", "wrong"), default="washed",
                        help="washed: dark in the photo, pale in the top third of the render; kept: dark pixels the "
                             "render gets right (the check); wrong: every pixel missed by more than WRONG")
    parser.add_argument("--resolution", type=int, default=256, help="long side of the render, as eval's")
    args = parser.parse_args()
    for name in args.captures.split(","):
        probe(args.root / name, args.checkpoint, args.views, args.pixels, args.resolution)


if __name__ == "__main__":
    main()
