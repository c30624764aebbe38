"""How far a rendered frame is from the machine's arithmetic limit: FLOPs per frame and achieved FLOP/s.

    python3 bench/render_flops.py                       # the bundled generator, 200x200, 10 views
    python3 bench/render_flops.py --size 800 --device cuda
    python3 bench/render_flops.py --model full

Counts the floating-point operations of ``InsertNeRF.render`` on one chunk of rays with torch's FlopCounterMode
(matrix products and convolutions; element-wise ops are not counted, so the figure is a lower bound), scales it
to a whole frame, times the same chunk (median of --repeats after a warm-up, one CPU thread, as render_image runs
each chunk) and prints the achieved rate next to the peak you pass with --peak-gflops (a core's FP32 FMA peak).
The encoder runs once per set of reference views and is left out: a frame's cost is the per-ray network.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from model_speed import FAR, NEAR, orbit  # noqa: E402

from insertnerf_cli.checkpoint import DEFAULT_MODEL, bundled_checkpoint, load_model  # noqa: E402
from insertnerf_cli.model import SourceViews  # noqa: E402
from insertnerf_cli.rays import rays_for_image  # noqa: E402
from insertnerf_cli.render import PixelGrid, Shortcuts  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, help="generator weights (default: the bundled --model)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help="which bundled generator: fast or full")
    parser.add_argument("--size", type=int, default=200, help="frame side in pixels")
    parser.add_argument("--views", type=int, default=10, help="reference views")
    parser.add_argument("--chunk", type=int, default=128, help="rays per network call")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--fine-fraction", type=float, default=1.0,
                        help="share of the pixels that get their own fine pass: it depends on the picture (render's "
                        "fine grid blends the rest; 0.2-0.4 on the dev scenes, docs/benchmarks.md)")
    parser.add_argument("--peak-gflops", type=float,
                        help="peak FP32 GFLOP/s of one core (CPU) or of the GPU (default: a measured large matmul)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    device = torch.device(args.device)
    model, config = load_model(args.checkpoint or bundled_checkpoint(args.model), device)
    model.eval()
    refs = orbit(args.views, args.size)
    with torch.inference_mode():
        encoded = model.encode(SourceViews(torch.rand(args.views, args.size, args.size, 3), refs).to(device))
        camera = orbit(1, args.size, phase=0.3).to(device)
        rays = rays_for_image(camera, torch.tensor([NEAR], device=device), torch.tensor([FAR], device=device))
        chunk = rays[: args.chunk]
        with FlopCounterMode(display=False) as coarse_counter:
            samples, weights = model.coarse_weights(encoded, chunk)
        with FlopCounterMode(display=False) as fine_counter:
            model.render_fine(encoded, chunk, samples, weights)
        coarse_flops, fine_flops = coarse_counter.get_total_flops(), fine_counter.get_total_flops()
        flops = coarse_flops + fine_flops
        times = []
        for i in range(args.repeats + 2):
            if device.type == "cuda":
                torch.cuda.synchronize()
            start = time.perf_counter()
            model.render(encoded, chunk)
            if device.type == "cuda":
                torch.cuda.synchronize()
            if i >= 2:
                times.append(time.perf_counter() - start)
    seconds = statistics.median(times)
    frame_flops = flops * args.size * args.size / args.chunk
    rate = flops / seconds / 1e9
    print(f"model: {config.samples_coarse}+{config.samples_fine} samples, {args.views} views; chunk {args.chunk} rays")
    print(f"FLOPs: {flops / 1e9:.2f} GFLOP per chunk, {frame_flops / 1e9:.0f} GFLOP per {args.size}x{args.size} "
          f"frame ({flops / args.chunk / 1e6:.1f} MFLOP per ray)")
    grid = len(PixelGrid(args.size, args.size, Shortcuts().coarse_stride, device).index) / args.size ** 2
    per_frame = args.size * args.size / args.chunk / 1e9
    print(f"of which coarse {coarse_flops * per_frame:.0f} and fine {fine_flops * per_frame:.0f} GFLOP; with render's "
          f"default shortcuts (coarse pass on {100 * grid:.0f} % of the pixels, fine pass on "
          f"{100 * args.fine_fraction:.0f} %) {(grid * coarse_flops + args.fine_fraction * fine_flops) * per_frame:.0f} "
          f"GFLOP per frame")
    print(f"achieved: {seconds * 1e3:.1f} ms per chunk = {rate:.1f} GFLOP/s on one thread "
          f"({frame_flops / 1e9 / rate:.1f} thread-seconds per frame)")
    peak = args.peak_gflops or matmul_gflops(device)
    source = "given" if args.peak_gflops else "measured 2048^3 matmul"
    print(f"ceiling ({source}): {peak:.0f} GFLOP/s -> {100 * rate / peak:.0f} % reached; at that rate a frame needs "
          f"{frame_flops / 1e9 / peak:.2f} thread-seconds")


def matmul_gflops(device: torch.device, n: int = 2048, repeats: int = 5) -> float:
    """What one thread (or the GPU) reaches on a large float32 matrix product: a practical ceiling."""
    a, b = torch.rand(n, n, device=device), torch.rand(n, n, device=device)
    times = []
    for i in range(repeats + 1):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        a @ b
        if device.type == "cuda":
            torch.cuda.synchronize()
        if i:
            times.append(time.perf_counter() - start)
    return 2 * n ** 3 / statistics.median(times) / 1e9


if __name__ == "__main__":
    main()
