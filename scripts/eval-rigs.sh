#!/usr/bin/env bash
# A camera-agnostic keypoints2d fitter on rigs it never saw: 200 frames of the MocapBank clip
# (./scripts/fetch-mocapbank.sh; evaluation only) retargeted onto the MakeHuman body, seen by one
# camera and by three cameras of `lfit synth --cameras N` (the default ring: 4 m around the
# subject, 1.3 m high, 640x480, fx = 550; training draws its rigs at random, so no training rig is
# this one), local scenario, default noise; fitted by the network (from the given start and from
# Φ(D)) and by LM. Prints one Markdown table (V2V, MPJPE, β RMS, evaluations, time per frame).
#
#   scripts/eval-rigs.sh CHECKPOINT [OUT]
#
# CHECKPOINT: a pooled keypoints2d checkpoint (network.views = "pooled"). OUT defaults to
# target/eval-rigs. LFIT (default: the release build) is the binary.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ] || [ $# -gt 2 ]; then
    echo "usage: scripts/eval-rigs.sh CHECKPOINT [OUT]" >&2
    exit 2
fi
CK="$1"
OUT="${2:-target/eval-rigs}"
LFIT="${LFIT:-${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}/release/lfit}"
MODEL=models/makehuman-cmu_mb.npz
FRAMES="${EVAL_FRAMES:-200}"
SEED=9103745171752751104
if [ ! -x "$LFIT" ]; then
    echo "eval-rigs: no lfit binary at $LFIT (cargo build --release --workspace)" >&2
    exit 1
fi
if [ ! -d "$CK" ]; then
    echo "eval-rigs: no checkpoint directory $CK" >&2
    exit 1
fi
mkdir -p "$OUT"
CLIP="$(./scripts/fetch-mocapbank.sh)"
"$LFIT" -q motion import --bvh "$CLIP" --map configs/maps/mocapbank_to_makehuman_cmu_mb.json \
    --model "$MODEL" --out "$OUT/clip-motion.npz" >/dev/null
rows=()
for cams in 1 3; do
    data="$OUT/clip-$cams-cam.npz"
    "$LFIT" -q synth --modality keypoints2d --cameras "$cams" --scenario local --frames "$FRAMES" \
        --seed "$SEED" --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
    "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
        --out "$OUT/$cams-cam-lm.json" >/dev/null
    rows+=("$cams-cam-lm")
    for start in given phi; do
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method neural --checkpoint "$CK" \
            --neural-start "$start" --budget 10 --out "$OUT/$cams-cam-neural-$start.json" >/dev/null
        rows+=("$cams-cam-neural-$start")
    done
done
python3 - "$OUT" "${rows[@]}" <<'PY'
import json, sys
out, names = sys.argv[1], sys.argv[2:]
print("| run | frames | V2V (mm) | MPJPE (mm) | β RMS | evaluations | time / frame (ms) |")
print("|---|---|---|---|---|---|---|")
for n in names:
    r = json.load(open(f"{out}/{n}.json"))
    s, fr = r["summary"], r["frames"]
    ev = sum(f["evaluations"] for f in fr) / len(fr)
    print(f"| {n} | {len(fr)} | {s['mean_v2v_mm']:.1f} | {s['mean_mpjpe_mm']:.1f} | "
          f"{s['mean_shape_rms']:.3f} | {ev:.0f} | {1000 * s['mean_time_s']:.2f} |")
PY
