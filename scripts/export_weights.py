"""Export a training checkpoint as bundled weights (no optimizer or RNG state).

    python3 scripts/export_weights.py runs/hyper/checkpoints/last.pt insertnerf_cli/weights/insertnerf.pt \
        [--sample-views 12] [--colour-prior-views 6]

The two options set inference-only config fields (checkpoint.INFERENCE_FIELDS) in the exported copy.
"""
import argparse

from insertnerf_cli.checkpoint import export_weights

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("destination")
    parser.add_argument("--sample-views", type=int, default=None)
    parser.add_argument("--colour-prior-views", type=int, default=None)
    args = parser.parse_args()
    inference = {name: value for name, value in (("sample_views", args.sample_views),
                                                 ("colour_prior_views", args.colour_prior_views)) if value is not None}
    print(f"wrote {export_weights(args.source, args.destination, **inference)}")
