#!/bin/bash
# Same-run A/B of the training step on this CPU (issue 9): the loop of an older tree, the checkout, and the
# checkout with --compile, 3 rounds in rotating order, each one bench/train_throughput.py process.
#   git worktree add /tmp/before9 388e38f && bench/train_ab.sh /tmp/before9 [python]
set -euo pipefail
BEFORE=${1:?usage: bench/train_ab.sh BEFORE_TREE [PYTHON]}
PY=${2:-python3}
NOW=$(cd "$(dirname "$0")/.." && pwd)
run() {  # label tree [extra args]
  local out
  out=$(cd /tmp && PYTHONPATH=$2 "$PY" "$2/bench/train_throughput.py" --threads 2 --steps 20 --warmup 5 "${@:3}" 2>&1 \
        | grep throughput)
  echo "$(date +%H:%M:%S) load $(cut -d' ' -f1 /proc/loadavg) | $1 | $out"
}
for order in "b n c" "n c b" "c b n"; do
  for v in $order; do
    case $v in
      b) run "before ($(git -C "$BEFORE" rev-parse --short HEAD))" "$BEFORE";;
      n) run "now" "$NOW";;
      c) run "now --compile" "$NOW" --compile;;
    esac
  done
done
