#!/usr/bin/env bash
# Does the held-out marker error measure accuracy? The check behind eval-real-c3d.sh's held-out
# tables, on a capture with a ground truth: the MocapBank clip's synthetic markers as a sequence
# (default noise, markers on the model's own vertices — where a lab's static calibration would
# put them — and β given by default, as that calibration gives it), fitted by LM, the markers
# network and neural+lm with the markers held out as eval-real-c3d.sh holds them out: five folds
# (marker k in fold k mod 5) and the two Plug-in Gait halves (PIG_HALF_A, PIG_HALF_B:
# eval-common.sh). Prints one Markdown table: per held-out set and method, the error on the
# held-out markers and the V2V against the ground truth — if the first orders the methods as
# the second does, it measures what a real capture cannot otherwise show. Every result is under
# OUT.
#
#   scripts/eval-holdout-clip.sh [OUT]
#
# CHECKPOINT (default checkpoints/markers-makehuman), SEED (0), FRAMES (454, the whole clip),
# SHAPE (`truth`: β given, the default; `free`: each frame's β fitted). LFIT (default: the release
# build) is the binary. The same seed gives the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -gt 1 ]; then
    echo "usage: scripts/eval-holdout-clip.sh [OUT]" >&2
    exit 2
fi
OUT="${1:-target/eval-holdout-clip}"
case "${SHAPE:-truth}" in
    truth) shape=(--known-shape truth) ;;
    free) shape=() ;;
    *)
        echo "eval-holdout-clip: SHAPE must be truth or free, not '${SHAPE}'" >&2
        exit 2
        ;;
esac
source scripts/eval-common.sh
CK="${CHECKPOINT:-checkpoints/markers-makehuman}"
eval_binary eval-holdout-clip
eval_need_dir eval-holdout-clip "$CK"
eval_setup eval-holdout-clip "$OUT"
data="$OUT/clip-sequence.npz"
"$LFIT" -q synth --modality markers --scenario sequence --frames "${FRAMES:-454}" \
    --seed "${SEED:-0}" --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
mapfile -t names < <(eval_marker_names)
sets=()
for ((k = 0; k < 5; k++)); do
    held=()
    for ((i = k; i < ${#names[@]}; i += 5)); do held+=("${names[$i]}"); done
    sets+=("fold$k=$(IFS=,; echo "${held[*]}")")
done
sets+=("halfA=$(IFS=,; echo "${PIG_HALF_A[*]}")" "halfB=$(IFS=,; echo "${PIG_HALF_B[*]}")")
for m in lm neural neural+lm; do
    read -ra args <<< "$(eval_marker_method $m "$CK")"
    for s in "${sets[@]}"; do
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method "${args[@]}" "${shape[@]}" \
            --holdout "${s#*=}" --out "$OUT/${s%%=*}-$m.json" >/dev/null
    done
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
print("| held out, method | held-out marker error (mm) | V2V (mm) | time / frame (ms) |")
print("|---|---|---|---|")
groups = [("five folds", [f"fold{k}" for k in range(5)]), ("half A", ["halfA"]),
          ("half B", ["halfB"]), ("halves A and B", ["halfA", "halfB"])]
for label, runs in groups:
    for m in ["lm", "neural", "neural+lm"]:
        held = seen = v2v = time = frames = 0.0
        for r in runs:
            doc = json.load(open(f"{out}/{r}-{m}.json"))
            for f in doc["frames"]:
                c = f.get("holdout_seen", 0)
                held += c * f.get("holdout_error_mm", 0.0)
                seen += c
                v2v += f["v2v_mm"]
                time += f["time_s"]
                frames += 1
        print(f"| {label}, {m} | {held / seen:.1f} | {v2v / frames:.1f} | {1000 * time / frames:.2f} |")
PY
