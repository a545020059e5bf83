#!/usr/bin/env bash
# Real markers: a Plug-in Gait capture from a motion-capture lab (a C3D lfit did not write), fitted
# on the MakeHuman body by LM, the shipped markers network and neural+lm, with the markers where
# the model's marker set puts them, with their placement solved over the trial (MoSh's latent
# markers: `--sequence-shape joint:64 --marker-placement solve`) and, given a static trial of the
# same subject, with the placement solved on that trial and reused (`--offsets`), with and
# without that trial's β (`--known-shape`: a lab's static calibration gives both). There is no ground truth: the first table reports the marker error each fit
# leaves, β against the prior's mean and how many β entries sit on the ±3 box; the second the
# error on markers each fit was not given (`--holdout`, FOLDS folds of the marker set, default 5),
# which measures what a fit predicts rather than how closely it follows what it saw; the third
# the same with half the Plug-in Gait markers held out (a sparse set: one marker of each pair);
# the fourth HALVES random such halves, with a paired test against LM. Prints four Markdown tables; every import and
# result is under OUT.
#
#   scripts/eval-real-c3d.sh MOVEMENT.c3d [STATIC.c3d] [OUT]
#
# Without a static trial, give the movement trial twice: the "static" rows then take the placement
# and β solved over that trial with every marker, which tells them where the held-out markers sit
# on the body (not where they are in any frame) — the same for every method (round 20's serve).
#
# Measured on pyCGM's sample trials (MIT; github.com/cadop/pyCGM at 1750a62,
# SampleData/Test_Files/Movement_trial.c3d and Static_trial.c3d; not committed: their capture's
# terms are not stated beyond the repository's licence) and kineticstoolkit's tennis serve
# (Apache-2.0; data/kinematics_tennis_serve.c3d, labels "Derrick:<marker>" through LABEL_MAP):
# docs/results/captured-motion.md, round 20; and kineticstoolkit_extensions' gait and static
# trials (Apache-2.0; kineticstoolkit_extensions/anthropometry/data/{gait,static}.c3d at 1c72fc2,
# Plug-in Gait labels as they are): round 26.
# UP (default z: Vicon's lab frame) and LABEL_MAP (a `lfit data import --label-map` file; default:
# labels equal to the model's Plug-in Gait names) describe the capture; CHECKPOINT (default
# checkpoints/markers-makehuman) is the markers network; METHODS (default "lm neural neural+lm";
# also lm+prior, neural+prior and neural+lm+prior, with POSE_PRIOR: eval-common.sh) the methods;
# LFIT (default: the release build) is the binary. The same files give the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ] || [ $# -gt 3 ]; then
    echo "usage: scripts/eval-real-c3d.sh MOVEMENT.c3d [STATIC.c3d] [OUT]" >&2
    exit 2
fi
MOVE="$1"
STATIC=""
OUT=target/eval-real-c3d
if [ $# -ge 2 ]; then
    case "$2" in
        *.c3d | *.C3D) STATIC="$2"; OUT="${3:-$OUT}" ;;
        *) OUT="$2" ;;
    esac
fi
for f in "$MOVE" ${STATIC:+"$STATIC"}; do
    if [ ! -f "$f" ]; then
        echo "eval-real-c3d: no C3D file $f" >&2
        exit 1
    fi
done
# FOLDS = 2 would hold out the whole right arm and leg in one fold (the model's Plug-in Gait set
# lists left and right markers alternately, and RBAK shifts the parity): at least 3.
if ! [[ "${FOLDS:-5}" =~ ^[0-9]+$ ]] || [ "${FOLDS:-5}" -lt 3 ]; then
    echo "eval-real-c3d: FOLDS must be a whole number of at least 3, not '${FOLDS}'" >&2
    exit 2
fi
if ! [[ "${HALVES:-10}" =~ ^[0-9]+$ ]]; then
    echo "eval-real-c3d: HALVES must be a whole number, not '${HALVES}'" >&2
    exit 2
fi
source scripts/eval-common.sh
eval_binary eval-real-c3d
eval_methods eval-real-c3d
CK="${CHECKPOINT:-checkpoints/markers-makehuman}"
eval_need_dir eval-real-c3d "$CK"
mkdir -p "$OUT"
import=(--model "$MODEL" --up "${UP:-z}")
[ -n "${LABEL_MAP:-}" ] && import+=(--label-map "$LABEL_MAP")
"$LFIT" -q data import --c3d "$MOVE" "${import[@]}" --out "$OUT/movement.npz" >/dev/null
rows=()
solve=(--sequence-shape joint:64 --marker-placement solve)
for m in "${methods[@]}"; do
    read -ra args <<< "$(eval_marker_method $m "$CK")"
    eval_run "model-$m" "$OUT/movement.npz" "${args[@]}"
    eval_run "solved-$m" "$OUT/movement.npz" "${args[@]}" "${solve[@]}"
done
if [ -n "$STATIC" ]; then
    "$LFIT" -q data import --c3d "$STATIC" "${import[@]}" --out "$OUT/static.npz" >/dev/null
    # The static trial's placement (LM, one β over its frames), then each method with it.
    read -ra args <<< "$(eval_marker_method lm "$CK")"
    "$LFIT" -q fit --data "$OUT/static.npz" --template "$MODEL" --method "${args[@]}" "${solve[@]}" \
        --out "$OUT/static-placement.json" >/dev/null
    # And the static trial's β with it, as a lab's static calibration gives both.
    beta="$(python3 -c 'import json, sys; print(",".join(map(str, json.load(open(sys.argv[1]))["summary"]["shape_pass"]["beta"])))' "$OUT/static-placement.json")"
    for m in "${methods[@]}"; do
        read -ra args <<< "$(eval_marker_method $m "$CK")"
        eval_run "static-$m" "$OUT/movement.npz" "${args[@]}" --offsets "$OUT/static-placement.json"
        eval_run "static+beta-$m" "$OUT/movement.npz" "${args[@]}" --offsets "$OUT/static-placement.json" \
            --known-shape="$beta"
    done
fi
eval_table real "$OUT" "${rows[@]}"
# Held-out markers (`lfit fit --holdout`): the marker set in FOLDS folds (marker k in fold
# k mod FOLDS), each fold left out of one fit and scored on it; the mean over every held-out
# marker of every frame. With the markers where the model puts them, and with the static
# trial's placement (every marker's, the held-out ones' too).
folds="${FOLDS:-5}"
mapfile -t names < <(eval_marker_names)
placements=(model)
[ -n "$STATIC" ] && placements+=(static static+beta)
# One held-out fit of the movement trial into OUT/NAME.json:
#   held_fit NAME PLACEMENT METHOD MARKER...   (PLACEMENT: model, static or static+beta)
held_fit() {
    local name="$1" placement="$2" method="$3" extra=() args
    shift 3
    [ "$placement" != model ] && extra=(--offsets "$OUT/static-placement.json")
    [ "$placement" = static+beta ] && extra+=(--known-shape="$beta")
    read -ra args <<< "$(eval_marker_method "$method" "$CK")"
    "$LFIT" -q fit --data "$OUT/movement.npz" --template "$MODEL" --method "${args[@]}" \
        "${extra[@]}" --holdout "$(IFS=,; echo "$*")" --out "$OUT/$name.json" >/dev/null
}
cv=()
for p in "${placements[@]}"; do
    for m in "${methods[@]}"; do
        for ((k = 0; k < folds; k++)); do
            held=()
            for ((i = k; i < ${#names[@]}; i += folds)); do held+=("${names[$i]}"); done
            held_fit "holdout-$p-$m-$k" "$p" "$m" "${held[@]}"
        done
        cv+=("$p-$m")
    done
done
python3 - "$OUT" "$folds" "${cv[@]}" <<'PY'
import json, sys
out, folds, names = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
print()
print("| placement, method | held-out marker error (mm) | fitted marker error (mm) | time / frame (ms) |")
print("|---|---|---|---|")
for n in names:
    held = fitted = seen = 0.0
    times = []
    for k in range(folds):
        r = json.load(open(f"{out}/holdout-{n}-{k}.json"))
        for f in r["frames"]:
            c = f.get("holdout_seen", 0)
            held += c * f.get("holdout_error_mm", 0.0)
            seen += c
        fitted += r["summary"]["mean_observation_error_mm"]
        times.append(1000 * r["summary"]["mean_time_s"])
    print(f"| {n} | {held / seen:.1f} | {fitted / folds:.1f} | {sum(times) / folds:.2f} |")
PY
# Half the Plug-in Gait markers held out (PIG_HALF_A, PIG_HALF_B: eval-common.sh), each half
# out of one fit and scored on it; then HALVES (default 10) random halves, one marker of each
# pair (eval_pig_random_half 1..HALVES), by every method with the static trial's placement and β
# (without a static trial: the model's marker set), and a two-sided Wilcoxon signed-rank test
# of each learned fitter against LM over them (scipy, through scripts/fetch-scipy.sh). The
# halves are draws of one capture's markers, not of subjects: a small p says that a difference
# holds whichever markers a fit sees, not that it holds for other people. Both skipped (said so)
# when the model's marker set does not name every Plug-in Gait marker.
# (A lookup table, not `printf … | grep -q`: under pipefail grep's early exit can fail the
# printf with SIGPIPE on a loaded machine and report a marker the model has as missing.)
declare -A has=()
for n in "${names[@]}"; do has["$n"]=1; done
missing=()
for n in "${PIG_HALF_A[@]}" "${PIG_HALF_B[@]}"; do
    [ -n "${has[$n]:-}" ] || missing+=("$n")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "eval-real-c3d: half-marker tables skipped: the model's marker set lacks ${missing[*]}" >&2
    exit 0
fi
halves=()
for p in "${placements[@]}"; do
    for m in "${methods[@]}"; do
        held_fit "half-$p-$m-a" "$p" "$m" "${PIG_HALF_A[@]}"
        held_fit "half-$p-$m-b" "$p" "$m" "${PIG_HALF_B[@]}"
        halves+=("$p-$m")
    done
done
python3 - "$OUT" "${halves[@]}" <<'PY'
import json, sys
out, names = sys.argv[1], sys.argv[2:]
print()
print("| placement, method | half A held out (mm) | half B held out (mm) | mean (mm) | fitted (mm) | worst held-out markers (mm) | time / frame (ms) |")
print("|---|---|---|---|---|---|---|")
for n in names:
    runs = [json.load(open(f"{out}/half-{n}-{h}.json"))["summary"] for h in "ab"]
    held = [s["mean_holdout_error_mm"] for s in runs]
    fitted = sum(s["mean_observation_error_mm"] for s in runs) / 2
    items = [o for s in runs for o in s["holdout_by_item"] if "mean_error_mm" in o]
    worst = sorted(items, key=lambda o: -o["mean_error_mm"])[:3]
    worst = ", ".join(f'{o["item"]} {o["mean_error_mm"]:.0f}' for o in worst)
    time = sum(1000 * s["mean_time_s"] for s in runs) / 2
    print(f"| {n} | {held[0]:.1f} | {held[1]:.1f} | {sum(held) / 2:.1f} | {fitted:.1f} | {worst} | {time:.2f} |")
PY
halves_n="${HALVES:-10}"
[ "$halves_n" -gt 0 ] || exit 0
setting="${placements[-1]}"
for ((k = 1; k <= halves_n; k++)); do
    held="$(eval_pig_random_half "$k")"
    for m in "${methods[@]}"; do
        held_fit "random-half-$k-$m" "$setting" "$m" "$held"
    done
done
PYTHONPATH="$(./scripts/fetch-scipy.sh)" python3 - "$OUT" "$halves_n" "$setting" "${methods[@]}" <<'PY'
import json, sys
from scipy.stats import wilcoxon
out, n, setting = sys.argv[1], int(sys.argv[2]), sys.argv[3]
err = {m: [json.load(open(f"{out}/random-half-{k}-{m}.json"))["summary"]["mean_holdout_error_mm"]
           for k in range(1, n + 1)] for m in sys.argv[4:]}
print()
print(f"| {setting}, method | {n} random halves held out: mean (mm) | per half (mm) | better than LM | Wilcoxon p against LM |")
print("|---|---|---|---|---|")
for m, e in err.items():
    per = " ".join(f"{x:.1f}" for x in e)
    if m == "lm":
        print(f"| {m} | {sum(e) / n:.1f} | {per} | — | — |")
        continue
    wins = sum(1 for a, b in zip(e, err["lm"]) if a < b)
    p = wilcoxon(e, err["lm"]).pvalue if n > 1 and e != err["lm"] else float("nan")
    print(f"| {m} | {sum(e) / n:.1f} | {per} | {wins}/{n} | {p:.3f} |")
PY
