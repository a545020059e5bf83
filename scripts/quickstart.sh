#!/usr/bin/env bash
# The README's main command, until `lfit quickstart` exists: the most complete pipeline so far.
# Exports the procedural template, poses it, and synthesizes a small dataset per modality.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
OUT="${1:-out/quickstart}"
mkdir -p "$OUT"
cargo build --release --bin lfit
LFIT="$CARGO_TARGET_DIR/release/lfit"
"$LFIT" template export --out-dir "$OUT/template"
python3 - "$OUT/walk_pose.json" <<'PY' 2>/dev/null || printf '{"pose": [0,0,0, 0,0.3,0, 0,0,0, 0,0,0, 0,0,0, -0.4,0,0, 0.6,0,0, 0,0,0, 0,0,0, 0.3,0,0, 0.1,0,0, 0,0,0, 0,0,0, 0,0,0.5, 0,0.8,0, 0,0,0, 0,0,-0.3, 0,0,0, 0,0,0]}\n' > "$OUT/walk_pose.json"
import json, sys
pose = [0.0] * 57
pose[4] = 0.3                # root yaw
pose[3 + 3 * 4] = -0.4       # right hip flexion
pose[3 + 3 * 5] = 0.6        # right knee flexion
pose[3 + 3 * 8] = 0.3        # left hip extension
pose[3 + 3 * 9] = 0.1
pose[3 + 3 * 12 + 2] = 0.5   # right shoulder
pose[3 + 3 * 13 + 1] = 0.8   # right elbow
pose[3 + 3 * 15 + 2] = -0.3  # left shoulder
json.dump({"pose": pose}, open(sys.argv[1], "w"))
PY
"$LFIT" template pose --pose "$OUT/walk_pose.json" --out "$OUT/posed.obj" --template "$OUT/template"
for m in markers keypoints2d hmd; do
    "$LFIT" synth --modality "$m" --scenario local --frames 200 --seed 1 --out "$OUT/$m.npz"
done
"$LFIT" synth --modality hmd --scenario sequence --frames 300 --seed 2 --out "$OUT/hmd_sequence.npz"
"$LFIT" synth --modality scan --scenario global --frames 4 --seed 3 --out "$OUT/scan.npz"
echo "wrote $OUT: template/, posed.obj and datasets (open them with numpy.load)"
