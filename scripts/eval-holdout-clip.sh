#!/usr/bin/env bash
# Does the held-out marker error measure accuracy? The check behind eval-real-c3d.sh's held-out
# tables, on a capture with a ground truth: the MocapBank clip's synthetic markers as a sequence
# (default noise, markers on the model's own vertices — where a lab's static calibration would
# put them — and β given by default, as that calibration gives it), fitted by LM, the markers
# network and neural+lm with the markers held out as eval-real-c3d.sh holds them out: five folds
# (marker k in fold k mod 5), the two Plug-in Gait halves (PIG_HALF_A, PIG_HALF_B:
# eval-common.sh) and HALVES (default 10) random halves (eval_pig_random_half). Prints per
# held-out set and method the error on the held-out markers and the V2V against the ground truth
# — if the first orders the methods as the second does, it measures what a real capture cannot
# otherwise show — and over the random halves how often each orders a learned fitter ahead of
# LM, how often the two agree, and Wilcoxon signed-rank tests (scipy). Every result is under
# OUT.
#
#   scripts/eval-holdout-clip.sh [OUT]
#
# CHECKPOINT (default checkpoints/markers-makehuman), SEED (0), FRAMES (454, the whole clip), HALVES,
# SHAPE (`truth`: β given, the default; `free`: each frame's β fitted), METHODS (as in
# eval-real-c3d.sh). LFIT (default: the release build) is the binary. The same seed gives the same numbers, but for the times.
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
if ! [[ "${HALVES:-10}" =~ ^[0-9]+$ ]]; then
    echo "eval-holdout-clip: HALVES must be a whole number, not '${HALVES}'" >&2
    exit 2
fi
source scripts/eval-common.sh
CK="${CHECKPOINT:-checkpoints/markers-makehuman}"
eval_binary eval-holdout-clip
eval_methods eval-holdout-clip
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
halves_n="${HALVES:-10}"
for ((k = 1; k <= halves_n; k++)); do
    sets+=("random$k=$(eval_pig_random_half "$k")")
done
for m in "${methods[@]}"; do
    read -ra args <<< "$(eval_marker_method $m "$CK")"
    for s in "${sets[@]}"; do
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method "${args[@]}" "${shape[@]}" \
            --holdout "${s#*=}" --out "$OUT/${s%%=*}-$m.json" >/dev/null
    done
done
PYTHONPATH="$(./scripts/fetch-scipy.sh)" python3 - "$OUT" "$halves_n" "${methods[@]}" <<'PY'
import json, sys
from scipy.stats import wilcoxon
out, n = sys.argv[1], int(sys.argv[2])
methods = sys.argv[3:]

def scores(run, m):
    """Held-out marker error (over every held-out marker of every frame), V2V, time per frame."""
    held = seen = v2v = time = 0.0
    frames = json.load(open(f"{out}/{run}-{m}.json"))["frames"]
    for f in frames:
        c = f.get("holdout_seen", 0)
        held += c * f.get("holdout_error_mm", 0.0)
        seen += c
        v2v += f["v2v_mm"]
        time += f["time_s"]
    return held, seen, v2v / len(frames), 1000 * time / len(frames)

print("| held out, method | held-out marker error (mm) | V2V (mm) | time / frame (ms) |")
print("|---|---|---|---|")
groups = [("five folds", [f"fold{k}" for k in range(5)]), ("half A", ["halfA"]),
          ("half B", ["halfB"]), (f"{n} random halves", [f"random{k}" for k in range(1, n + 1)])]
for label, runs in groups:
    if not runs:
        continue
    for m in methods:
        s = [scores(r, m) for r in runs]
        held = sum(x[0] for x in s) / sum(x[1] for x in s)
        v2v = sum(x[2] for x in s) / len(s)
        time = sum(x[3] for x in s) / len(s)
        print(f"| {label}, {m} | {held:.1f} | {v2v:.1f} | {time:.2f} |")
if n > 1:
    # Per random half, does the held-out error order a learned fitter and LM as V2V does?
    print()
    print(f"| over the {n} random halves | better than LM, held out | better than LM, V2V | the two agree | Wilcoxon p, held out | Wilcoxon p, V2V |")
    print("|---|---|---|---|---|---|")
    base = [scores(f"random{k}", "lm") for k in range(1, n + 1)]
    for m in methods[1:]:
        s = [scores(f"random{k}", m) for k in range(1, n + 1)]
        h = [x[0] / x[1] for x in s]
        hb = [x[0] / x[1] for x in base]
        v, vb = [x[2] for x in s], [x[2] for x in base]
        wins_h = sum(a < b for a, b in zip(h, hb))
        wins_v = sum(a < b for a, b in zip(v, vb))
        agree = sum((a < b) == (c < d) for a, b, c, d in zip(h, hb, v, vb))
        print(f"| {m} | {wins_h}/{n} | {wins_v}/{n} | {agree}/{n} | "
              f"{wilcoxon(h, hb).pvalue:.3f} | {wilcoxon(v, vb).pvalue:.3f} |")
PY
