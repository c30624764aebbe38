"""Probe: which reference views eval renders a held-out view from, and what the choice costs (issue 27, round 15).

Eval picks the k nearest views by IBRNet's rules (views.view_rule: the angle about the scene centre for
object-centric captures, camera distance for forward-facing ones). This scores other rules on the dev captures,
with ViewRenderer's choice patched in this process only, and prints each held-out view's PSNR (--refs: and its
references), so a view that one reference spoils shows up:

- vector, dist, matrix: views.view_distances's rules;
- cover:L: the 3k nearest by the capture's own rule, re-ranked by (own distance / the k-th's) + L x (share of the
  target's frustum the view does not see: 8 x 8 pixels at 4 depths even in disparity between the bounds);
- mix:L: the vector angle + L x the angle between the optical axes;
- time:W: the capture's own rule among the views at most W places from the target in the capture's file order
  (the order a walk or a turntable took them), filled up by the rest: is a view spoilt by what changed between
  passes (a shadow, a person), i.e. by a scene that is not static? (It reads the held-out view's own place in
  the capture, which a novel view does not have: a diagnostic, not a rule for render.)
- anchor:W: the nearest view by the capture's rule, then the rest among the views at most W places from it in the
  capture's order, filled up by the rest (uses only the references' order, so a novel view could use it too).

    OMP_NUM_THREADS=1 python3 bench/view_set_probe.py --rules vector,dist,cover:3 --captures beer --views 3,10
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.evaluate import EvalConfig, run_eval  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.views import VIEW_METHODS, view_distances  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
GRID, DEPTHS, POOL = 8, 4, 3  # frustum grid per side, depths along each ray, candidates per chosen view for cover
RULE = {"name": "vector", "weight": 0.0}
LIBRARY_RENDER = ViewRenderer.render  # before main() patches it


def unseen_share(renderer: ViewRenderer, camera, near: float, far: float, candidates: list[int]) -> torch.Tensor:
    """[N] share of the target frustum's GRID^2 x DEPTHS points that each candidate view does not see."""
    h, w = camera.height, camera.width
    ys, xs = torch.meshgrid(torch.linspace(0.5, h - 0.5, GRID, dtype=torch.float64),
                            torch.linspace(0.5, w - 0.5, GRID, dtype=torch.float64), indexing="ij")
    uv = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).repeat(DEPTHS, 1)  # [D * G^2, 2]
    depth = (1.0 / torch.linspace(1.0 / near, 1.0 / far, DEPTHS, dtype=torch.float64)).repeat_interleave(GRID ** 2)
    points = camera.to(dtype=torch.float64).unproject(uv[None], depth[None])[0]  # [D * G^2, 3]
    views = renderer.scene.cameras.subset(candidates).rescale(h, w).to(dtype=torch.float64)
    uv_refs, depth_refs = views.project(points)
    return 1.0 - views.in_image(uv_refs, depth_refs).double().mean(-1)


def choose(renderer: ViewRenderer, camera, near: float, far: float, exclude: list[int], k: int) -> list[int]:
    """The k references of ``camera`` under RULE."""
    name, weight = RULE["name"], RULE["weight"]
    c2w = renderer.scene.cameras.c2w
    dist = view_distances(camera.c2w[0], c2w, name if name in VIEW_METHODS else renderer.method)
    if name == "mix":
        dist = dist + weight * view_distances(camera.c2w[0], c2w, "matrix")
    dist[sorted(set(exclude))] = math.inf
    if name in ("time", "anchor"):
        if name == "time":
            centre = int((c2w - camera.c2w[0]).abs().flatten(1).sum(-1).argmin())  # the held-out view itself
        else:
            centre = int(torch.argmin(dist))  # the nearest reference
        places = (torch.arange(len(dist)) - centre).abs()
        dist = dist + 1e6 * (places > weight)  # outside the window: after every view inside it
    order = torch.argsort(dist, stable=True)
    if name != "cover":
        return order[:k].tolist()
    candidates = order[:POOL * k].tolist()
    own = dist[candidates]
    kth = own[min(k, len(own)) - 1].clamp(min=1e-9)  # fewer candidates than k: the farthest one
    score = own / kth + weight * unseen_share(renderer, camera, near, far, candidates)
    return [candidates[i] for i in torch.argsort(score, stable=True)[:k].tolist()]


def render(self: ViewRenderer, camera, near: float, far: float, exclude: list[int], views: int | None = None):
    """ViewRenderer.render with the references chosen by RULE: the library's render (its SfM prior of those
    references, raised far bound and blend at the SfM depth, as eval) with the renderer's choice set to them."""
    refs = choose(self, camera, near, far, exclude, views or self.k)
    self.references = lambda *args, **kwargs: refs  # shadows the method for this one call
    try:
        return LIBRARY_RENDER(self, camera, near, far, exclude, views)
    finally:
        del self.references


def add_eval_arguments(parser: argparse.ArgumentParser) -> None:
    """--captures, --root and --views, as every probe of this kind takes them."""
    parser.add_argument("--captures", default="beer,mold_gold_cape,room,flower")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--views", default="3,10,16")


def print_run(label: str, capture: str, run, per_view: bool, references: bool = False) -> None:
    """One line of PSNR / SSIM per count; with ``per_view`` each held-out view's PSNR (and its references)."""
    print(f"{label} | {capture} | " + " | ".join(f"{r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports), flush=True)
    for report in run.reports if per_view else ():
        cells = " ".join(f"{Path(s.name).stem}:{s.psnr:.2f}" + (f"{list(s.references)}" if references else "")
                         for s in report.views)
        print(f"    {report.reference_views} views: {cells}", flush=True)


def score_variants(args: argparse.Namespace, variants: str, apply, per_view: bool, references: bool = False) -> None:
    """For each comma-separated variant: ``apply(variant)``, then eval every capture and print_run it."""
    counts = tuple(int(v) for v in args.views.split(","))
    for variant in variants.split(","):
        apply(variant)
        for capture in args.captures.split(","):
            print_run(variant, capture, run_eval(args.root / capture, EvalConfig(views=counts)), per_view, references)


def variants_main(description: str, default: str, apply, patch, variants_help: str | None = None) -> None:
    """A probe's command line: --variants (default ``default``), the eval arguments and --per-view; ``patch()``
    installs the probe's patches, then each variant is applied and scored (score_variants)."""
    parser = argparse.ArgumentParser(description=description.splitlines()[0])
    parser.add_argument("--variants", default=default, help=variants_help)
    add_eval_arguments(parser)
    parser.add_argument("--per-view", action="store_true", help="also print each held-out view's PSNR")
    args = parser.parse_args()
    patch()
    score_variants(args, args.variants, apply, args.per_view)


def set_rule(rule: str) -> None:
    name, _, weight = rule.partition(":")
    RULE.update(name=name, weight=float(weight or 0.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rules", default="vector",
                        help="comma-separated: vector, dist, matrix, cover:L, mix:L, time:W, anchor:W")
    add_eval_arguments(parser)
    parser.add_argument("--refs", action="store_true", help="also print each view's references")
    args = parser.parse_args()
    ViewRenderer.render = render
    score_variants(args, args.rules, set_rule, True, args.refs)


if __name__ == "__main__":
    main()
