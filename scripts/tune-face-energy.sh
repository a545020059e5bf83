#!/usr/bin/env bash
# The face energy's regularisation weights (papers/002 eq. 9: w_θ‖θ‖² + w_ψ‖ψ‖² + w_β‖β‖², "tuned
# manually for the best baseline result"): a grid over the three weights, each scored by
# Levenberg–Marquardt's mean whole-head V2V on a validation set (seed 2, apart from the study's
# seed 0), with the data term as eq. 9 has it (plain squared reprojection error, no joint-limit or
# penetration term). Writes docs/results/face/tuning.csv (one row per weight triple) and prints
# the best triple.
#
# Usage: scripts/tune-face-energy.sh [LFIT_BINARY] [FRAMES]
set -euo pipefail
cd "$(dirname "$0")/.."
LFIT=${1:-${CARGO_TARGET_DIR:-target}/release/lfit}
FRAMES=${2:-100}
MODEL=models/makehuman-face.npz
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$LFIT" synth -q --modality landmarks2d --scenario global --source face --frames "$FRAMES" \
  --seed 2 --template "$MODEL" --out "$work/val.npz" > /dev/null
out=docs/results/face/tuning.csv
tmp="$out.tmp"
echo "w_pose,w_expression,w_shape,mean_v2v_head_mm,mean_v2v_face_mm,mean_ldmk_mm,mean_energy" > "$tmp"
for wp in 0 0.001 0.01; do
  for we in 0.0001 0.001 0.01 0.1 1; do
    for wb in 0 0.00001 0.0001 0.001 0.01; do
      cat > "$work/e.json" <<JSON
{"weights": {"data": 1.0, "ep": 0.0, "ea": 0.0, "pose": $wp, "expression": $we, "shape": $wb},
 "robust": {"kind": "l2"}, "angle_prior": "hinge", "silhouettes": false}
JSON
      "$LFIT" fit -q --data "$work/val.npz" --template "$MODEL" --method lm --budget 200 \
        --energy "$work/e.json" --out "$work/fit.json" > /dev/null
      python3 - "$work/fit.json" "$wp" "$we" "$wb" >> "$tmp" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
rows = d["frames"]
m = lambda k: sum(r["face"][k] for r in rows) / len(rows)
e = sum(r["energy"] for r in rows) / len(rows)
print(f"{sys.argv[2]},{sys.argv[3]},{sys.argv[4]},{m('v2v_head_mm'):.3f},{m('v2v_face_mm'):.3f},{m('ldmk_mm'):.3f},{e:.6f}")
PY
    done
  done
done
mv "$tmp" "$out"
sort -t, -k4 -g <(tail -n +2 "$out") | head -3
