#!/bin/bash
# Stage v11 on a lent GPU machine (16 cores + one GPU): make fresh pairs on its CPU cores for GEN_S seconds (the
# stipplers' labels re-measured, cd35280), then train from v10's weights on its GPU for TRAIN_TIME. Run from anywhere; OUT receives the log, the last
# checkpoint and the metrics. Env overrides (for a local smoke test): PY GEN_S TRAIN_TIME TRAINER PRECISION EPOCHS
# BATCHES BS NW THREADS N_* (items per folder) W_* (workers per folder).
set -u
ROOT=$(cd "$(dirname "$0")/../.." && pwd); SRC=${SRC:-$ROOT/runs/gpu11/src}  # SRC: a `git archive` snapshot of the code
cd "$SRC"
OUT=${OUT:-/tmp/gpu11out}; mkdir -p "$OUT"
PY=${PY:-python3}; GEN_S=${GEN_S:-170}; TRAIN_TIME=${TRAIN_TIME:-00:00:05:10}
TRAINER=${TRAINER:-gpu}; PRECISION=${PRECISION:-bf16-mixed}; EPOCHS=${EPOCHS:-70}; BATCHES=${BATCHES:-100}
BS=${BS:-32}; NW=${NW:-8}; THREADS=${THREADS:-4}
export PYTHONPATH=$ROOT/.devsite:$SRC OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONUNBUFFERED=1
LOG=$OUT/log.txt; TMPL=/tmp/gpu11logs; mkdir -p $TMPL
say() { echo "[$(date +%T)] $*" >>"$LOG"; }
say "start; code $(cat COMMIT 2>/dev/null); $(nproc --all) cores; $(nvidia-smi -L 2>/dev/null | head -1)"
$PY -c "import torch, lightning, numba, numpy, hydra; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'lightning', lightning.__version__, 'numba', numba.__version__, 'numpy', numpy.__version__)" >>"$LOG" 2>&1
OFF="other_methods.methods.random=0 other_methods.methods.lloyd=0 other_methods.methods.poisson_disk=0 other_methods.methods.jitter=0 other_methods.methods.clusters=0"
gen() {  # gen NAME WORKERS ITEMS SEED settings...
  local name=$1 workers=$2 items=$3 seed=$4; shift 4
  timeout -k 15 "$GEN_S" $PY -m data_gen.pairs dataset=procedural workers=$workers num_items=$items seed=$seed out_dir=data/pairs/$name "$@" >$TMPL/gen_$name.log 2>&1
  say "gen $name rc=$? shards=$(ls data/pairs/$name/pairs-*.npz 2>/dev/null | wc -l)"
}
# gS: v5's recipe (35 % other methods, 25 % light, 3 % empty; synthesised items not lightened) with textures and scales
gen gS ${W_S:-6} ${N_S:-2400} 101 other_methods.share=0.25 sparse.share=0.25 sparse.empty_share=0.03 sparse.lighten_synthesis=false \
  textures.share=0.4 scale.share=0.3 scale.lighten_synthesis=false &
# gE: exact stipplers at the development stipplings' scale (v8's exact-v8 recipe)
gen gE ${W_E:-4} ${N_E:-2400} 102 other_methods.share=1.0 other_methods.methods.random=1.0 other_methods.methods.lloyd=1.0 \
  other_methods.methods.poisson_disk=0.5 other_methods.methods.jitter=0.3 other_methods.methods.clusters=0.2 \
  other_methods.methods.floyd_steinberg=1.0 other_methods.methods.jarvis=0.7 other_methods.methods.floyd_steinberg_jitter=0.5 \
  other_methods.methods.bayer=0.3 other_methods.methods.lloyd_few=0.5 textures.share=0.6 scale.share=0.75 \
  "scale.points_per_ink=[16000,128000]" sparse.share=0.05 sparse.empty_share=0.0 dense.share=0.1 &
# gL: light Poisson (v7b's light-v7b then light2-v7b recipes)
( gen gL ${W_L:-1} ${N_L:-500} 103 other_methods.share=1.0 $OFF other_methods.methods.random=1.0 other_methods.methods.poisson_disk=0.2 \
    sparse.share=1.0 "sparse.scale=[0.1,0.5]" textures.share=0.2
  gen gL2 ${W_L:-1} ${N_L2:-250} 104 other_methods.share=1.0 $OFF other_methods.methods.random=1.0 sparse.share=1.0 \
    "sparse.scale=[0.04,0.15]" textures.share=0.2 ) &
# gT: lattices at random rotations and offsets (v7's recipe, no light items)
gen gT ${W_T:-2} ${N_T:-800} 105 other_methods.share=1.0 $OFF other_methods.methods.lattice_square=1.0 other_methods.methods.lattice_hex=1.0 \
  other_methods.methods.lattice_square_jitter=0.5 other_methods.methods.lattice_hex_jitter=0.5 scale.share=0.6 sparse.share=0.0 \
  dense.share=0.1 textures.share=0.2 &
# gP: Poisson-disk and Lloyd over scales (v7b's blue-v7b recipe)
gen gP ${W_P:-2} ${N_P:-600} 106 other_methods.share=1.0 $OFF other_methods.methods.poisson_disk=1.0 other_methods.methods.lloyd=0.5 \
  scale.share=0.6 "scale.points_per_ink=[1000,64000]" sparse.share=0.1 dense.share=0.1 textures.share=0.2 &
wait
for f in $TMPL/gen_*.log; do echo "== $f" >>"$LOG"; grep -v "it/s\|s/it" "$f" | tail -4 >>"$LOG"; done
$PY - >>"$LOG" 2>&1 <<'PYEOF'
import collections, json, glob, numpy as np
for folder in sorted(glob.glob("data/pairs/g*")):
    methods = collections.Counter()
    for shard in sorted(glob.glob(folder + "/pairs-*.npz")):
        with np.load(shard) as z:
            methods.update(m.get("method", "?") for m in json.loads(str(z["meta_json"]))["items"])
    print(folder, sum(methods.values()), dict(methods.most_common()))
PYEOF
EXTRA=$(for d in gE gL gL2 gT gP; do ls data/pairs/$d/pairs-*.npz >/dev/null 2>&1 && printf "data/pairs/%s," $d; done | sed 's/,$//')
say "training; extra [$EXTRA]"
$PY train.py model=pix2pix_v6 dataset=procedural trainer=$TRAINER trainer.precision=$PRECISION data.generate=false data.crop=null \
  data.baselines=false data.pairs_dir=data/pairs/gS "data.extra_pairs_dirs=[$EXTRA]" data.batch_size=$BS data.num_workers=$NW \
  threads=$THREADS run_dir=/tmp/run11 resume=false init_from=$ROOT/runs/gpu11/v10.ckpt model.lr=${LR:-7e-5} model.lr_decay_epochs=$EPOCHS \
  trainer.max_epochs=$EPOCHS +trainer.limit_train_batches=$BATCHES trainer.check_val_every_n_epoch=10 \
  model.blurred_l1_weight=0.4 model.blurred_l1_sigma_px=4.0 trainer.max_time=$TRAIN_TIME trainer.enable_progress_bar=false \
  >$TMPL/train.log 2>&1
say "train rc=$?"
grep -v "^\s*$" $TMPL/train.log | tail -25 >>"$LOG"
$PY -c "import torch; c = torch.load('/tmp/run11/checkpoints/last.ckpt', map_location='cpu', weights_only=False); torch.save({k: c[k] for k in ('epoch', 'global_step', 'state_dict', 'hparams_name', 'hyper_parameters')}, '$OUT/last_slim.ckpt')" >>"$LOG" 2>&1
cp /tmp/run11/summary.json "$OUT/summary.json" 2>>"$LOG"
cp "$(ls /tmp/run11/logs/version_*/metrics.csv | tail -1)" "$OUT/metrics.csv" 2>>"$LOG"
cp "$(ls /tmp/run11/logs/version_*/samples/*.png | tail -1)" "$OUT/samples.png" 2>>"$LOG"
say "done"
