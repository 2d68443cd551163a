#!/usr/bin/env bash
# Issue 31 bar, in-motion starts: every simulator scenario started in motion
# (`povins simulate --start-s motion`: the rest and the ramp to full motion cut away) against the
# same sequence started at rest, over seeds, with the tracks front end (FRONTEND=images for the
# image front end). Prints per run the first estimate's delay after the first camera frame, the
# coverage of the ground truth after it, the resets and the ATE (summary.json), then medians.
# Usage: scripts/motion_start.sh BIN OUTDIR   (env: SCENS, SEEDS, DUR, FRONTEND, INIT, EXTRA)
set -euo pipefail
BIN=${1:?povins binary}; OUT=${2:?output folder}
SCENS=${SCENS:-"robot handheld flight fast vehicle"}; SEEDS=${SEEDS:-"1 2 3"}; DUR=${DUR:-40}
FRONTEND=${FRONTEND:-tracks}; INIT=${INIT:-auto}; EXTRA=${EXTRA:-}
mkdir -p "$OUT/data" "$OUT/runs"
for sc in $SCENS; do for seed in $SEEDS; do for start in motion 0; do
  d="$OUT/data/$sc-s$seed-start$start"
  imgs=(); [ "$FRONTEND" = images ] && imgs=(--images)
  [ -d "$d" ] || "$BIN" simulate --scenario "$sc" --seed "$seed" --duration "$DUR" --start-s "$start" \
      --wrong-track-rate 0.03 --lidar none "${imgs[@]}" --format euroc --out "$d" >/dev/null 2>&1
  r="$OUT/runs/$sc-s$seed-start$start-$FRONTEND-$INIT"
  init=$INIT; [ "$start" = 0 ] && [ "$INIT" = motion ] && init=auto
  [ -f "$r/summary.json" ] || "$BIN" run "$d" --frontend "$FRONTEND" --init "$init" $EXTRA --out "$r" >"$r.log" 2>&1 || true
done; done; done
python3 - "$OUT" "$FRONTEND" "$INIT" <<'PY'
import json, os, sys, statistics as st, collections
out, fe, init = sys.argv[1:4]
rows = collections.defaultdict(list)
for name in sorted(os.listdir(os.path.join(out, "runs"))):
    p = os.path.join(out, "runs", name, "summary.json")
    if not name.endswith(f"-{fe}-{init}") or not os.path.isfile(p):
        continue
    sc, seed, start = name.split("-")[:3]
    s = json.load(open(p))
    rows[(sc, start)].append(s)
    print(f"{sc:9s} {seed:4s} {start:12s} start {s.get('start_after_camera_s') or float('nan'):6.2f} s  coverage {s.get('coverage') or 0:6.3f}  resets {s['counters']['resets']}  ATE {s.get('ate_pos_rmse_m') or float('nan'):.4f} m  keyframes {s['keyframes']}")
print("\nscenario  start        runs  start(max) s  coverage(min)  ATE median m  vs rest")
for (sc, start) in sorted(rows):
    v = rows[(sc, start)]
    ate = st.median([s.get("ate_pos_rmse_m") or float("inf") for s in v])
    rest = rows.get((sc, "start0"))
    ratio = ate / st.median([s.get("ate_pos_rmse_m") or float("inf") for s in rest]) if rest else float("nan")
    print(f"{sc:9s} {start:12s} {len(v):4d}  {max((s.get('start_after_camera_s') or float('inf')) for s in v):12.2f}  {min((s.get('coverage') or 0) for s in v):13.3f}  {ate:12.4f}  {ratio:6.2f}x")
PY
