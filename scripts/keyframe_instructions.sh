#!/usr/bin/env bash
# Instructions per keyframe step of the estimator (machine- and load-independent: callgrind
# counts them): runs `povins run DATASET ARGS...` under valgrind's callgrind with a profile dump
# at every entry of `Estimator::add_keyframe`, then prints the inclusive count of add_keyframe
# in each dump (the keyframe step that ended in that interval) and their median, p90 and max.
# About 20x slower than the run itself. Needs valgrind (Debian: apt-get install valgrind).
# Usage: scripts/keyframe_instructions.sh target/release/povins DATASET [povins run args...]
set -euo pipefail
povins=$(realpath "$1"); dataset=$(realpath "$2"); shift 2
command -v valgrind >/dev/null || { echo "keyframe_instructions: valgrind not found (apt-get install valgrind)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
( cd "$work" && valgrind --tool=callgrind --dump-before='*add_keyframe*' \
    --callgrind-out-file="$work/cg.out" "$povins" run "$dataset" --out "$work/run" "$@" ) \
  > "$work/log" 2>&1 || { tail -20 "$work/log" >&2; exit 1; }
for f in $(cd "$work" && ls cg.out.* | sort -t. -k3 -n); do
  # The first dump (before the first keyframe) has none.
  { callgrind_annotate --inclusive=yes "$work/$f" 2>/dev/null | grep "add_keyframe \[" || true; } \
    | head -1 | awk '{gsub(",","",$1); print $1}'
done > "$work/kf"
python3 - "$work/kf" <<'PY'
import statistics, sys
v = [int(x) for x in open(sys.argv[1]) if x.strip()]
if not v:
    sys.exit("keyframe_instructions: no keyframe step found")
s = sorted(v)
med = statistics.median(v)
print(f"keyframes {len(v)}: instructions per keyframe step median {med/1e6:.1f} M, "
      f"p90 {s[int(0.9*len(s))]/1e6:.1f} M, max {s[-1]/1e6:.1f} M ({s[-1]/med:.2f}x the median)")
PY
