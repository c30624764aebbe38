"""Throughput of `insertnerf synth`: views per second, and the wall time of a 1,000 x 50-view dataset.

Renders a small dataset ``--repeats`` times into temporary folders through the library call behind the
command (parallel workers, PNG writing included) and prints, per repeat and as the median:
  * wall views/s (what a user sees; depends on what else runs on the machine),
  * CPU seconds per view summed over the workers (independent of other load),
together with the load average before and after, so figures from a shared machine can be judged.

    python3 bench/synth_speed.py --scenes 8 --views 50 --resolution 200 --workers 2 --square
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

from insertnerf_cli.synth import GENERATOR_VERSION, CaptureOptions, SynthOptions, build_dataset


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def measure(options: SynthOptions, workers: int) -> tuple[float, float]:
    """(wall views per second, CPU seconds per view) of one fresh dataset."""
    with tempfile.TemporaryDirectory() as tmp:
        cpu, start = _cpu_seconds(), time.perf_counter()
        build_dataset(Path(tmp) / "data", options, workers=workers, progress=False)
        wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu
    views = options.scenes * options.views
    return views / wall, cpu / views


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--views", type=int, default=50)
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--layout", default="mixed", choices=["object", "forward", "360", "handheld", "mixed"])
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--square", action="store_true", help="square images (200x200 at --resolution 200)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--photo", action="store_true", help="with the --photo capture effects")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    aspects = (1.0,) if args.square else SynthOptions().aspects
    print(f"generator {GENERATOR_VERSION}, cores: {os.cpu_count()}, workers: {args.workers}, "
          f"load average before: {os.getloadavg()[0]:.2f}")
    rates, cpus = [], []
    for r in range(args.repeats):
        # Another seed per repeat: the median is over different scenes, not a warm cache of the same ones.
        options = SynthOptions(scenes=args.scenes, views=args.views, test_views=max(1, args.views // 8),
                               resolution=args.resolution, layout=args.layout, seed=args.seed + r, aspects=aspects,
                               capture=CaptureOptions(photo=args.photo))
        rate, cpu = measure(options, args.workers)
        rates.append(rate)
        cpus.append(cpu)
        print(f"repeat {r + 1}: {rate:6.1f} views/s wall, {1000 * cpu:5.1f} CPU ms/view, "
              f"load average now {os.getloadavg()[0]:.2f}")
    rate, cpu = statistics.median(rates), statistics.median(cpus)
    total = 1000 * 50
    print(f"median: {rate:.1f} views/s wall ({args.workers} workers), {1000 * cpu:.1f} CPU ms/view "
          f"(= {args.workers / cpu:.1f} views/s if {args.workers} cores were free)")
    print(f"1,000 scenes x 50 views: {total / rate / 3600:.2f} h at the measured wall rate, "
          f"{total * cpu / args.workers / 3600:.2f} h with {args.workers} free cores")


if __name__ == "__main__":
    main()
