"""Seeded byte-level damage of every scene format `load_scene` reads (issue 29), for tests/test_fuzz_scenes.py's
short run and bench/fuzz_scenes.py's long one.

Each format's tiny scene is written once by scene_fixtures.py (the formats' own conventions, pycolmap for COLMAP,
never our readers). Each variant copies it, damages one of its files (the camera files mostly, sometimes an image)
with one seeded mutation (cut short, bits flipped, a run of bytes set to 0xFF like a huge count, zeroed or
inserted), then loads the scene, normalises it and decodes every image, as `render` does before it writes. A
variant passes when it loads or is refused with one line (SceneError/UserError); any other exception, a multi-line
or over-long message, an allocation failure that surfaced as a message, a binary file cut short that loads anyway,
or more than ``slow_s`` seconds fails it.
"""
from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

import scene_fixtures as fixtures
from insertnerf_cli.errors import UserError
from insertnerf_cli.scenes import load_scene, normalize_scene

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
    except Exception as err:  # noqa: BLE001 - any other exception is what this fuzz looks for
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
