"""`insertnerf eval` scores of the same weights under several settings of render's shortcuts (issue 11).

    python3 bench/shortcut_quality.py ../shared/realdata/beer ../shared/realdata/mold_gold_cape --strides exact,2,3
    python3 bench/shortcut_quality.py ../shared/realdata/beer --strides 3:1,3:2:0.02:0.02
    insertnerf synth /tmp/proc --scenes 6 --views 53 --test-views 3 --resolution 200 --square --layout object \\
        --seed 900001 && python3 bench/shortcut_quality.py /tmp/proc/scene_0000* --strides 2,3

Each scene is scored by the library behind `insertnerf eval` (its default protocol: 10 nearest views, 256 px, every
held-out view) once per entry of --strides: "exact" is `eval --exact`; "C[:F[:RGB[:DEPTH]]]" is the default
shortcuts with the coarse pass on every C-th pixel and, if given, the fine pass first on every F-th pixel, the
pixels between blended where their neighbours agree within RGB (colour, opacity) and DEPTH (fraction of the depth
range). These are not command-line options of insertnerf, so this script sets the default of
`render.Shortcuts` for the duration of each score. Prints one line per score and the means per variant.
"""
from __future__ import annotations

import argparse
import functools
import statistics
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli import render  # noqa: E402
from insertnerf_cli.exporters.records import EvalConfig  # noqa: E402
from insertnerf_cli.pipelines.evaluate import evaluate_scene  # noqa: E402


FIELDS = ("coarse_stride", "fine_stride", "smooth_rgb", "smooth_depth")


@contextmanager
def shortcuts(variant: str) -> Iterator[None]:
    """render.Shortcuts() means the shortcuts of ``variant`` ("C[:F[:RGB[:DEPTH]]]") inside the block."""
    parts = variant.split(":")
    settings = {name: (int if name.endswith("stride") else float)(value) for name, value in zip(FIELDS, parts)}
    original = render.Shortcuts
    render.Shortcuts = functools.partial(original, **settings)
    try:
        yield
    finally:
        render.Shortcuts = original


def score(scene: Path, variant: str, checkpoint: Path | None) -> tuple[float, float]:
    config = EvalConfig(checkpoint=checkpoint, device="cpu", exact=variant == "exact")
    if variant == "exact":
        report = evaluate_scene(scene, config)
    else:
        with shortcuts(variant):
            report = evaluate_scene(scene, config)
    return report.psnr, report.ssim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--strides", default="exact,2,3", help="comma-separated: exact and/or C[:F[:RGB[:DEPTH]]] (see above)")
    parser.add_argument("--checkpoint", type=Path, help="weights (default: the bundled default generator)")
    args = parser.parse_args()
    variants = [v.strip() for v in args.strides.split(",") if v.strip()]
    results: dict[str, list[tuple[float, float]]] = {v: [] for v in variants}
    for scene in args.scenes:
        for variant in variants:
            psnr, ssim = score(scene, variant, args.checkpoint)
            results[variant].append((psnr, ssim))
            print(f"{scene.name}: {variant:>14}  PSNR {psnr:.3f} dB  SSIM {ssim:.4f}", flush=True)
    for variant, rows in results.items():
        print(f"mean over {len(rows)} scenes, {variant:>14}: PSNR {statistics.mean(p for p, _ in rows):.3f} dB  "
              f"SSIM {statistics.mean(s for _, s in rows):.4f}")


if __name__ == "__main__":
    main()
