"""Probe: reference colours looked up in the photos at F x the frame's size, and references encoded at E x
(issue 27, round 23).

Variants are ``colour:F`` (the U-Net encodes at the frame's size, colours from the photos at up to F x; F = 1 is
eval before round 23, F = 2 eval since) and ``encode:E`` (references loaded, encoded and looked up at E x the frame's
size, the target still rendered at the frame's size). Patched in this process only (ViewRenderer).

    OMP_NUM_THREADS=1 python3 bench/colour_scale_probe.py --variants colour:1,colour:1.5,colour:2 --captures room --views 3,10
    OMP_NUM_THREADS=1 python3 bench/colour_scale_probe.py --variants encode:1.5,encode:2 --captures room,flower --views 3,10
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.view_renderer import ViewRenderer, colour_size  # noqa: E402
from view_set_probe import variants_main  # noqa: E402

SETTINGS = {"colour": 2.0, "encode": 1.0}
_init, _encoded = ViewRenderer.__init__, ViewRenderer._encoded


def init(self: ViewRenderer, *args, **kwargs) -> None:
    _init(self, *args, **kwargs)
    photo = (self.scene.cameras.height, self.scene.cameras.width)
    self.colour_size = colour_size(self.size, photo, SETTINGS["colour"])


def encoded(self: ViewRenderer, refs: list[int]):
    """The references encoded at SETTINGS["encode"] x the frame's size (projection follows the encoded size)."""
    frame = self.size
    self.size = (round(frame[0] * SETTINGS["encode"]), round(frame[1] * SETTINGS["encode"]))
    try:
        return _encoded(self, refs)
    finally:
        self.size = frame


def set_variant(variant: str) -> None:
    name, _, value = variant.partition(":")
    if name not in SETTINGS:
        raise SystemExit(f"unknown variant {variant!r}: colour:F or encode:E")
    SETTINGS.update(colour=float(value) if name == "colour" else 1.0,
                    encode=float(value) if name == "encode" else 1.0)


def main() -> None:
    def patch() -> None:
        ViewRenderer.__init__, ViewRenderer._encoded = init, encoded

    variants_main(__doc__, "colour:1,colour:2", set_variant, patch)


if __name__ == "__main__":
    main()
