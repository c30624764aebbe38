"""Probe: references much farther than the nearest left out (issue 27, round 21; room's rim views).

Room's 3-to-10 gain is three held-out views inside its grid that gain and three on its rim that lose: a rim
view's nearest references lie to one side and its 7th-10th are two to three times as far as the nearest. Here a
view's references (the capture's rule, as eval picks them) keep only those within F times the nearest one's
distance by that rule, and never fewer than MIN_KEPT; the SfM prior and everything else are render's. A diagnostic
of where the views curve breaks, patched in this process only (ViewRenderer.references).

    OMP_NUM_THREADS=1 python3 bench/near_refs_probe.py --variants off,ratio:2,ratio:3 --captures room --views 3,10
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.views import view_distances  # noqa: E402
from view_set_probe import variants_main  # noqa: E402

MIN_KEPT = 3
SETTINGS = {"ratio": None}
_references = ViewRenderer.references


def references(self: ViewRenderer, target_c2w, exclude: list[int], views: int | None = None) -> list[int]:
    """The capture's references, those beyond ratio x the nearest one's distance dropped (nearest first)."""
    refs = _references(self, target_c2w, exclude, views)
    ratio = SETTINGS["ratio"]
    if ratio is None or len(refs) <= MIN_KEPT:
        return refs
    distance = view_distances(target_c2w, self.scene.cameras.c2w[refs], self.method)
    nearest = float(distance.min())
    return [r for i, r in enumerate(refs) if i < MIN_KEPT or float(distance[i]) <= ratio * nearest]


def set_variant(variant: str) -> None:
    name, _, value = variant.partition(":")
    SETTINGS["ratio"] = float(value) if name == "ratio" else None


def main() -> None:
    def patch() -> None:
        ViewRenderer.references = references

    variants_main(__doc__, "off,ratio:2", set_variant, patch)


if __name__ == "__main__":
    main()
