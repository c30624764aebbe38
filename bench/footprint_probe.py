"""Probe: do the references' pixel sizes differ from the target's, and does matching them help?

Issue 27 (round 18): mold_gold_cape's photos are taken from distances that differ by up to 2x, so a point on the
cape covers a different area in each reference than in the held-out view. A reference whose pixels are smaller
than the target's at a sample (footprint ratio rho = target pixel size / reference pixel size > 1) shows finer
detail than the target's pixel averages over, which aliases the punched texture. This patches, in this process
only, the reference colour lookup (model.projection.project_samples as the model calls it): with --levels L > 0
every colour comes from a box-filtered pyramid of each reference (L levels of 2x2 averages), at level log2(rho)
clamped to [0, L], trilinear between levels (as a GPU's mipmapping does). The features are unchanged. It prints
eval's PSNR / SSIM per level setting and the quantiles of rho over every visible sample.

    OMP_NUM_THREADS=2 python3 bench/footprint_probe.py --captures mold_gold_cape --views 10 --levels 0,3
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import insertnerf_cli.model.insertnerf as insertnerf_module  # noqa: E402
from insertnerf_cli.evaluate import EvalConfig, run_eval  # noqa: E402
from insertnerf_cli.model import projection  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
RHO_KEPT = 20_000  # samples of rho kept per call for the quantiles
STATE: dict = {"levels": 0, "centre": None, "focal": None, "rho": []}
_original_project = projection.project_samples
_original_render = ViewRenderer.render


def render(self, camera, *args, **kwargs):
    """ViewRenderer.render that first notes the target camera's centre and focal length (pixels)."""
    STATE["centre"], STATE["focal"] = camera.centers[0], float(camera.K[0, 0, 0])
    return _original_render(self, camera, *args, **kwargs)


def reference_focals(proj: torch.Tensor) -> torch.Tensor:
    """[V] fx of each view from K [R | t] [V, 3, 4]: (K R)(K R)^T = K K^T, whose (0, 0) entry is fx^2 + cx^2."""
    kr = proj[:, :, :3]
    kkt = kr @ kr.transpose(1, 2)
    return (kkt[:, 0, 0] - kkt[:, 0, 2] ** 2).clamp(min=1e-12).sqrt()


def footprint_ratio(encoded, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(rho [V, 1, P], uv [V, 2, P]): target pixel size over each reference's at every sample, and its pixel."""
    samples = points.shape[1]
    flat = points.reshape(-1, 3).T  # [3, P]
    proj = encoded.projection.to(points)
    uv, depth = projection.pixel_coordinates(proj, flat)
    d = directions.repeat_interleave(samples, 0)  # [P, 3], camera-z = 1 so t is the target's z-depth
    t = ((flat.T - STATE["centre"].to(points)) * d).sum(-1) / (d * d).sum(-1)  # [P]
    ref_size = depth.clamp(min=1e-6) / reference_focals(proj)[:, None, None]  # [V, 1, P]
    return (t / STATE["focal"])[None, None] / ref_size, uv


def project(encoded, points: torch.Tensor, directions: torch.Tensor):
    seen = _original_project(encoded, points, directions)
    rho, uv = footprint_ratio(encoded, points, directions)
    visible = rho[seen.mask > 0]
    STATE["rho"].append(visible[torch.randperm(len(visible))[:RHO_KEPT]].cpu().numpy())
    levels = STATE["levels"]
    if not levels:
        return seen
    level = torch.log2(rho.clamp(min=1e-6)).clamp(0, levels)  # [V, 1, P]
    pad_h, pad_w = encoded.padded_size
    scale = torch.tensor([2.0 / pad_w, 2.0 / pad_h], dtype=uv.dtype, device=uv.device)[:, None]
    grid = torch.where(seen.mask > 0, uv * scale - 1.0, torch.full_like(uv, 4.0)).transpose(1, 2)[:, None]
    pyramid = [encoded.images]
    for _ in range(levels):
        pyramid.append(F.avg_pool2d(pyramid[-1], 2))  # the padded size is a multiple of 2^levels: same grid
    stack = torch.stack([projection._sample(im, grid) for im in pyramid])  # [L + 1, V, 3, P]
    lo = level.floor().long()
    hi = (lo + 1).clamp(max=levels)
    frac = level - lo

    def at(index: torch.Tensor) -> torch.Tensor:
        return stack.gather(0, index[None].expand(1, -1, 3, -1))[0]

    colours = at(lo) * (1 - frac) + at(hi) * frac
    return projection.Projected(seen.features, colours, seen.mask, seen.ray_diff)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="mold_gold_cape")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", default="10")
    parser.add_argument("--levels", default="0,3", help="pyramid levels to try; 0 = eval as shipped")
    parser.add_argument("--max-views", type=int, default=None)
    args = parser.parse_args()
    insertnerf_module.project_samples = project
    ViewRenderer.render = render
    counts = tuple(int(v) for v in args.views.split(","))
    for capture in args.captures.split(","):
        for levels in (int(v) for v in args.levels.split(",")):
            STATE["levels"], STATE["rho"] = levels, []
            run = run_eval(args.root / capture, EvalConfig(views=counts, max_views=args.max_views))
            rho = np.concatenate(STATE["rho"])
            q = " / ".join(f"{v:.2f}" for v in np.quantile(rho, [0.05, 0.25, 0.5, 0.75, 0.95]))
            scores = " | ".join(f"{r.reference_views} views {r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports)
            print(f"{capture} | levels {levels} | {scores} | rho 5/25/50/75/95 %: {q} "
                  f"| rho > 1: {100 * np.mean(rho > 1):.0f}%", flush=True)


if __name__ == "__main__":
    main()
