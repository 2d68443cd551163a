#!/usr/bin/env bash
# Issue 31 item 4: why the online camera-IMU delay locked in on calm flights, and the bar.
# Simulates flights (--scenario $SCEN, default flight, 60 s, 3% wrong tracks, no LiDAR, as the
# regression suite) with true delays $TDS (default -30 -10 8 30 ms) over seeds $SEEDS (1-3), runs
# `povins run` (tracks front end, static init) with configuration variants given through config
# keys, and prints the keyframe delay (stats.csv td_ms) at 2, 5, 10, 20, 30, 40, 50 s and the
# end, plus the ATE; then (summary) per true delay and variant the median over seeds of the
# error at 20 s and of the ATE, and the ATE ratio against the variant `truth` where it ran.
# STEP=10 steps the true delay by +10 ms at 30 s (`--td-step-ms 10 --td-step-at-s 30`; the
# errors after 30 s are against the stepped delay): the bar is 1 ms again by 50 s.
# Usage: scripts/td_lockin.sh BIN OUTDIR [variants...]   (variants: see VARIANTS below)
set -euo pipefail
BIN=${1:?povins binary}; OUT=${2:?output folder}; shift 2
mkdir -p "$OUT/data" "$OUT/cfg" "$OUT/runs"
declare -A VARIANTS=(
  [blind]='td_s = 0.0'
  [truth]='td_s = TRUTH'
  [blind_prior50ms]=$'td_s = 0.0\n[td]\nprior_s = 0.05'
  [truth_prior50ms]=$'td_s = TRUTH\n[td]\nprior_s = 0.05'
  [blind_rw1e-3]=$'td_s = 0.0\n[td]\nrw_s_per_sqrt_s = 1e-3'
  [blind_rw3e-4]=$'td_s = 0.0\n[td]\nrw_s_per_sqrt_s = 3e-4'
  [truth_rw1e-3]=$'td_s = TRUTH\n[td]\nrw_s_per_sqrt_s = 1e-3'
  [blind_rw1e-5]=$'td_s = 0.0\n[td]\nrw_s_per_sqrt_s = 1e-5'
  [blind_info0]=$'td_s = 0.0\n[td]\nmin_info_per_s2 = 0.0'
  [blind_info1e5]=$'td_s = 0.0\n[td]\nmin_info_per_s2 = 1e5'
  [blind_info1e7]=$'td_s = 0.0\n[td]\nmin_info_per_s2 = 1e7'
  [blind_info3e6]=$'td_s = 0.0\n[td]\nmin_info_per_s2 = 3e6'
  [blind_prior5ms]=$'td_s = 0.0\n[td]\nprior_s = 0.005'
  [blind_prior5ms_info0]=$'td_s = 0.0\n[td]\nprior_s = 0.005\nmin_info_per_s2 = 0.0'
  [blind_prior50ms_rw1e-3]=$'td_s = 0.0\n[td]\nprior_s = 0.05\nrw_s_per_sqrt_s = 1e-3'
  [blind_inverse_depth]=$'td_s = 0.0\nmode = "inverse-depth"'
  [blind_noreuse]=$'td_s = 0.0\nreuse_marginalized_landmarks = false'
  [truth_noreuse]=$'td_s = TRUTH\nreuse_marginalized_landmarks = false'
  [blind_nomargvis]=$'td_s = 0.0\nmarginalize_visual = false'
  [blind_noreuse_prior50ms]=$'td_s = 0.0\nreuse_marginalized_landmarks = false\n[td]\nprior_s = 0.05'
)
SEL=("$@"); [ ${#SEL[@]} -eq 0 ] && SEL=(blind truth)
TDS=${TDS:-"-30 -10 8 30"}; SEEDS=${SEEDS:-"1 2 3"}; SCEN=${SCEN:-flight}; DUR=${DUR:-60}
STEP=${STEP:-0}
step_args=(); tag=""
if [ "$STEP" != 0 ]; then step_args=(--td-step-ms "$STEP" --td-step-at-s 30); tag="-step$STEP"; fi
SUM="$OUT/lines-$SCEN$tag.txt"; : > "$SUM"
for td in $TDS; do for seed in $SEEDS; do
  d="$OUT/data/$SCEN-td$td-s$seed$tag"
  [ -d "$d" ] || "$BIN" simulate --scenario "$SCEN" --seed "$seed" --duration "$DUR" --td-ms "$td" \
      "${step_args[@]}" --wrong-track-rate 0.03 --lidar none --format euroc --out "$d" 2>/dev/null
  for v in "${SEL[@]}"; do
    truth=$(python3 -c "print($td*1e-3)")
    c="$OUT/cfg/$v-td$td.toml"; printf '%s\n' "${VARIANTS[$v]//TRUTH/$truth}" > "$c"
    r="$OUT/runs/$SCEN-td$td-s$seed$tag-$v"
    [ -f "$r/stats.csv" ] || "$BIN" run "$d" --frontend tracks --config "$c" --out "$r" >"$r.log" 2>&1 || echo "FAILED $r"
    python3 - "$r" "$td" "$v" "$seed" "$STEP" <<'PY' | tee -a "$SUM"
import csv, json, sys, os
r, td, v, seed, step = sys.argv[1:6]
rows = list(csv.DictReader(open(os.path.join(r, "stats.csv"))))
# t_s is the keyframe's time on the sequence clock; the simulator's first IMU sample is at 1 s.
pts = {float(row["t_s"]) - 1.0: float(row["td_ms"]) for row in rows}
def at(s):
    ks = [k for k in pts if k <= s]
    return pts[max(ks)] if ks else float("nan")
ate = "?"
for line in open(r + ".log"):
    if line.startswith("ATE"):
        ate = line.split()[1]
vals = " ".join(f"{at(s):7.2f}" for s in (2, 5, 10, 20, 30, 40, 50, 1e9))
print(f"td={td:>4} step={step} seed={seed} {v:<24} td_ms@2,5,10,20,30,40,50,end: {vals}  ate={ate}")
PY
  done
done; done
echo "summary ($SCEN, step $STEP): median over seeds of |td error| at 20 s (and at 50 s), ATE, ATE / truth's"
python3 - "$SUM" <<'PY'
import sys, statistics as st, collections
rows = collections.defaultdict(list)
for line in open(sys.argv[1]):
    f = line.replace("= ", "=").replace("= ", "=").replace("= ", "=").split()
    td, step, v = float(f[0].split("=")[1]), float(f[1].split("=")[1]), f[3]
    vals = [float(x) for x in f[5:13]]
    ate = float(f[13].split("=")[1]) if f[13] != "ate=?" else float("nan")
    rows[(td, v)].append((abs(vals[3] - td), abs(vals[6] - td - step), ate))
for (td, v), rs in sorted(rows.items()):
    med = lambda i: st.median(r[i] for r in rs)
    truth = rows.get((td, "truth"))
    ratio = med(2) / st.median(r[2] for r in truth) if truth else float("nan")
    print(f"td={td:>5} {v:<24} err@20 {med(0):6.2f} ms  err@50 {med(1):6.2f} ms  ate {med(2):.4f}  ate/truth {ratio:.3f}  (n={len(rs)})")
PY
