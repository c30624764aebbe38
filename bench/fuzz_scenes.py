"""Seeded byte-level fuzz of every scene format `load_scene` reads (issue 29).

    OMP_NUM_THREADS=1 python3 bench/fuzz_scenes.py                  # 200 variants per format
    OMP_NUM_THREADS=1 python3 bench/fuzz_scenes.py --variants 20 --format colmap-bin --verbose

The fuzz itself is tests/scene_fuzz.py (tests/test_fuzz_scenes.py runs a few variants of it). Each format's tiny
scene is written once by tests/scene_fixtures.py (the formats' own conventions, pycolmap for COLMAP, never our
readers). Each variant copies it, damages one of its files (the camera files mostly, sometimes an image) with one
seeded mutation (cut short, bits flipped, a run of bytes set to 0xFF like a huge count, zeroed or inserted), then
loads the scene, normalises it and decodes every image, as `render` does before it writes.

A variant passes when it loads or is refused with one line (SceneError/UserError). It fails on any other exception
(a traceback for the user), a multi-line or over-long message, an allocation failure that surfaced as a message
(bad_alloc, MemoryError), a binary file (npy/npz/bin) cut short that loads anyway, more than --slow-s seconds, or
the process's peak memory passing --max-rss-mb. The address space is capped at --address-space-gb so that an
unbounded allocation fails fast instead of swapping the machine. Last line:
`fuzz_scenes: N variants over F formats: loaded L, refused R, failed X (...)`; the exit status is 1 on any failure.
"""
from __future__ import annotations

import argparse
import resource
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the package, and the fuzz the tests run too (scene_fuzz)

from scene_fuzz import FORMATS, Outcome, fuzz  # noqa: E402


def summary(outcomes: list[Outcome], peak_mb: float) -> str:
    verdicts = Counter(o.verdict.split(":")[0] for o in outcomes)
    failed = sum(o.failed for o in outcomes)
    kinds = ", ".join(f"{k.removeprefix('FAIL ')} {n}" for k, n in sorted(verdicts.items()) if k.startswith("FAIL"))
    return (f"fuzz_scenes: {len(outcomes)} variants over {len({o.format for o in outcomes})} formats: loaded "
            f"{verdicts['loaded']}, refused {verdicts['refused']}, failed {failed}{f' ({kinds})' if kinds else ''}; "
            f"peak memory {peak_mb:.0f} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--variants", type=int, default=200, help="seeded variants per format")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--format", action="append", choices=sorted(FORMATS), help="only this format (repeatable)")
    parser.add_argument("--slow-s", type=float, default=20.0, help="a variant slower than this fails")
    parser.add_argument("--max-rss-mb", type=float, default=1024.0, help="peak memory above this fails the run")
    parser.add_argument("--address-space-gb", type=float, default=6.0, help="RLIMIT_AS of this process (0: none)")
    parser.add_argument("--verbose", action="store_true", help="print every variant, not only failures")
    args = parser.parse_args()
    if args.address_space_gb > 0:
        limit = int(args.address_space_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    start = time.monotonic()

    def report(o: Outcome) -> None:
        if args.verbose or o.failed:
            print(f"{o.format:<12} seed {o.seed:<5} {o.file:<28} {o.mutation:<34} {o.verdict}", flush=True)

    outcomes = fuzz(args.format or list(FORMATS), args.variants, args.seed, args.slow_s, report)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for name in args.format or list(FORMATS):
        mine = [o for o in outcomes if o.format == name]
        counts = Counter(o.verdict.split(":")[0] for o in mine)
        print(f"  {name:<12} {len(mine)} variants: " + ", ".join(f"{k} {n}" for k, n in sorted(counts.items())))
    print(f"wall time {time.monotonic() - start:.0f} s")
    line = summary(outcomes, peak_mb)
    memory_failed = peak_mb > args.max_rss_mb
    print(line + (f"; FAIL: peak memory over {args.max_rss_mb:.0f} MB" if memory_failed else ""))
    sys.exit(1 if memory_failed or any(o.failed for o in outcomes) else 0)


if __name__ == "__main__":
    main()
