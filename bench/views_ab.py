"""Side-by-side of generators on the dev captures: eval PSNR / SSIM per reference-view count (issue 27's A/Bs).

Every checkpoint is scored with `insertnerf eval`'s library call (same held-out views, same references per
count, render's shortcuts, 256 px) on each capture, and a table is printed: one row per checkpoint and capture,
one column per count, plus the 10-minus-3 and 16-minus-10 differences.

    OMP_NUM_THREADS=1 python3 bench/views_ab.py runs/a/checkpoints/last.pt runs/b/checkpoints/last.pt \
        --captures beer,room,flower,mold_gold_cape --views 3,10,16 [--max-views 4] [--colour-prior 0,6]

--colour-prior K,...: score each checkpoint once per K with its config's ``colour_prior_views`` set to K (the same
weights; the angular colour prior needs no training), through a copy in a temporary folder.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.checkpoint import bundled_checkpoint, export_weights  # noqa: E402
from insertnerf_cli.exporters.records import EvalConfig  # noqa: E402
from insertnerf_cli.pipelines.evaluate import run_eval  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="*", type=Path, help="default: the bundled fast generator")
    parser.add_argument("--captures", default="beer,room,flower,mold_gold_cape")
    parser.add_argument("--root", type=Path, default=REALDATA, help="folder of the captures")
    parser.add_argument("--views", default="3,10,16")
    parser.add_argument("--max-views", type=int, default=None, help="held-out views per capture (default: all)")
    parser.add_argument("--colour-prior", default=None, help="comma-separated colour_prior_views values to try")
    args = parser.parse_args()
    counts = tuple(int(v) for v in args.views.split(","))
    checkpoints = args.checkpoints or [bundled_checkpoint()]
    if args.colour_prior is not None:
        scratch = tempfile.TemporaryDirectory(prefix="views_ab_")
        priors = [int(k) for k in args.colour_prior.split(",")]
        checkpoints = [with_colour_prior(c, k, Path(scratch.name)) for c in checkpoints for k in priors]
    print("checkpoint | capture | " + " | ".join(f"{k} views" for k in counts) + " | 10-3 | 16-10", flush=True)
    for checkpoint in checkpoints:
        for capture in args.captures.split(","):
            run = run_eval(args.root / capture, EvalConfig(views=counts, checkpoint=checkpoint,
                                                             max_views=args.max_views))
            psnr = {r.reference_views: r.psnr for r in run.reports}
            cells = [f"{r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports]
            gains = [f"{psnr[b] - psnr[a]:+.2f}" if a in psnr and b in psnr else "-" for a, b in ((3, 10), (10, 16))]
            print(f"{checkpoint} | {capture} | " + " | ".join(cells + gains), flush=True)


def with_colour_prior(checkpoint: Path, views: int, folder: Path) -> Path:
    """A copy of ``checkpoint`` in ``folder`` whose config has colour_prior_views = ``views``, named after both."""
    return export_weights(checkpoint, folder / f"{checkpoint.stem}-prior{views}.pt", colour_prior_views=views)


if __name__ == "__main__":
    main()
