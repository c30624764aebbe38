"""Seeded byte-level fuzz of every scene format `load_scene` reads (issue 29).

    OMP_NUM_THREADS=1 python3 bench/fuzz_scenes.py                  # 200 variants per format
    OMP_NUM_THREADS=1 python3 bench/fuzz_scenes.py --variants 20 --format colmap-bin --verbose

Each format's tiny scene is written once by tests/scene_fixtures.py (the formats' own conventions, pycolmap for
COLMAP, never our readers). Each variant copies it, damages one of its files (the camera files mostly, sometimes
an image) with one seeded mutation (cut short, bits flipped, a run of bytes set to 0xFF like a huge count, zeroed
or inserted), then loads the scene, normalises it and decodes every image, as `render` does before it writes.

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
import shutil
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import numpy as np  # noqa: E402

import scene_fixtures as fixtures  # noqa: E402
from insertnerf_cli.errors import UserError  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402

# Format -> (writer, glob patterns of its camera files, relative to the scene folder).
FORMATS: dict[str, tuple[Callable[[Path], Path], tuple[str, ...]]] = {
    "blender": (lambda r: fixtures.write_blender(r, fixtures.known_scene()), ("transforms_*.json",)),
    "nerfstudio": (lambda r: fixtures.write_nerfstudio(r, fixtures.known_scene()), ("transforms.json",)),
    "llff": (lambda r: fixtures.write_llff(r, fixtures.known_scene()), ("poses_bounds.npy",)),
    "colmap-bin": (lambda r: fixtures.write_colmap(r, fixtures.known_scene()), ("sparse/0/*.bin",)),
    "colmap-text": (lambda r: fixtures.write_colmap(r, fixtures.known_scene(), text=True), ("sparse/0/*.txt",)),
    "dtu-idr": (lambda r: fixtures.write_dtu_idr(r, fixtures.known_scene()), ("cameras.npz",)),
    "dtu-mvsnet": (lambda r: fixtures.write_dtu_mvsnet(r, fixtures.known_scene()), ("Cameras/*.txt",)),
}
BINARY = (".npy", ".npz", ".bin")
ALLOCATION = ("bad_alloc", "MemoryError", "std::", "Cannot allocate")
MUTATIONS = ("truncate", "flip", "ff_run", "zero_run", "insert")
MAX_MESSAGE_CHARS = 400


@dataclass(frozen=True)
class Outcome:
    format: str
    seed: int
    file: str
    mutation: str
    verdict: str  # "loaded", "refused" or "FAIL <class>: <detail>"

    @property
    def failed(self) -> bool:
        return self.verdict.startswith("FAIL")


def mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One seeded mutation of ``data``: (its description, the damaged bytes)."""
    kind = MUTATIONS[int(rng.integers(len(MUTATIONS)))]
    size = len(data)
    at = int(rng.integers(max(size, 1)))
    if kind == "truncate" or size == 0:
        return f"truncate to {at} of {size} bytes", data[:at]
    buf = bytearray(data)
    if kind == "flip":
        flips = int(rng.integers(1, 9))
        for pos in rng.integers(size, size=flips):
            buf[int(pos)] ^= 1 << int(rng.integers(8))
        return f"flip {flips} bits", bytes(buf)
    run = int(rng.integers(1, 9))
    if kind == "insert":
        return f"insert {run} bytes at {at}", bytes(buf[:at]) + rng.bytes(run) + bytes(buf[at:])
    buf[at:at + run] = (b"\xff" if kind == "ff_run" else b"\0") * len(buf[at:at + run])
    return f"{kind} of {run} bytes at {at}", bytes(buf)


def _load_everything(folder: Path) -> None:
    scene = load_scene(folder)
    normalize_scene(scene)
    height, width = scene.size_for(16)
    for index in range(len(scene)):
        scene.load_image(index, height, width)


def _targets(folder: Path, patterns: tuple[str, ...]) -> list[Path]:
    files = sorted({p for pattern in patterns for p in folder.glob(pattern) if p.is_file()})
    images = sorted(p for p in folder.rglob("*.png") if p.is_file())
    return files + images[:1]


def run_variant(name: str, intact: Path, work: Path, seed: int, slow_s: float) -> Outcome:
    """Copy the intact scene to ``work``, damage one file with the mutation of ``seed``, load it, judge it."""
    rng = np.random.default_rng([seed, sum(map(ord, name))])
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(intact, work)
    targets = _targets(work, FORMATS[name][1])
    camera_files = len(targets) - 1
    # Mostly the camera files (what the readers parse), one variant in five an image.
    target = targets[-1] if rng.random() < 0.2 else targets[int(rng.integers(max(camera_files, 1)))]
    original = target.read_bytes()
    what, damaged = mutate(original, rng)
    target.write_bytes(damaged)
    rel = target.relative_to(work).as_posix()
    start = time.monotonic()
    try:
        _load_everything(work)
        verdict = "loaded"
        if target.suffix in BINARY and len(damaged) < len(original):
            verdict = "FAIL accepted cut-short: the damaged file loaded"
    except UserError as err:
        message = str(err)
        verdict = "refused"
        if any(mark in message for mark in ALLOCATION):
            verdict = f"FAIL allocation: {message[:200]}"
        elif "\n" in message or len(message) > MAX_MESSAGE_CHARS:
            verdict = f"FAIL long message: {len(message)} chars, {message[:120]!r}"
    except Exception as err:  # noqa: BLE001 - any other exception is what this bench looks for
        verdict = f"FAIL traceback: {type(err).__name__}: {str(err)[:200]}"
    seconds = time.monotonic() - start
    if seconds > slow_s and not verdict.startswith("FAIL"):
        verdict = f"FAIL slow: {seconds:.1f} s"
    return Outcome(name, seed, rel, what, verdict)


def fuzz(formats: list[str], variants: int, first_seed: int = 0, slow_s: float = 20.0,
         report: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """``variants`` seeded variants of each format; returns every outcome."""
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="insertnerf-fuzz-") as tmp:
        for name in formats:
            intact = FORMATS[name][0](Path(tmp) / f"{name}-intact")
            _load_everything(intact)  # the undamaged scene must load, or the fuzz tests nothing
            for seed in range(first_seed, first_seed + variants):
                outcome = run_variant(name, intact, Path(tmp) / "work", seed, slow_s)
                outcomes.append(outcome)
                if report is not None:
                    report(outcome)
    return outcomes


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
