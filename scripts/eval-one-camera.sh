#!/usr/bin/env bash
# Keypoints2d sequences seen by one phone camera (configs/rigs/phone-1.json, a rig no training run
# drew): the held-out CMU subject 6 (data/motions/cmu/validation) on six synthetic subjects
# (seeds SEEDS, default 11–16: one β each) at the frame rates FPS (default "30 10"), 100 frames,
# each frame from the previous frame's fit. Fitted by LM with the temporal anchor (`--dofs
# anchored:5[,MM]`) and by the keypoints2d sequence network (`--dofs observed:30+anchored:5[,MM]`)
# with β per frame (`free`), each subject's true height as a soft measurement (`height`,
# `--height-prior truth`) and β given (`known`, `--known-shape truth`), for each translation
# standard deviation of MMS (default "default 30 300": `default` is `anchored:5` as shipped, a
# number N is `anchored:5,N`). SEQUENCE_SHAPE (e.g. joint:64; default the per-frame β of `lfit
# fit`) is passed as `--sequence-shape` to every fit, FLOOR (e.g. contact:truth: the ground plane
# at the median of the truth's lowest sole; round 36) as `--floor`. Prints one Markdown table: mean V2V (mm)
# over the subjects, PA-MPJPE in brackets, how rough the fitted root's track is — the
# root-mean-square of its second difference between consecutive frames, mm per frame² (the
# truth's: 4.8 at 30 fps, 15.8 at 10 — a fixed pull trades V2V against it) — and the summary's
# acceleration error of the joints against the truth's (`mean_accel_error_mm`);
# docs/results/captured-motion.md, round 34.
#
#   scripts/eval-one-camera.sh [OUT]
#
# OUT defaults to target/eval-one-camera. LFIT (default: the release build) is the binary.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-one-camera}"
source scripts/eval-common.sh
eval_binary eval-one-camera
mkdir -p "$OUT"
export RAYON_NUM_THREADS=1
SEEDS="${SEEDS:-11 12 13 14 15 16}"
FPS="${FPS:-30 10}"
MMS="${MMS:-default 30 300}"
SHAPES="${SHAPES:-free height known}"
# Every setting checked before any work: one line and a non-zero exit for a bad one.
for shape in $SHAPES; do
    case "$shape" in
        free | height | known) ;;
        *)
            echo "eval-one-camera: unknown shape '$shape' in SHAPES (free, height or known)" >&2
            exit 1
            ;;
    esac
done
for mm in $MMS; do
    if [ "$mm" != default ] && ! [[ "$mm" =~ ^[0-9]+([.][0-9]+)?$ ]]; then
        echo "eval-one-camera: MMS entry '$mm' is neither 'default' nor a number of millimetres" >&2
        exit 1
    fi
done
for f in $FPS $SEEDS; do
    if ! [[ "$f" =~ ^[0-9]+$ ]]; then
        echo "eval-one-camera: FPS and SEEDS take whole numbers, not '$f'" >&2
        exit 1
    fi
done
for f in $FPS; do
    for s in $SEEDS; do
        data="$OUT/phone-$f-$s.npz"
        [ -f "$data" ] || "$LFIT" -q synth --modality keypoints2d --scenario sequence --frames 100 \
            --fps "$f" --seed "$s" --template "$MODEL" --motions data/motions/cmu/validation/006_*.npz \
            --camera configs/rigs/phone-1.json --out "$data" >/dev/null
    done
done
shape_args() {
    [ -n "${SEQUENCE_SHAPE:-}" ] && echo "--sequence-shape $SEQUENCE_SHAPE"
    [ -n "${FLOOR:-}" ] && echo "--floor $FLOOR"
    case "$1" in
        height) echo "--height-prior truth" ;;
        known) echo "--known-shape truth" ;;
        *) ;; # free (SHAPES is checked above)
    esac
}
mean() { # JSON files...: "V2V (PA-MPJPE) · root acceleration" means
    python3 - "$@" <<'PY'
import json, math, sys
runs = [json.load(open(f)) for f in sys.argv[1:]]
n = len(runs)
v2v = sum(r["summary"]["mean_v2v_mm"] for r in runs) / n
pa = sum(r["summary"]["mean_pa_mpjpe_mm"] for r in runs) / n
def roughness(r):
    # The root translation (the first three entries, metres) of consecutive frames.
    p = [f["pose"][:3] for f in sorted(r["frames"], key=lambda f: f["frame"])]
    acc = [
        sum((1000.0 * (p[k + 1][a] - 2.0 * p[k][a] + p[k - 1][a])) ** 2 for a in range(3))
        for k in range(1, len(p) - 1)
    ]
    return math.sqrt(sum(acc) / len(acc))
rough = sum(roughness(r) for r in runs) / n
accel = sum(r["summary"]["mean_accel_error_mm"] for r in runs) / n
print(f"{v2v:.1f} ({pa:.1f}) · {rough:.1f} · {accel:.1f}")
PY
}
echo "| fps | β | translation σ | LM anchored: V2V (PA-MPJPE) · root acceleration · acceleration error | sequence network: the same |"
echo "|---|---|---|---|---|"
for f in $FPS; do
    for shape in $SHAPES; do
        for mm in $MMS; do
            anchor="anchored:5"
            [ "$mm" != default ] && anchor="anchored:5,$mm"
            lm=()
            net=()
            for s in $SEEDS; do
                data="$OUT/phone-$f-$s.npz"
                stem="$OUT/r-$f-$s-$shape-$mm${SEQUENCE_SHAPE:+-${SEQUENCE_SHAPE/:/}}${FLOOR:+-floor-${FLOOR//[:,]/-}}"
                # shellcheck disable=SC2046
                "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
                    --dofs "$anchor" $(shape_args "$shape") --out "$stem-lm.json" >/dev/null 2>"$stem.err" || { cat "$stem.err" >&2; exit 1; }
                # shellcheck disable=SC2046
                "$LFIT" -q fit --data "$data" --template "$MODEL" --method neural \
                    --checkpoint checkpoints/keypoints2d-makehuman-sequence --neural-start given \
                    --budget 12 --dofs "observed:30+$anchor" $(shape_args "$shape") \
                    --out "$stem-net.json" >/dev/null 2>"$stem.err" || { cat "$stem.err" >&2; exit 1; }
                lm+=("$stem-lm.json")
                net+=("$stem-net.json")
            done
            echo "| $f | $shape | $mm | $(mean "${lm[@]}") | $(mean "${net[@]}") |"
        done
    done
done
