#!/bin/bash
# Issue 27, rounds 10 and 13 on a lent GPU (one command of < 10 minutes, docs/training-on-gpu.md): a fresh synth-4 +
# synth-5 set like data/trainmix (other seeds), a 4-step CUDA smoke test of both generators while it renders,
# then three runs side by side on the one GPU, warm-started from the bundled generators, each for the minutes
# left before END_AT seconds. The run folders are packed into $OUT.
#   python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
#   bash scripts/gpu_warm_runs.sh cuda auto 1      # DEVICE, TRAIN_MINUTES (auto: until END_AT), SCALE of scene counts
# RAYS=16384 (environment) for 5x the rays per second of the 4,096 that ran (docs/training-on-gpu.md).
# SEED_SHIFT=N adds N to every synth seed (a fresh set); RUN_SPECS="NAME:FAST|FULL:LR:SEED[:SHARE[:guide[:narrow]]] ..."
# picks the runs (SHARE: train through bench/transient_train.py with transients in that share of the source views,
# round 15; guide: train --guide-prior, round 20; narrow: train on the set plus half as many scenes again seen through
# 20-35-degree lenses, `synth --fov 20:35`, around mold_gold_cape's 26.7-degree lens, round 27; its control is the
# same spec without it). Score with bench/fov_probe.py --checkpoint W beside the dev captures.
# FASTPP in place of FAST: the fast generator warm-started into the NeRF++ backbone (examples/fast-nerfpp-model.json,
# issue 63). supports in place of narrow: the mix plus a quarter as many scenes again of 360 orbits around subjects on a
# plinth, pedestal or table (`synth --supports`), the analogue of the captures walked round an object; its control
# is the same spec without it (CPU probe at 45 minutes: docs/research-log.md, The NeRF++ backbone).
# MORE=M (a second call on the still-warm machine): resume every run of the first call for M more minutes, pack again.
# .whl holds trimesh, embreex and pycolmap for the GPU machine's Python (synth needs the first two; the CLI imports
# pycolmap on the way to `train` since finetune's SfM prior, a28cd39; 52 MB of the 64 MiB carry; docs/training-on-gpu.md).
set -u
DEV=${1:-cuda}; MIN=${2:-auto}; SCALE=${3:-1}
OUT=${OUT:-/tmp/gpuout}; mkdir -p "$OUT"
W=/tmp/g27
RUN_SPECS=${RUN_SPECS:-A_fast3e4:FAST:3e-4:0 B_full3e4:FULL:3e-4:0 C_fast1e4:FAST:1e-4:0}
RUNS=$(for r in $RUN_SPECS; do echo -n "${r%%:*} "; done)
case " $RUN_SPECS" in *:narrow\ *|*:narrow) NARROW=1 ;; *) NARROW= ;; esac
case " $RUN_SPECS" in *:supports\ *|*:supports) SUPPORTS=1 ;; *) SUPPORTS= ;; esac
case " $RUN_SPECS" in *:FASTPP:*) SMOKE="FAST FULL FASTPP" ;; *) SMOKE="FAST FULL" ;; esac
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PY:-python3}
ins() { $PY -c "import sys; sys.argv[0] = 'insertnerf'; from insertnerf_cli.cli.main import main; main()" "$@"; }
trainer() {  # `ins train ARGS`, or through the transient probe when run $1 has a share (file $W/$1.share)
  local share; share=$(cat $W/$1.share 2>/dev/null); shift
  if [ -n "$share" ]; then $PY bench/transient_train.py --transient-share $share "$@"; else ins train "$@"; fi; }
T0=$(date +%s); el() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null
$PY -c "import torch, sys; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), sys.version.split()[0])"
pack() { for r in $RUNS; do
  tr '\r' '\n' < $W/$r.log | grep -v '^\s*$' | tail -4
  tar -C $W -czf $OUT/$r.tgz $r/checkpoints/last.pt $r/checkpoints/config.json $r/metrics.jsonl $r/splits.json $r.log
done; ls -la $OUT; el "end"; }
FAST="--init insertnerf_cli/weights/insertnerf-fast.pt --model-config examples/fast-prior-model.json"
FULL="--init insertnerf_cli/weights/insertnerf.pt --model-config examples/full-prior-model.json"
FASTPP="--init insertnerf_cli/weights/insertnerf-fast.pt --model-config examples/fast-nerfpp-model.json"
COMMON="--device $DEV --rays ${RAYS:-4096} --batch-scenes ${BATCH:-8} --data-budget-mb 30000"
if [ -n "${MORE:-}" ]; then  # the first call's runs go on from their last.pt, for MORE minutes more each
  for r in $RUNS; do
    TOTAL=$($PY -c "print(round($(cat $W/$r.minutes) + $MORE, 2))"); echo $TOTAL > $W/$r.minutes
    trainer $r $W/$(cat $W/$r.data 2>/dev/null || echo mix) --out $W/$r --resume --device $DEV --minutes $TOTAL >> $W/$r.log 2>&1 &
  done
  wait; el "resumed runs done"; pack; exit 0
fi
rm -rf $W; mkdir -p $W
n() { $PY -c "print(max(2, round($1 * $SCALE)))"; }
( # data/make27.sh and data/make27s5.sh with other seeds, all seven sets at once
 ins synth $W/s4o --scenes $(n 40) --views 24 --test-views 3 --resolution 200 --layout object --seed $(( 141 + ${SEED_SHIFT:-0} )) --workers 6 > $W/syn1.log 2>&1 &
 ins synth $W/s4r --scenes $(n 50) --views 24 --test-views 3 --resolution 200 --layout 360 --seed $(( 142 + ${SEED_SHIFT:-0} )) --workers 6 --noise --jitter > $W/syn2.log 2>&1 &
 ins synth $W/s4f --scenes $(n 50) --views 24 --test-views 3 --resolution 200 --layout forward --seed $(( 143 + ${SEED_SHIFT:-0} )) --workers 6 --noise --jitter > $W/syn3.log 2>&1 &
 ins synth $W/s5h --scenes $(n 40) --views 30 --test-views 4 --resolution 200 --layout handheld --seed $(( 154 + ${SEED_SHIFT:-0} )) --workers 6 --photo > $W/syn4.log 2>&1 &
 ins synth $W/s5r --scenes $(n 40) --views 24 --test-views 3 --resolution 200 --layout 360 --seed $(( 152 + ${SEED_SHIFT:-0} )) --workers 6 --photo > $W/syn5.log 2>&1 &
 ins synth $W/s5f --scenes $(n 30) --views 24 --test-views 3 --resolution 200 --layout forward --seed $(( 153 + ${SEED_SHIFT:-0} )) --workers 6 --photo > $W/syn6.log 2>&1 &
 ins synth $W/s5o --scenes $(n 30) --views 24 --test-views 3 --resolution 200 --layout object --seed $(( 151 + ${SEED_SHIFT:-0} )) --workers 6 > $W/syn7.log 2>&1 &
 if [ -n "$NARROW" ]; then  # round 27's four long-lens sets (docs/training-on-gpu.md), a third of the mix then
  wait  # after the mix: its seven sets already hold every core
  ins synth $W/n5o --scenes $(n 35) --views 24 --test-views 3 --resolution 200 --fov 20:35 --layout object --seed $(( 271 + ${SEED_SHIFT:-0} )) --workers 4 > $W/syn8.log 2>&1 &
  ins synth $W/n5r --scenes $(n 35) --views 24 --test-views 3 --resolution 200 --fov 20:35 --layout 360 --seed $(( 272 + ${SEED_SHIFT:-0} )) --workers 4 --photo > $W/syn9.log 2>&1 &
  ins synth $W/n5h --scenes $(n 35) --views 30 --test-views 4 --resolution 200 --fov 20:35 --layout handheld --seed $(( 273 + ${SEED_SHIFT:-0} )) --workers 4 --photo > $W/syn10.log 2>&1 &
  ins synth $W/n5f --scenes $(n 35) --views 24 --test-views 3 --resolution 200 --fov 20:35 --layout forward --seed $(( 274 + ${SEED_SHIFT:-0} )) --workers 4 --noise --jitter > $W/syn11.log 2>&1 &
 fi
 if [ -n "$SUPPORTS" ]; then  # orbits around subjects on supports (issue 63), after the mix for the same reason
  wait
  ins synth $W/p5r --scenes $(n 70) --views 24 --test-views 3 --resolution 200 --layout 360 --supports --photo --seed $(( 631 + ${SEED_SHIFT:-0} )) --workers 16 > $W/syn12.log 2>&1
 fi
 wait
) &
SYN=$!
ins synth $W/smoke --scenes 10 --views 12 --test-views 2 --resolution 120 --layout 360 --seed 7 --workers 2 > $W/smoke_syn.log 2>&1 \
  || { el "smoke synth failed"; tail -5 $W/smoke_syn.log; kill $SYN; exit 1; }
for m in $SMOKE; do  # fail fast, with time left to mend and rerun, if the CUDA path breaks
  ins train $W/smoke --out $W/smoke_$m ${!m} $COMMON --guide-prior --seed 0 --batch-scenes 2 --steps 4 --val-every 2 --ckpt-every 2 > $W/smoke_$m.log 2>&1 \
    || { el "smoke $m failed"; tr '\r' '\n' < $W/smoke_$m.log | tail -25; kill $SYN; pkill -f "synth $W"; exit 1; }
  el "smoke $m ok: $(tr '\r' '\n' < $W/smoke_$m.log | grep -v '^\s*$' | tail -1)"
done
wait $SYN; el "synth done: $(cat $W/syn*.log | grep -ci error) error lines"; for f in $W/syn*.log; do tail -1 $f; done
link_sets() {  # link_sets NAME SET...: a folder of links to the scenes of every SET, named SET_scene
  mkdir -p $W/$1; local to=$W/$1; shift
  for d in "$@"; do for s in $d/scene_*; do ln -s $s $to/$(basename $d)_$(basename $s); done; done
  el "$(basename $to): $(ls $to | wc -l) scenes"; }
link_sets mix $W/s4? $W/s5?
if [ -n "$NARROW" ]; then link_sets mixn $W/s4? $W/s5? $W/n5?; fi  # the mix's scenes and the long-lens ones
if [ -n "$SUPPORTS" ]; then link_sets mixs $W/s4? $W/s5? $W/p5r; fi  # the mix's scenes and the orbits on supports
if [ "$MIN" = auto ]; then MIN=$($PY -c "print(round(max(1.0, (${END_AT:-525} - $(( $(date +%s) - T0 )) - 30) / 60), 2))"); fi
el "training minutes: $MIN"
for spec in $RUN_SPECS; do
  IFS=: read -r name model lr seed share guide data <<< "$spec"; echo $MIN > $W/$name.minutes; echo "${share:-}" > $W/$name.share
  case "${data:-}" in narrow) echo mixn ;; supports) echo mixs ;; *) echo mix ;; esac > $W/$name.data
  trainer $name $W/$(cat $W/$name.data) --out $W/$name ${!model} $COMMON ${guide:+--guide-prior} --seed $seed --lr $lr --steps 200000 --minutes $MIN --val-every 100000 --ckpt-every 250 > $W/$name.log 2>&1 &
done
sleep 60; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader 2>/dev/null
for r in $RUNS; do el "$r: $(tr '\r' '\n' < $W/$r.log | grep -v '^\s*$' | tail -1)"; done
wait; el "training done"; pack
