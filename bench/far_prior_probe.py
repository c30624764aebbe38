"""Probe: eval's default protocol with each frame's far bound raised to cover its SfM depth prior (issue 27,
round 26: a capture's LLFF far bound can stop short of background its references triangulate, and the fine
samples, drawn within [near, far], then cannot reach it), optionally with the infinity sample switched on.

Inference only, in this process: ViewRenderer.render is patched; scene files and weights are untouched. Every
held-out view, 256 px, as `insertnerf eval`. `--margins 0` renders with the far bound as given (round 25);
`--only-past --margins 1.1` (quantile 0.99) is what render and eval now do (depth_prior.covering_far).

    OMP_NUM_THREADS=2 python3 bench/far_prior_probe.py --captures mold_gold_cape --margins 0,1.1 --views 10
    OMP_NUM_THREADS=2 python3 bench/far_prior_probe.py --infinity --margins 1.1
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import insertnerf_cli.evaluate as evaluate  # noqa: E402
from bounds_probe import with_infinity  # noqa: E402
from insertnerf_cli.prior_blend import blend_at_prior  # noqa: E402
from insertnerf_cli.render import render_image  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def covering(bound: float, prior: torch.Tensor | None, margin: float, quantile: float, far: bool,
             only_past: bool = False, trigger: float | None = None) -> float:
    """The far bound raised to ``margin`` x the ``quantile`` of the prior's finite depths, or (``far`` False) the
    near bound lowered to the ``1 - quantile`` / ``margin``; margin 0 or no prior: ``bound`` unchanged.
    ``only_past``: the far bound moves only where the quantile itself lies past it (``trigger``: where that
    quantile of the prior does, e.g. 0.95: at least 5 % of the prior's pixels lie past the bound)."""
    depths = None if prior is None or margin <= 0 else prior[torch.isfinite(prior)]
    if depths is None or depths.numel() == 0:
        return bound
    if far:
        reach = float(depths.quantile(quantile))
        past = reach if trigger is None else float(depths.quantile(trigger))
        return bound if only_past and past <= bound else max(bound, margin * reach)
    return min(bound, float(depths.quantile(1.0 - quantile)) / margin)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer,room,flower,mold_gold_cape",
                        help="dev capture names, or scene folders (a name with a slash)")
    parser.add_argument("--margins", default="0,1.1", help="comma-separated: far >= margin x the prior's quantile")
    parser.add_argument("--quantile", type=float, default=0.99)
    parser.add_argument("--views", default="10")
    parser.add_argument("--infinity", action="store_true", help="switch the infinity sample on at inference")
    parser.add_argument("--near", action="store_true", help="also lower the near bound to cover the prior")
    parser.add_argument("--only-past", action="store_true",
                        help="raise the far bound only where the prior's quantile lies past it")
    parser.add_argument("--trigger", type=float, default=None,
                        help="with --only-past: raise only where this quantile of the prior lies past far")
    parser.add_argument("--far-views", type=int, default=None,
                        help="take the far bound from the prior of the frame's nearest K references only")
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    margin = [0.0]
    raised: list[float] = []

    def render(self, camera, near, far, exclude, views=None):
        refs = self.references(camera.c2w[0], exclude, views)
        prior = self._prior(camera, refs, exclude)
        bounding = prior if args.far_views is None or len(refs) <= args.far_views else \
            self._prior(camera, refs[:args.far_views], exclude)
        wide = covering(far, bounding, margin[0], args.quantile, far=True, only_past=args.only_past,
                        trigger=args.trigger)
        raised.append(wide / far)
        if args.near:
            near = covering(near, prior, margin[0], args.quantile, far=False)
        encoded = self._encoded(refs)
        frame = render_image(self.model, encoded, camera, near, wide, self.chunk, self.shortcuts, prior)
        if prior is not None and self.prior_blend:  # as the library's render: the blend within the bound drawn
            frame = blend_at_prior(frame, encoded, camera, prior, wide)
        return frame, refs

    ViewRenderer.render = render
    if args.infinity:
        with_infinity()
    counts = tuple(int(n) for n in args.views.split(","))
    for m in (float(f) for f in args.margins.split(",")):
        margin[0] = m
        for capture in args.captures.split(","):
            raised.clear()
            config = evaluate.EvalConfig(views=counts if len(counts) > 1 else counts[0], checkpoint=args.checkpoint)
            run = evaluate.run_eval(REALDATA / capture if "/" not in capture else Path(capture), config)
            scores = " / ".join(f"{r.psnr:.2f} ({r.ssim:.3f})" for r in run.reports)
            moved = sum(r > 1.0 for r in raised)
            rule = (f"margin {m:g}{' only past' if args.only_past else ''}"
                    f"{'' if args.trigger is None else f' trigger q{args.trigger:g}'}"
                    f"{' + infinity' if args.infinity else ''}"
                    f"{'' if args.far_views is None else f' far from {args.far_views} views'}")
            print(f"{rule} | {capture} | views {args.views} | "
                  f"{scores} | far raised in {moved}/{len(raised)} renders", flush=True)


if __name__ == "__main__":
    main()
