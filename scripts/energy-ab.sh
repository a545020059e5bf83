#!/bin/bash
# The energy's cost model, one commit against this tree, in one alternated session:
#   ./scripts/energy-ab.sh BASE_REV [OUT]
# builds `cargo bench -p lfit-model --bench energy` at BASE_REV (a git worktree under OUT, its
# own target directory: Burn-free, a few minutes cold) and in this tree, then runs the two bench
# binaries alternately REPS times (default 4) on FILTER (default: value, value + gradient and
# factored residuals + Jacobian of markers, keypoints2d and hmd) and prints µs per system
# (criterion's median over its 32 systems / 32) per run, the medians, their ratio and the rate.
# The harness of this tree's bench is used for both (copied into the worktree), so that a change
# of harness does not pass for a change of code.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 1 ] || { echo "usage: scripts/energy-ab.sh BASE_REV [OUT]" >&2; exit 1; }
BASE_REV="$1"; O="${2:-target/energy-ab}"; REPS="${REPS:-4}"
FILTER="${FILTER:-cost_model/makehuman/(markers|keypoints2d|hmd)/(value|value_and_gradient|jacobian_factored)\$}"
mkdir -p "$O"; O="$(cd "$O" && pwd)"
rm -rf "$O/base-tree"; git worktree prune
git worktree add --detach -f "$O/base-tree" "$BASE_REV" >/dev/null
# The base bench reads the models from its own tree: the worktree goes when the script ends.
ROOT="$PWD"
trap 'git -C "$ROOT" worktree remove --force "$O/base-tree" 2>/dev/null || true' EXIT
cp model/benches/energy.rs "$O/base-tree/model/benches/energy.rs"
bench_bin() { # tree target-dir -> path of the bench binary
    (cd "$1" && CARGO_TARGET_DIR="$2" cargo bench -p lfit-model --bench energy --no-run --message-format=json 2>/dev/null) |
        python3 -c "import json,sys; print([m['executable'] for m in map(json.loads, sys.stdin) if m.get('reason')=='compiler-artifact' and m.get('target',{}).get('name')=='energy' and m.get('executable')][-1])"
}
BASE_BIN=$(bench_bin "$O/base-tree" "$O/base-target")
NEW_BIN=$(bench_bin "$PWD" "${CARGO_TARGET_DIR:-$PWD/target}")
cd model
for rep in $(seq "$REPS"); do
    for b in base new; do
        bin="$BASE_BIN"; [ $b = new ] && bin="$NEW_BIN"
        "$bin" --bench "$FILTER" --warm-up-time 1 --measurement-time "${MT:-5}" 2>&1 |
            awk -v b=$b '/^cost_model.*\/[a-z_]+$/ {n=$1} /time:/ && $5 ~ /s$/ {v=$4; if ($5=="ms") v*=1000; if ($5=="ns") v/=1000; split(n,a,"/"); printf "%s %s/%s %.3f\n", b, a[3], a[4], v/32}'
    done
done > "$O/runs.txt"
python3 - "$O/runs.txt" <<'PY'
import collections, statistics, sys
runs = collections.defaultdict(list)
for line in open(sys.argv[1]):
    b, name, us = line.split()
    runs[(b, name)].append(float(us))
print('| per system (µs) | base runs | new runs | new / base (medians) | new per second |')
print('|---|---|---|---|---|')
for name in sorted({n for _, n in runs}):
    a, n = runs[('base', name)], runs[('new', name)]
    ma, mn = statistics.median(a), statistics.median(n)
    print(f"| {name} | {', '.join(f'{x:.2f}' for x in a)} | {', '.join(f'{x:.2f}' for x in n)} | {mn / ma:.3f} | {1e3 / mn:.1f} k |")
PY
