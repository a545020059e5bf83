# Shared by the scripts/eval-*.sh scripts (sourced, not run): the lfit
# binary, the MakeHuman model, the MocapBank evaluation clip retargeted onto it, and the Markdown
# tables the scripts print.
#
#   source scripts/eval-common.sh
#   eval_setup NAME OUT          # LFIT, MODEL; OUT created; OUT/clip-motion.npz written
#   eval_binary NAME             # LFIT alone (eval_setup without the clip)
#   eval_ab_args NAME DEFAULT_OUT BASE_BIN NEW_BIN [OUT]  # an A/B script's two binaries: BASE, NEW, OUT, LFIT=NEW
#   eval_need_dir NAME DIR       # exits with a one-line error unless DIR is a directory
#   eval_local_sets OUT [M]      # OUT/clip.npz, OUT/proc.npz: sensor M's local clip and procedural frames
#   eval_run NAME DATA METHOD ARG...  # lfit fit of DATA into OUT/NAME.json; NAME appended to rows
#   eval_native_fit BIN DATA CK BATCH THREADS OUT [ARG...]  # one timed native network fit
#   eval_table fits OUT ROW...   # V2V, MPJPE, PA-MPJPE, β RMS, shape V2V, energy, evaluations, time per frame
#   eval_table c3d OUT ROW...    # share within 5 mm marker RMS, mean/median RMS, evaluations, time
#   eval_table real OUT ROW...   # the same, and mean marker error, β RMS, β entries on the box
#
#   eval_marker_names            # the model's marker names, one per line
#   eval_methods NAME            # the markers methods to run (METHODS) into `methods`, checked
#   eval_marker_method M CK      # `lfit fit` arguments of markers method M on a sequence
#   eval_pig_random_half K       # one marker of each Plug-in Gait pair (the K-th draw, reproducible)
#   PIG_PAIRS, PIG_HALF_A, PIG_HALF_B  # the Plug-in Gait markers by pairs, and two halves (below)
#
# LFIT (default: the release build under CARGO_TARGET_DIR or ~/.cache/lfit-target) is the binary.

MODEL=models/makehuman-cmu_mb.npz

# The Plug-in Gait markers in pairs on one segment each (first/second; an empty side: a marker
# without a partner), the sparse sets of eval-real-c3d.sh and eval-holdout-clip.sh: a fit that
# sees one marker of each pair sees every segment but some hands' and feet's rotations. Half A
# is the second of each pair (the back and upper-arm markers, RBAK), half B the first (the
# fingers).
PIG_PAIRS=(LFHD/LBHD RFHD/RBHD C7/T10 CLAV/STRN LSHO/LUPA RSHO/RUPA LELB/LFRM RELB/RFRM
    LWRA/LWRB RWRA/RWRB LFIN/ RFIN/ /RBAK LASI/LPSI RASI/RPSI LKNE/LTHI RKNE/RTHI LANK/LTIB
    RANK/RTIB LTOE/LHEE RTOE/RHEE)
PIG_HALF_A=()
PIG_HALF_B=()
for pair in "${PIG_PAIRS[@]}"; do
    [ -n "${pair#*/}" ] && PIG_HALF_A+=("${pair#*/}")
    [ -n "${pair%/*}" ] && PIG_HALF_B+=("${pair%/*}")
done
unset pair

# Random half K of the Plug-in Gait pairs, comma-separated: of each pair the side a SHA-256 of
# "K:pair" picks (the same half for the same K on every machine).
eval_pig_random_half() {
    python3 - "$1" "${PIG_PAIRS[@]}" <<'PY'
import hashlib, sys
k, pairs = sys.argv[1], sys.argv[2:]
held = []
for p in pairs:
    side = hashlib.sha256(f"{k}:{p}".encode()).digest()[0] & 1
    name = p.split("/")[side]
    if name:
        held.append(name)
print(",".join(held))
PY
}

# A markers method's `lfit fit` arguments on a sequence, from the better of the previous result
# and Φ(D) per frame for the learned fitters: eval_marker_method lm|neural|neural+lm CHECKPOINT.
# lm+prior, neural+prior and neural+lm+prior are LM, the network and neural+lm with POSE_PRIOR's
# energy (an `lfit motion prior` file; a path without spaces; a network trained on that energy
# needs it). neural-nK and neural+lm-nK (K = 1 … 9) stop the network after its first K
# iterations (`--neural-iterations K`, both starts still fitted); neural-best fits once per
# frame, from the better start by energy (`--neural-start best`); neural-tolT stops each frame's
# network by the energy rule (`--neural-tolerance T`) from that start (the rule serves one fit
# per frame). neural+lm-all is neural+lm whose LM stage moves every entry freely (`--dofs all`);
# neural+lm-anchored moves every entry with the rotations and the root translation pulled
# toward the network's values (`--dofs anchored`, neural+lm's default on markers, named); lm-anchored is LM pulled the same way
# toward its start (in a sequence the previous frame's result: the control for what the
# network adds as the anchor's centre); lm-anchored:DEG with another σ. neural-sequence is the
# network fine-tuned on the temporal anchor (CHECKPOINT=checkpoints/markers-makehuman-sequence)
# from the previous frame's result, pulled toward it and holding what the markers leave open
# (`--dofs observed:30+anchored:4`, lfit_fitters::sequence_network_dofs).
eval_marker_method() {
    case "$1" in
        *+prior) echo "$(eval_marker_method "${1%+prior}" "$2") --energy $POSE_PRIOR" ;;
        lm) echo lm --budget 4000 ;;
        neural) echo neural --checkpoint "$2" --neural-start both --budget 24 ;;
        neural+lm) echo neural+lm --checkpoint "$2" --neural-start both --budget 4000 ;;
        neural+lm-all) echo "$(eval_marker_method neural+lm "$2") --dofs all" ;;
        neural+lm-anchored) echo "$(eval_marker_method neural+lm "$2") --dofs anchored" ;;
        lm-anchored | lm-anchored:*) echo "$(eval_marker_method lm "$2") --dofs anchored${1#lm-anchored}" ;;
        neural-n[1-9] | neural+lm-n[1-9])
            echo "$(eval_marker_method "${1%-n*}" "$2") --neural-iterations ${1##*-n}" ;;
        neural-best) echo neural --checkpoint "$2" --neural-start best --budget 24 ;;
        neural-sequence) echo neural --checkpoint "$2" --neural-start given --budget 24 --dofs observed:30+anchored:4 ;;
        neural-tol*)
            echo neural --checkpoint "$2" --neural-start best --neural-tolerance "${1#neural-tol}" --budget 24 ;;
    esac
}

# METHODS (default "lm neural neural+lm"; LM first: the tests compare against it) into the
# array `methods`: eval_methods SCRIPT-NAME.
eval_methods() {
    read -ra methods <<< "${METHODS:-lm neural neural+lm}"
    if [ "${methods[0]:-}" != lm ]; then
        echo "$1: METHODS must start with lm (the others are compared with it), not '${METHODS}'" >&2
        exit 2
    fi
    local m
    for m in "${methods[@]}"; do
        case "$m" in
            lm | lm-anchored | lm-anchored:[0-9]* | neural | neural+lm | neural+lm-all | neural+lm-anchored | neural-n[1-9] | neural+lm-n[1-9] | neural-best | neural-sequence) ;;
            neural-tol0.[0-9]*) ;;
            lm+prior | neural+prior | neural+lm+prior)
                if [ -z "${POSE_PRIOR:-}" ] || [ ! -f "$POSE_PRIOR" ] || [[ "$POSE_PRIOR" == *" "* ]]; then
                    echo "$1: $m needs POSE_PRIOR, an energy file of \`lfit motion prior\` (a path without spaces), not '${POSE_PRIOR:-}'" >&2
                    exit 2
                fi
                ;;
            *)
                echo "$1: unknown method '$m' in METHODS (lm, lm-anchored[:DEG], neural, neural+lm, neural+lm-all, neural+lm-anchored, lm+prior, neural+prior, neural+lm+prior, neural-nK, neural+lm-nK, neural-best, neural-tolT, neural-sequence)" >&2
                exit 2
                ;;
        esac
    done
}

eval_marker_names() {
    "$LFIT" model info --model "$MODEL" | python3 -c '
import json, sys
for m in json.load(sys.stdin)["markers"]:
    print(m["name"])'
}

eval_binary() {
    LFIT="${LFIT:-${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}/release/lfit}"
    if [ ! -x "$LFIT" ]; then
        echo "$1: no lfit binary at $LFIT (cargo build --release --workspace)" >&2
        exit 1
    fi
}

eval_ab_args() {
    local name="$1" default_out="$2"
    shift 2
    if [ $# -lt 2 ] || [ $# -gt 3 ]; then
        echo "usage: scripts/$name.sh BASE_BIN NEW_BIN [OUT]" >&2
        exit 2
    fi
    BASE="$1"
    NEW="$2"
    OUT="${3:-$default_out}"
    for b in "$BASE" "$NEW"; do
        [ -x "$b" ] || { echo "$name: no lfit binary at $b" >&2; exit 1; }
    done
    LFIT="$NEW"
}

eval_setup() {
    local name="$1" out="$2"
    eval_binary "$name"
    mkdir -p "$out"
    local clip
    clip="$(./scripts/fetch-mocapbank.sh)"
    "$LFIT" -q motion import --bvh "$clip" --map configs/maps/mocapbank_to_makehuman_cmu_mb.json \
        --model "$MODEL" --out "$out/clip-motion.npz" >/dev/null
}

# The frames of eval-chord.sh, eval-chord-sensors.sh, native-ab.sh and batch-ab.sh in OUT ($1),
# unless there: of sensor $2 (default markers) the clip's 454 local frames (clip.npz, from
# eval_setup's clip-motion.npz) and 500 procedural held-out local frames (proc.npz), both at the
# seed SEED.
eval_local_sets() {
    local m="${2:-markers}"
    [ -f "$1/clip.npz" ] || "$LFIT" -q synth --modality "$m" --scenario local --frames 454 --seed "$SEED" \
        --template "$MODEL" --motions "$1/clip-motion.npz" --out "$1/clip.npz" >/dev/null
    [ -f "$1/proc.npz" ] || "$LFIT" -q synth --modality "$m" --scenario local --frames 500 --seed "$SEED" \
        --template "$MODEL" --out "$1/proc.npz" >/dev/null
}

eval_run() {
    local name="$1" data="$2" method="$3"
    shift 3
    "$LFIT" -q fit --data "$data" --template "$MODEL" --method "$method" --out "$OUT/$name.json" "$@" >/dev/null
    rows+=("$name")
}

eval_need_dir() {
    if [ ! -d "$2" ]; then
        echo "$1: no checkpoint directory $2" >&2
        exit 1
    fi
}

eval_table() {
    python3 - "$@" <<'PY'
import json, statistics, sys
kind, out, names = sys.argv[1], sys.argv[2], sys.argv[3:]
if kind == "fits":
    print("| run | frames | V2V (mm) | MPJPE (mm) | PA-MPJPE (mm) | β RMS | shape V2V (mm) | energy | evaluations | time / frame (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
elif kind == "c3d":
    print("| source, method | frames | within 5 mm RMS | mean RMS (mm) | median RMS (mm) | evaluations | time / frame (ms) |")
    print("|---|---|---|---|---|---|---|")
else:
    print("| placement, method | frames | marker error (mm) | within 5 mm RMS | mean RMS (mm) | β RMS | β entries on ±3 | evaluations | time / frame (ms) |")
    print("|---|---|---|---|---|---|---|---|---|")
for n in names:
    r = json.load(open(f"{out}/{n}.json"))
    s, fr = r["summary"], r["frames"]
    ev = sum(f["evaluations"] for f in fr) / len(fr)
    ms = 1000 * s["mean_time_s"]
    if kind == "fits":
        beta, surface = s.get("mean_shape_rms"), s.get("mean_shape_v2v_mm")
        given = beta is None or "hmd" in n
        beta = "given" if given else f"{beta:.3f}"
        surface = "given" if given or surface is None else f"{surface:.1f}"
        # PA-MPJPE: older result files lack it.
        pa = s.get("mean_pa_mpjpe_mm")
        pa = "–" if pa is None else f"{pa:.1f}"
        print(f"| {n} | {len(fr)} | {s['mean_v2v_mm']:.1f} | {s['mean_mpjpe_mm']:.1f} | {pa} | {beta} | {surface} | "
              f"{s['mean_energy']:.4f} | {ev:.0f} | {ms:.2f} |")
    else:
        rms = [f["observation_rms_mm"] for f in fr]
        ok = sum(1 for x in rms if x <= 5.0)
        cells = f"{ok}/{len(fr)} ({100 * ok / len(fr):.0f} %) | {statistics.mean(rms):.1f}"
        if kind == "c3d":
            print(f"| {n} | {len(fr)} | {cells} | {statistics.median(rms):.1f} | {ev:.0f} | {ms:.1f} |")
        else:
            # No ground truth: β against the prior's mean, and how many entries sit on its box.
            beta = [f["shape"] for f in fr]
            brms = statistics.mean((sum(b * b for b in x) / len(x)) ** 0.5 for x in beta)
            bound = statistics.mean(sum(1 for b in x if abs(b) >= 2.999) for x in beta)
            print(f"| {n} | {len(fr)} | {s['mean_observation_error_mm']:.1f} | {cells} | {brms:.3f} | "
                  f"{bound:.1f} | {ev:.0f} | {ms:.2f} |")
PY
}

# One timed fit of the neural fitter as the speed tables run it (eval-chord.sh, native-ab.sh,
# eval-native-simd.sh): lfit binary BIN on DATA with CHECKPOINT, N = 5 from the given start,
# `--runtime native`, BATCH frames per pass on THREADS threads, into OUT; more `lfit fit`
# arguments after.
eval_native_fit() {
    local bin="$1" data="$2" ck="$3" batch="$4" threads="$5" out="$6"
    shift 6
    RAYON_NUM_THREADS=$threads "$bin" -q fit --data "$data" --template "$MODEL" --method neural \
        --checkpoint "$ck" --neural-start given --runtime native --budget 10 --batch "$batch" \
        "$@" --out "$out" >/dev/null
}
