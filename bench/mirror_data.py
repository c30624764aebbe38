"""`insertnerf synth` with most subjects made of polished metal (issue 27, round 17's probe of reflections).

synth's own recipe makes 20 % of glossy materials metallic and coats a quarter of them as mirrors, so a subject
that mirrors its surroundings like mold_gold_cape's gold is rare. Here a share (default 0.6) of every glossy
material (subjects and clutter; floors and walls stay matte) becomes metallic with a mirror coat of 0.5-0.9 and a
specular lobe of 0.2-0.6 (the draws shift the scene's random stream, so the geometry differs from synth's).
``--share 1`` makes every glossy material metal with a coat of 0.8 and a lobe of 0.4 and draws nothing more: with
the same seed and options its scenes are synth's own (``--share 0``) with only the glossy materials changed, a
twin to compare the generator on (bench/depth_bias.py --versus).

    python3 bench/mirror_data.py data/mirror/obj --scenes 20 --views 24 --layout object --seed 1701
    python3 bench/mirror_data.py data/mirror/hand --scenes 20 --views 30 --layout handheld --seed 1704 --photo
    python3 bench/mirror_data.py D/mirror --share 1 --scenes 3 --views 48 --resolution 256 --layout 360 --seed 4242
    python3 bench/mirror_data.py D/plain --share 0 ...the same options
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from click.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.cli.group import cli  # noqa: E402
from insertnerf_cli.synth import builder, compose, enclosures, world  # noqa: E402

_SYNTH_MATERIAL = world.random_material


def polished(share: float):
    """random_material with ``share`` of the glossy draws turned into mirror-coated metal."""

    def material(rng: np.random.Generator, tile_scale: float = 1.0, glossy: bool = True) -> world.Material:
        drawn = _SYNTH_MATERIAL(rng, tile_scale, glossy)
        if glossy and share >= 1:
            return replace(drawn, metallic=1.0, mirror=0.8, specular=0.4, name=f"{drawn.name}+metalmirror")
        if glossy and rng.random() < share:
            drawn = replace(drawn, metallic=1.0, mirror=float(rng.uniform(0.5, 0.9)),
                            specular=float(rng.uniform(0.2, 0.6)), name=f"{drawn.name}+metalmirror")
        return drawn

    return material


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--share", type=float, default=0.6, help="share of glossy materials made mirror metal")
    parser.add_argument("--scenes", default="20")
    parser.add_argument("--views", default="24")
    parser.add_argument("--layout", default="object")
    parser.add_argument("--seed", default="0")
    parser.add_argument("--resolution", default="200")
    parser.add_argument("--photo", action="store_true")
    args = parser.parse_args()
    if args.share > 0:
        # synth's modules bound the name at import; the worker processes fork with these bindings.
        for module in (world, builder, compose, enclosures):
            module.random_material = polished(args.share)
    result = CliRunner().invoke(cli, ["synth", str(args.out), "--scenes", args.scenes, "--views", args.views,
                                      "--resolution", args.resolution, "--layout", args.layout, "--seed", args.seed,
                                      "--workers", "2", *(["--photo"] if args.photo else [])])
    print(result.output.strip().splitlines()[-1] if result.output.strip() else "", flush=True)
    sys.exit(result.exit_code)


if __name__ == "__main__":
    main()
