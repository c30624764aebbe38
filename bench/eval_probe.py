"""eval on the dev captures with one inference-time change: depth bounds, view choice, weights, sample placement.

Issue 27, rounds 4, 7 and 8 (docs/model-card.md, docs/benchmarks.md): `insertnerf eval`'s library call, with the
normalised scene's per-view near/far bounds scaled, replaced by one pair for all views (as render's orbit and
spiral frames had them), by those of each view's references, or (synth scenes) by LLFF-like ones from the depth
files; or the view-choice rule swapped (views.py: vector, dist, matrix); or the fine pass's compositing weights
raised to a power (renormalised to the same opacity); or the coarse samples even in disparity; or each sample
matched across only its K views nearest in angle; or references ranked by frustum overlap too (round 13). Prints one
line per capture.

    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --far-scale 1.5 --captures beer,mold_gold_cape --max-views 3
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --method matrix --views 3,10,16
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --weight-power 2 --max-views 3
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --depth-bounds --root scratch/syn_obj --captures scene_00000
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --sample-views 12 --max-views 3 --views 10,16
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --prior-rule round19 --views 3,10
    OMP_NUM_THREADS=1 python3 bench/eval_probe.py --reach-px 24 --captures mold_gold_cape,room

--prior-rule round19 makes each frame's SfM depth prior as rounds 19-24 did: from the points that two of every
reference photo (any view eval does not hold out) observe and one of the frame's 10 nearest references does.
Since round 25 the rule is two of the frame's references, one of them among its 10 nearest (depth_prior.view_prior).
It also renders within the view's own far bound, as rounds 19-25 did (round 26 raises it to cover the prior).
--reach-px carries each SfM splat's depth that far (at 256 px; the library's 12) into the pixels around it (round 26).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli import depth_prior, scenes, view_renderer  # noqa: E402
from insertnerf_cli.checkpoint import bundled_checkpoint, export_weights  # noqa: E402
from insertnerf_cli.model import insertnerf  # noqa: E402
from insertnerf_cli.evaluate import EvalConfig, run_eval  # noqa: E402
from insertnerf_cli.scenes.geometry import bounds_from_depths  # noqa: E402
from insertnerf_cli.training.depth import read_scene_depth  # noqa: E402
from insertnerf_cli.views import VIEW_METHODS  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DEPTH_SIDE = 64  # long side at which the depth files are read for --depth-bounds (percentiles need no more)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer,mold_gold_cape,room,flower")
    parser.add_argument("--root", type=Path, default=REALDATA, help="folder of the captures")
    parser.add_argument("--views", default="10", help="reference-view counts, comma-separated")
    parser.add_argument("--max-views", type=int, default=None, help="held-out views per capture (default: all)")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    parser.add_argument("--near-scale", type=float, default=1.0, help="multiply every view's near bound")
    parser.add_argument("--far-scale", type=float, default=1.0, help="multiply every view's far bound")
    parser.add_argument("--global-bounds", action="store_true", help="one pair for all views: min near, max far")
    parser.add_argument("--depth-bounds", action="store_true",
                        help="LLFF-like bounds per view from synth's depth files (0.1 and 99.9 percentiles)")
    parser.add_argument("--reference-bounds", choices=("span", "median"), default=None,
                        help="each view's bounds from its references: span = min near / max far, or their medians")
    parser.add_argument("--method", choices=VIEW_METHODS, default=None, help="view-choice rule for every scene")
    parser.add_argument("--overlap-weight", type=float, default=None,
                        help="rank references by the rule's distance + W * (1 - the share of the target's frustum "
                             "points that land in their image)")
    parser.add_argument("--weight-power", type=float, default=None,
                        help="raise the fine pass's weights to this power (0 = the heaviest sample alone)")
    parser.add_argument("--in-disparity", action="store_true",
                        help="place the coarse samples uniformly in 1/t instead of t (the model trained with t)")
    parser.add_argument("--sample-views", type=int, default=None,
                        help="per sample, aggregate only the K views nearest in angle to the query ray")
    parser.add_argument("--prior-rule", choices=("references", "round19"), default="references",
                        help="which points make a frame's SfM prior: two of its references observe them (shipped), "
                             "or two of any non-held-out photo and one of its references (rounds 19-24)")
    parser.add_argument("--reach-px", type=float, default=None,
                        help="carry each splat's depth this many pixels (at 256 px) into the empty pixels around it")
    args = parser.parse_args()
    checkpoint = args.checkpoint
    if args.reach_px is not None:  # read by depth_prior.prior_depth at each call
        depth_prior.REACH_FRACTION = args.reach_px / 256
    if args.prior_rule == "round19":
        patch_round19_prior()
    if args.sample_views is not None:  # the config's own setting, in a copy: whatever the checkpoint carries
        scratch = tempfile.TemporaryDirectory(prefix="eval_probe_")
        checkpoint = export_weights(checkpoint or bundled_checkpoint(), Path(scratch.name) / "probe.pt",
                                    sample_views=args.sample_views)
    if args.in_disparity:
        patch_in_disparity()
    patch_bounds(args.near_scale, args.far_scale, args.global_bounds, args.depth_bounds)
    if args.method is not None:
        patch_view_rule(args.method)
    if args.overlap_weight is not None:
        patch_overlap_rule(args.overlap_weight)
    if args.reference_bounds is not None:
        patch_reference_bounds(args.reference_bounds)
    if args.weight_power is not None:
        patch_weight_power(args.weight_power)
    counts = tuple(int(v) for v in args.views.split(","))
    for capture in args.captures.split(","):
        run = run_eval(args.root / capture, EvalConfig(views=counts, checkpoint=checkpoint,
                                                         max_views=args.max_views))
        cells = " | ".join(f"{r.reference_views} views {r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports)
        print(f"near x{args.near_scale} far x{args.far_scale} global {args.global_bounds} depth {args.depth_bounds} "
              f"rule {args.method} "
              f"from references {args.reference_bounds} weight power {args.weight_power} "
              f"in disparity {args.in_disparity} sample views {args.sample_views} overlap {args.overlap_weight} "
              f"prior rule {args.prior_rule} reach {args.reach_px} | "
              f"{capture} | {cells}", flush=True)


def patch_bounds(near_scale: float, far_scale: float, global_bounds: bool, depth_bounds: bool) -> None:
    """Make normalize_scene (which run_eval imports when it runs) return the scene with changed bounds."""
    normalize = scenes.normalize_scene

    def changed(scene):
        normed, similarity = normalize(scene)
        if depth_bounds:
            normed = with_depth_bounds(normed)
        near, far = normed.near * near_scale, normed.far * far_scale  # [N] each
        if global_bounds:
            near, far = torch.full_like(near, float(near.min())), torch.full_like(far, float(far.max()))
        return dataclasses.replace(normed, near=near, far=far), similarity

    scenes.normalize_scene = changed


def with_depth_bounds(scene):
    """The scene with each view's near/far the POINT_PERCENTILES of its depth file's surface depths (a view
    without depth, or without any surface, keeps its bounds)."""
    height, width = scene.size_for(DEPTH_SIDE)
    depths = [read_scene_depth(scene, i, height, width) for i in range(len(scene))]  # [H, W] each, or None
    near, far = bounds_from_depths([torch.empty(0) if d is None else torch.from_numpy(d) for d in depths],
                                   (scene.near, scene.far))
    return dataclasses.replace(scene, near=near, far=far)


def patch_round19_prior() -> None:
    """Make ViewRenderer.render's SfM prior round 19's: the points two of the non-held-out photos observe and one of
    the frame's PRIOR_VIEWS nearest references does."""
    from insertnerf_cli.depth_prior import PRIOR_VIEWS, prior_depth
    from insertnerf_cli.render import render_image

    def render(self, camera, near, far, exclude, views=None):
        refs = self.references(camera.c2w[0], exclude, views)
        prior = None
        if self.sfm_depth and self.scene.points is not None:
            allowed = [i for i in range(len(self.scene)) if i not in set(exclude)]
            seen = self.scene.points.seen_from(allowed, near=refs[:PRIOR_VIEWS])
            prior = prior_depth(seen, camera) if len(seen) else None
        return render_image(self.model, self._encoded(refs), camera, near, far, self.chunk, self.shortcuts,
                            prior), refs

    view_renderer.ViewRenderer.render = render


def patch_view_rule(method: str) -> None:
    """Make every ViewRenderer pick its references by ``method`` (it picks by the scene's layout otherwise)."""
    init = view_renderer.ViewRenderer.__init__

    def with_rule(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.method = method

    view_renderer.ViewRenderer.__init__ = with_rule


OVERLAP_GRID = 8  # target pixels per side whose rays are tested against each reference's image
OVERLAP_DEPTHS = 4  # points per ray, spread in disparity between the view's near and far bounds


def frustum_overlap(camera, near: float, far: float, refs) -> torch.Tensor:
    """[N] share of the target camera's frustum points (a grid of rays, points between near and far) that land
    inside each reference image in front of it."""
    h, w = camera.height, camera.width
    v, u = torch.meshgrid(torch.linspace(0.5, h - 0.5, OVERLAP_GRID, dtype=torch.float64),
                          torch.linspace(0.5, w - 0.5, OVERLAP_GRID, dtype=torch.float64), indexing="ij")
    uv = torch.stack([u, v], -1).reshape(1, -1, 2)  # [1, G*G, 2]
    depths = 1.0 / torch.linspace(1.0 / near, 1.0 / far, OVERLAP_DEPTHS, dtype=torch.float64)  # [D]
    cam = camera.to(dtype=torch.float64)
    points = torch.cat([cam.unproject(uv, torch.full(uv.shape[:2], float(d), dtype=torch.float64))[0]
                        for d in depths])  # [D*G*G, 3]
    return refs.to(dtype=torch.float64).sees(points).double().mean(-1)  # [N]


def patch_overlap_rule(weight: float) -> None:
    """Make ViewRenderer.render pick its references by rule distance + weight * (1 - frustum overlap)."""
    from insertnerf_cli.views import view_distances

    render = view_renderer.ViewRenderer.render

    def by_overlap(self, camera, near, far, exclude, views=None):
        all_cams = self.scene.cameras.rescale(camera.height, camera.width)
        score = view_distances(camera.c2w[0], self.scene.cameras.c2w, self.method) \
            + weight * (1.0 - frustum_overlap(camera, near, far, all_cams))
        score[sorted(set(exclude))] = float("inf")
        chosen = torch.sort(score, stable=True).indices[: views or self.k].tolist()
        self.references = lambda *_args, **_kwargs: chosen
        try:
            return render(self, camera, near, far, exclude, views)
        finally:
            del self.references

    view_renderer.ViewRenderer.render = by_overlap


def patch_reference_bounds(rule: str) -> None:
    """Make ViewRenderer.render take a view's bounds from the references it renders from, not its own."""
    render = view_renderer.ViewRenderer.render

    def from_references(self, camera, near, far, exclude, views=None):
        refs = torch.tensor(self.references(camera.c2w[0], exclude, views))
        ref_near, ref_far = self.scene.near[refs], self.scene.far[refs]  # [k] each
        if rule == "span":
            near, far = float(ref_near.min()), float(ref_far.max())
        else:
            near, far = float(ref_near.median()), float(ref_far.median())
        return render(self, camera, near, far, exclude, views)

    view_renderer.ViewRenderer.render = from_references


def patch_weight_power(power: float) -> None:
    """Make the model's composite (the fine pass at inference) use weights w^power, or the heaviest sample alone
    for power 0, rescaled to the ray's opacity."""
    composite = insertnerf.composite

    def sharper(weights, colour, t, background):
        opacity = weights.sum(dim=-1, keepdim=True)  # [R, 1]
        if power == 0:
            w = torch.zeros_like(weights).scatter_(-1, weights.argmax(dim=-1, keepdim=True), 1.0)
        else:
            w = weights.clamp(min=0.0) ** power  # [R, S]
        return composite(w / w.sum(dim=-1, keepdim=True).clamp(min=1e-12) * opacity, colour, t, background)

    insertnerf.composite = sharper


def patch_in_disparity() -> None:
    """Make the model's coarse samples uniform in disparity whatever its config says."""
    stratified = insertnerf.stratified_samples

    def in_disparity(rays, count, jitter, in_disparity=False):
        return stratified(rays, count, jitter=jitter, in_disparity=True)

    insertnerf.stratified_samples = in_disparity


if __name__ == "__main__":
    main()
