"""Milliseconds of one coarse and one fine 128-ray chunk of a bundled generator on one thread (issue 11).

    python3 bench/chunk_timing.py                      # fast generator, 10 reference views
    python3 bench/chunk_timing.py --model full --views 8
    python3 bench/chunk_timing.py & python3 bench/chunk_timing.py   # two at once: do the cores share resources?

The reference images are random (every pixel gets a fine pass), the target is the first camera of an orbit at
200 px; medians of --repeats calls after 5 warm-up calls, under torch.inference_mode as render runs them.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from model_speed import FAR, NEAR, orbit  # noqa: E402

from insertnerf_cli.model.checkpoint import BUNDLED_MODELS, DEFAULT_MODEL, bundled_checkpoint, load_model  # noqa: E402
from insertnerf_cli.model import SourceViews  # noqa: E402
from insertnerf_cli.cameras.rays import rays_for_image  # noqa: E402


def median_ms(work, repeats: int) -> float:
    for _ in range(5):
        work()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=sorted(BUNDLED_MODELS), default=DEFAULT_MODEL)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--size", type=int, default=200)
    parser.add_argument("--chunk", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model, _ = load_model(bundled_checkpoint(args.model), torch.device("cpu"))
    cams = orbit(args.views + 1, args.size)
    views = SourceViews(torch.rand(args.views, args.size, args.size, 3), cams.subset(list(range(1, args.views + 1))))
    with torch.inference_mode():
        encoded = model.encode(views)
        rays = rays_for_image(cams.subset([0]), torch.tensor([NEAR]), torch.tensor([FAR]))
        middle = len(rays) // 2
        chunk = rays[torch.arange(middle, middle + args.chunk)]
        samples, weights = model.coarse_weights(encoded, chunk)
        coarse = median_ms(lambda: model.coarse_weights(encoded, chunk), args.repeats)
        fine = median_ms(lambda: model.render_fine(encoded, chunk, samples, weights), args.repeats)
    print(f"{args.model} generator, {args.views} views, {args.chunk} rays, one thread: coarse chunk {coarse:.1f} ms, "
          f"fine chunk {fine:.1f} ms")


if __name__ == "__main__":
    main()
