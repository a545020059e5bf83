#!/usr/bin/env bash
# The shipped MakeHuman fitters stopped early (`lfit fit --neural-iterations K`) against their
# full N = 5 and against LM (and, for markers and keypoints2d, LM and `neural+lm` with the shipped
# CMU pose prior), on three sets per modality: 500 procedural held-out frames, the MocapBank
# clip's 454 frames (./scripts/fetch-mocapbank.sh; an evaluation clip, never training data) and
# the held-out CMU subject 6 (200 frames × seeds 1–3), all in the local scenario (a start near
# the target; β given for hmd). The network runs on lfit's own f32 forward (`--runtime native`),
# one thread, batch 1; the whole grid runs REPS times (default 2) so that each time is read
# twice. Prints one Markdown table per modality (mean V2V / MPJPE in mm, time per frame in ms per
# run; the CMU subject's figures are the means over its three sets) and writes every result under
# OUT (default target/eval-early-exit). MODALITIES and KS pick what runs.
#
#   scripts/eval-early-exit.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-early-exit}"
# The seed of the clip frames in docs/results/learned-vs-classical.md.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-early-exit "$OUT"
export RAYON_NUM_THREADS=1
KS="${KS:-1 2 3 5}"
MODALITIES="${MODALITIES:-markers keypoints2d hmd}"
synth() { # modality name args...
    local m="$1" name="$2"
    shift 2
    "$LFIT" -q synth --modality "$m" --scenario local --template "$MODEL" --out "$OUT/$name-$m.npz" "$@" >/dev/null
}
for m in $MODALITIES; do
    synth "$m" proc --frames 500 --seed "$SEED"
    synth "$m" clip --frames 454 --seed "$SEED" --motions "$OUT/clip-motion.npz"
    for s in 1 2 3; do
        synth "$m" "val$s" --frames 200 --seed "$s" --motions data/motions/cmu/validation/*.npz
    done
done
fit() { # rep modality set name args...
    local rep="$1" m="$2" d="$3" name="$4"
    shift 4
    "$LFIT" -q fit --data "$OUT/$d-$m.npz" --template "$MODEL" --out "$OUT/r$rep-$m-$d-$name.json" "$@" >/dev/null
}
for rep in $(seq "${REPS:-2}"); do
    for m in $MODALITIES; do
        ck="checkpoints/$m-makehuman"
        eval_need_dir eval-early-exit "$ck"
        known=()
        [ "$m" = hmd ] && known=(--known-shape truth)
        prior=()
        [ "$m" != hmd ] && prior=(--energy "configs/pose-prior-cmu-$m.json")
        net=(--checkpoint "$ck" --neural-start given --runtime native "${known[@]}")
        for d in proc clip val1 val2 val3; do
            fit "$rep" "$m" "$d" lm --method lm --budget 4000 "${known[@]}"
            [ "$m" != hmd ] && fit "$rep" "$m" "$d" lmprior --method lm --budget 4000 "${prior[@]}"
            for k in $KS; do
                fit "$rep" "$m" "$d" "nn$k" --method neural --budget 100 --neural-iterations "$k" "${net[@]}"
                fit "$rep" "$m" "$d" "nlm$k" --method neural+lm --budget 4000 --neural-iterations "$k" "${net[@]}"
                if [ "$m" != hmd ]; then
                    fit "$rep" "$m" "$d" "nlmprior$k" --method neural+lm --budget 4000 --neural-iterations "$k" "${net[@]}" "${prior[@]}"
                fi
            done
        done
    done
done
python3 - "$OUT" "${REPS:-2}" "$KS" $MODALITIES <<'PY'
import json, os, sys
out, reps, ks, modalities = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(), sys.argv[4:]
sets = {"procedural (500)": ["proc"], "clip (454)": ["clip"], "CMU subject 6 (3 × 200)": ["val1", "val2", "val3"]}

def cell(m, names, meth):
    v2v, mpjpe, times = [], [], [[] for _ in range(reps)]
    for d in names:
        for rep in range(reps):
            f = f"{out}/r{rep + 1}-{m}-{d}-{meth}.json"
            if not os.path.exists(f):
                return ""
            s = json.load(open(f))["summary"]
            times[rep].append(s["mean_time_s"] * 1e3)
            if rep == 0:
                v2v.append(s["mean_v2v_mm"])
                mpjpe.append(s["mean_mpjpe_mm"])
    mean = lambda x: sum(x) / len(x)
    return f"{mean(v2v):.1f} / {mean(mpjpe):.1f} · " + " / ".join(f"{mean(t):.2f}" for t in times)

rows = [("lm", "LM"), ("lmprior", "LM + pose prior")]
rows += [(f"nn{k}", f"neural, K = {k}") for k in ks]
rows += [(f"nlm{k}", f"neural+lm, K = {k}") for k in ks]
rows += [(f"nlmprior{k}", f"neural+lm + pose prior, K = {k}") for k in ks]
for m in modalities:
    print(f"\n{m}:\n")
    print("| method | " + " | ".join(f"{s}: V2V / MPJPE · ms" for s in sets) + " |")
    print("|---|" + "---|" * len(sets))
    for meth, label in rows:
        cells = [cell(m, names, meth) for names in sets.values()]
        if any(cells):
            print(f"| {label} | " + " | ".join(cells) + " |")
PY
