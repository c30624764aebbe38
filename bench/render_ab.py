"""Same-run A/B of `insertnerf render` speed: the code before issue 11 against this tree (issue 11's "must show").

    git worktree add /tmp/before11 c9dffde          # the last commit before the render shortcuts
    python3 bench/render_ab.py --before /tmp/before11 --rounds 3
    python3 bench/render_ab.py --before /tmp/before11 --also stride3=/tmp/stride3   # another tree's defaults too

Each round renders one fresh procedural object scene (made once by `insertnerf synth`) with every variant, in
an order that rotates between rounds so that a drift of the machine's speed hits every variant alike: the code
before, this tree with its defaults (the fast generator since it became the default), this tree with --model full
(the generator that was the default before), and with --exact if --exact-too is given.
Every render is the real command in a child process with the given tree on PYTHONPATH; the figure is the
command's own "s/frame" (frames rendered, start-up and videos excluded) and its peak RSS. Prints the median of
each variant and its speed-up over the code before.
"""
from __future__ import annotations

import argparse
import re
import shutil
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from render_eval import HERE, run  # noqa: E402  (one child-process runner for the render benchmarks)


@dataclass(frozen=True)
class Variant:
    label: str
    tree: Path
    args: tuple[str, ...]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, required=True, help="a checkout of the code before issue 11")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=3, help="frames per render")
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--exact-too", action="store_true", help="also time this tree with --exact")
    parser.add_argument("--also", action="append", default=[], metavar="LABEL=TREE",
                        help="also time the defaults of another checkout (repeatable)")
    parser.add_argument("--seed", type=int, default=900001)
    args = parser.parse_args()

    variants = [Variant("before", args.before, ()), Variant("after", HERE, ()),
                Variant("after --model full", HERE, ("--model", "full"))]
    if args.exact_too:
        variants.append(Variant("after --exact", HERE, ("--exact",)))
    for item in args.also:
        label, _, tree = item.partition("=")
        if not tree or not Path(tree).is_dir():
            parser.error(f"--also wants LABEL=TREE with TREE a checkout, got {item!r}")
        variants.append(Variant(label, Path(tree), ()))
    work = Path(tempfile.mkdtemp(prefix="render_ab_"))
    try:
        scene = work / "data"
        run(["synth", str(scene), "--scenes", "1", "--views", str(args.views + 2), "--resolution",
                   str(args.resolution), "--square", "--layout", "object", "--seed", str(args.seed), "--workers", "1"],
            cwd=work)
        times: dict[str, list[float]] = {v.label: [] for v in variants}
        peaks: dict[str, list[float]] = {v.label: [] for v in variants}
        for r in range(args.rounds):
            order = variants[r % len(variants):] + variants[:r % len(variants)]
            for v in order:
                out = work / f"out_{r}_{len(times[v.label])}_{variants.index(v)}"
                _, peak, stdout = run(["render", str(scene / "scene_00000"), "--out", str(out), "--frames",
                                            str(args.frames), "--resolution", str(args.resolution), "--views",
                                            str(args.views), "--device", args.device, *v.args], v.tree, work)
                per_frame = float(re.search(r"([\d.]+) s/frame", stdout).group(1))
                times[v.label].append(per_frame)
                peaks[v.label].append(peak)
                print(f"round {r + 1}: {v.label}: {per_frame:.2f} s/frame, peak RSS {peak:.0f} MiB", flush=True)
                shutil.rmtree(out)
        base = statistics.median(times["before"])
        print(f"\n{args.resolution}x{args.resolution}, {args.views} views, {args.frames} frames per render, "
              f"{args.rounds} rounds, device {args.device}:")
        for v in variants:
            med = statistics.median(times[v.label])
            print(f"  {v.label:20s} median {med:6.2f} s/frame ({', '.join(f'{t:.2f}' for t in times[v.label])}); "
                  f"{base / med:4.1f}x the code before; peak RSS {max(peaks[v.label]):.0f} MiB")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
