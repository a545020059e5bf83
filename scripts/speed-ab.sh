#!/bin/bash
# Back-to-back speed of two lfit builds on the same frames: ./scripts/speed-ab.sh BASE_BIN NEW_BIN [OUT]
# (e.g. a build of an older commit and this tree): LM on 500 procedural held-out frames per sparse
# modality, LM and the shipped markers network on the MocapBank clip; one thread,
# alternating, twice; prints time per frame, V2V, energy and evaluations of each.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 2 ] || { echo "usage: scripts/speed-ab.sh BASE_BIN NEW_BIN [OUT]" >&2; exit 1; }
M=models/makehuman-cmu_mb.npz
BASE="$1"; NEW="$2"; O="${3:-target/speed-ab}"; mkdir -p "$O"
SEED=9103745171752751104
for m in markers keypoints2d hmd; do
  [ -f $O/proc-$m.npz ] || "$NEW" -q synth --modality $m --scenario local --frames 500 --seed $SEED --template $M --out $O/proc-$m.npz >/dev/null
done
if [ ! -f $O/clip-motion.npz ]; then
  "$NEW" -q motion import --bvh "$(./scripts/fetch-mocapbank.sh)" --map configs/maps/mocapbank_to_makehuman_cmu_mb.json \
    --model $M --out $O/clip-motion.npz >/dev/null
fi
[ -f $O/clip-markers.npz ] || "$NEW" -q synth --modality markers --scenario local --frames 454 --seed $SEED --template $M --motions $O/clip-motion.npz --out $O/clip-markers.npz >/dev/null
export RAYON_NUM_THREADS=1
for rep in 1 2; do
  for b in base new; do
    bin="$BASE"; [ $b = new ] && bin="$NEW"
    for m in markers keypoints2d hmd; do
      k=(); [ $m = hmd ] && k=(--known-shape truth)
      "$bin" -q fit --data $O/proc-$m.npz --template $M --method lm --budget 4000 "${k[@]}" --out $O/$b-$rep-lm-$m.json >/dev/null
    done
    "$bin" -q fit --data $O/clip-markers.npz --template $M --method neural --checkpoint checkpoints/markers-makehuman --neural-start given --budget 10 --out $O/$b-$rep-nn-clip.json >/dev/null
    "$bin" -q fit --data $O/clip-markers.npz --template $M --method lm --budget 4000 --out $O/$b-$rep-lm-clip.json >/dev/null
  done
done
python3 - "$O" <<'PY'
import json
import sys; O=sys.argv[1]
rows=['lm-markers','lm-keypoints2d','lm-hmd','lm-clip','nn-clip']
print('| run | base ms/frame (rep 1, 2) | new ms/frame (rep 1, 2) | new / base | base V2V | new V2V | base E | new E | base evals | new evals |')
print('|---|---|---|---|---|---|---|---|---|---|')
for r in rows:
    d={}
    for b in ['base','new']:
        for rep in [1,2]:
            j=json.load(open(f'{O}/{b}-{rep}-{r}.json'))
            d[(b,rep)]=j
    t=lambda b: [1000*d[(b,rep)]['summary']['mean_time_s'] for rep in [1,2]]
    s=lambda b,k: d[(b,1)]['summary'][k]
    ev=lambda b: sum(f['evaluations'] for f in d[(b,1)]['frames'])/len(d[(b,1)]['frames'])
    tb,tn=t('base'),t('new')
    print(f"| {r} | {tb[0]:.2f}, {tb[1]:.2f} | {tn[0]:.2f}, {tn[1]:.2f} | {sum(tn)/sum(tb):.3f} | {s('base','mean_v2v_mm'):.2f} | {s('new','mean_v2v_mm'):.2f} | {s('base','mean_energy'):.4f} | {s('new','mean_energy'):.4f} | {ev('base'):.1f} | {ev('new'):.1f} |")
PY
