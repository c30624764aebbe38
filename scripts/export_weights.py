"""Export a training checkpoint as bundled weights (no optimizer or RNG state).

    python3 scripts/export_weights.py runs/hyper/checkpoints/last.pt insertnerf_cli/weights/insertnerf.pt
"""
import sys

from insertnerf_cli.checkpoint import export_weights

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    print(f"wrote {export_weights(sys.argv[1], sys.argv[2])}")
