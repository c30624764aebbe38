"""Export a training checkpoint as bundled weights (no optimizer or RNG state).

    python3 scripts/export_weights.py runs/hyper/checkpoints/last.pt insertnerf_cli/weights/insertnerf.pt \
        [--sample-views 12] [--colour-prior-views 6] [--consistency-temperature-fine 0.01]

One option per inference-only config field (checkpoint.INFERENCE_FIELDS) sets it in the exported copy.
"""
import argparse

from insertnerf_cli.model.checkpoint import INFERENCE_FIELDS, export_weights
from insertnerf_cli.config import ModelConfig

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("destination")
    defaults = ModelConfig()
    for field in INFERENCE_FIELDS:
        kind = type(getattr(defaults, field))  # int or float, as the config declares it
        parser.add_argument(f"--{field.replace('_', '-')}", dest=field, type=kind, default=None)
    args = parser.parse_args()
    inference = {field: getattr(args, field) for field in INFERENCE_FIELDS if getattr(args, field) is not None}
    print(f"wrote {export_weights(args.source, args.destination, **inference)}")
