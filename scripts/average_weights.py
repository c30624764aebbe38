"""Average the weights of generators that share one model config (checkpoint.average_weights, a "model soup").

    python3 scripts/average_weights.py runs/a.pt runs/b.pt --out runs/soup.pt [--shares 0.5,0.5]
"""
import argparse
import sys

from insertnerf_cli.model.checkpoint import average_weights
from insertnerf_cli.errors import UserError

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sources", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--shares", default=None, help="comma-separated, one per source (default: equal)")
    args = parser.parse_args()
    try:
        shares = None if args.shares is None else [float(s) for s in args.shares.split(",")]
        print(f"wrote {average_weights(args.sources, args.out, shares)}")
    except (UserError, ValueError) as err:
        sys.exit(f"error: {err}")
