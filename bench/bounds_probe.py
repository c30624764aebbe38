"""Probe: eval's default protocol with each held-out view's far bound scaled, and/or the infinity sample switched on
for weights trained without it (issue 27, round 11: does content past a capture's far bound cost the score?).

Inference only, in this process: the renderer's far bound and the loaded model's config are patched; the scene
files and the weights are untouched. Every held-out view, 10 reference views, 256 px, as `insertnerf eval`.

    OMP_NUM_THREADS=2 python3 bench/bounds_probe.py --far-scale 1.5,2 --captures beer
    OMP_NUM_THREADS=2 python3 bench/bounds_probe.py --infinity --captures beer,mold_gold_cape
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import insertnerf_cli.evaluate as evaluate  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def with_infinity() -> None:
    """Patch eval's model loader so every generator it loads renders with the infinity sample on."""
    load = evaluate.load_model

    def load_with_infinity(*a, **k):
        model = load(*a, **k)
        model.config = dataclasses.replace(model.config, infinity_sample=True)
        return model

    evaluate.load_model = load_with_infinity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", default="beer,room,flower,mold_gold_cape")
    parser.add_argument("--far-scale", default="1", help="comma-separated factors for each held-out view's far bound")
    parser.add_argument("--infinity", action="store_true", help="switch the infinity sample on at inference")
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    factor = [1.0]
    render = ViewRenderer.render
    ViewRenderer.render = lambda self, camera, near, far, exclude, views=None: render(
        self, camera, near, far * factor[0], exclude, views)
    if args.infinity:
        with_infinity()
    for scale in (float(f) for f in args.far_scale.split(",")):
        factor[0] = scale
        for capture in args.captures.split(","):
            run = evaluate.run_eval(REALDATA / capture, evaluate.EvalConfig(checkpoint=args.checkpoint))
            report = run.reports[0]
            print(f"far x{scale:g}{' + infinity' if args.infinity else ''} | {capture} | "
                  f"{report.psnr:.2f} / {report.ssim:.3f}", flush=True)


if __name__ == "__main__":
    main()
