#!/bin/bash
# Same-run A/B of the training step on this CPU (issue 9): the loop of an older tree, the checkout, the
# checkout with --compile, and the checkout with --compile as one single-thread DDP process per core under
# torchrun, in float32 and in bf16; 3 rounds in rotating order, each one bench/train_throughput.py launch.
#   git worktree add /tmp/before9 388e38f && bench/train_ab.sh /tmp/before9 [python]
set -euo pipefail
BEFORE=${1:?usage: bench/train_ab.sh BEFORE_TREE [PYTHON]}
PY=${2:-python3}
CORES=$(nproc)
NOW=$(cd "$(dirname "$0")/.." && pwd)
bench() {  # label threads launcher... (ending in a tree's bench/train_throughput.py) [extra args]
  local out
  out=$(cd /tmp && "${@:3}" --threads "$2" --steps 20 --warmup 5 2>&1 | grep throughput)
  echo "$(date +%H:%M:%S) load $(cut -d' ' -f1 /proc/loadavg) | $1 | $out"
}
one() {  # label tree [extra args]: one process with a thread per core
  bench "$1" "$CORES" env PYTHONPATH="$2" "$PY" "$2/bench/train_throughput.py" "${@:3}"
}
ddp() {  # label tree [extra args]: one single-thread DDP process per core
  bench "$1" 1 env PYTHONPATH="$2" OMP_NUM_THREADS=1 "$PY" -m torch.distributed.run --nproc_per_node "$CORES" \
    "$2/bench/train_throughput.py" "${@:3}"
}
for order in "b n c d e" "n c d e b" "c d e b n"; do
  for v in $order; do
    case $v in
      b) one "before ($(git -C "$BEFORE" rev-parse --short HEAD))" "$BEFORE";;
      n) one "now" "$NOW";;
      c) one "now --compile" "$NOW" --compile;;
      d) ddp "now --compile, $CORES DDP processes" "$NOW" --compile;;
      e) ddp "now --compile --precision bf16, $CORES DDP processes" "$NOW" --compile --precision bf16;;
    esac
  done
done
