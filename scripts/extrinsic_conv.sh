#!/usr/bin/env bash
# Issue 31 item 5: does the online camera-IMU extrinsic converge?
# Simulates scenarios (60 s, no LiDAR, EuRoC folders carrying the true T_bc in cam0/sensor.yaml
# T_BS) over seeds, runs `povins run --frontend tracks` (static init) with three configurations
#   perturbed_est: T_bc started 2 cm and 2 deg off the truth, estimate_extrinsic = true
#   exact_est:     T_bc started at the truth, estimate_extrinsic = true
#   exact_fixed:   T_bc at the truth, held fixed (the default)
# and prints, from stats.csv's extrinsic columns (T_bc after each keyframe's solve), the error of
# the extrinsic at 5, 10, 20, 30 s and the end (translation cm / rotation deg), the translation
# error per body axis at the end (cm), the ATE, and (estimated runs) the translation's marginal
# standard deviations at the end (cm) and its NEES against them (at the end, and the mean from
# 20 s on; 3 when the estimate knows its own error). Then the medians over seeds per scenario.
# Usage: scripts/extrinsic_conv.sh BIN OUTDIR
#   env: SCENS (default "robot handheld flight fast vehicle"), SEEDS (default "1 2 3"),
#        DUR (default 60), VARIANTS (default "perturbed_est exact_est exact_fixed"),
#        EXTRA_TOP (top-level TOML keys for every configuration, e.g. 'extrinsic_prior = [0.1, 0.1]'),
#        EXTRA_TABLES (TOML tables for every configuration, e.g. $'[td]\nestimate = false')
set -euo pipefail
BIN=${1:?povins binary}; OUT=${2:?output folder}
SCENS=${SCENS:-"robot handheld flight fast vehicle"}; SEEDS=${SEEDS:-"1 2 3"}; DUR=${DUR:-60}
VARIANTS=${VARIANTS:-"perturbed_est exact_est exact_fixed"}
EXTRA_TOP=${EXTRA_TOP:-}; EXTRA_TABLES=${EXTRA_TABLES:-}
mkdir -p "$OUT/data" "$OUT/cfg" "$OUT/runs"
# Pure-Python helpers shared by the two Python steps below: the true T_bc of a sensor.yaml and
# quaternion algebra (w, x, y, z).
PYLIB=$(cat <<'PY'
import math, re
def true_extrinsic(yaml):
    text = open(yaml).read()
    data = re.search(r"T_BS:.*?data:\s*\[(.*?)\]", text, re.S).group(1)
    t = [float(x) for x in data.replace("\n", " ").split(",")]
    m = [t[0:3], t[4:7], t[8:11]]
    return [t[3], t[7], t[11]], mat_to_quat(m)
def mat_to_quat(m):
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        return [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    i = max(range(3), key=lambda k: m[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + m[i][i] - m[j][j] - m[k][k])
    q = [0.0] * 4
    q[0] = (m[k][j] - m[j][k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (m[j][i] + m[i][j]) / s
    q[1 + k] = (m[k][i] + m[i][k]) / s
    return q
def qmul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return [w1*w2 - x1*x2 - y1*y2 - z1*z2, w1*x2 + x1*w2 + y1*z2 - z1*y2,
            w1*y2 - x1*z2 + y1*w2 + z1*x2, w1*z2 + x1*y2 - y1*x2 + z1*w2]
def qinv(q):
    return [q[0], -q[1], -q[2], -q[3]]
def exp_q(v):
    a = math.sqrt(sum(x * x for x in v))
    if a == 0:
        return [1.0, 0.0, 0.0, 0.0]
    s = math.sin(a / 2) / a
    return [math.cos(a / 2)] + [x * s for x in v]
def angle_deg(q):
    return math.degrees(2.0 * math.atan2(math.sqrt(q[1]**2 + q[2]**2 + q[3]**2), abs(q[0])))
PY
)
RESULTS="$OUT/results.txt"; : > "$RESULTS"
for scen in $SCENS; do for seed in $SEEDS; do
  d="$OUT/data/$scen-s$seed"
  [ -d "$d" ] || "$BIN" simulate --scenario "$scen" --seed "$seed" --duration "$DUR" \
      --lidar none --format euroc --out "$d" >/dev/null 2>&1
  for v in $VARIANTS; do
    c="$OUT/cfg/$scen-s$seed-$v.toml"
    python3 -c "$PYLIB
$(cat <<'PY'
import sys
yaml, v, top, tables = sys.argv[1:5]
p, q = true_extrinsic(yaml)
if v.startswith("perturbed"):
    # 2 cm along (1, -1, 1)/sqrt(3) and 2 deg about (1, 2, -1)/sqrt(6), both in the body frame.
    p = [x + 0.02 * d / math.sqrt(3.0) for x, d in zip(p, (1.0, -1.0, 1.0))]
    q = qmul(exp_q([math.radians(2.0) * d / math.sqrt(6.0) for d in (1.0, 2.0, -1.0)]), q)
print(f"estimate_extrinsic = {'true' if v.endswith('_est') else 'false'}")
print(top)
print("[extrinsic]")
print("p_bc = [" + ", ".join(repr(x) for x in p) + "]")
print("q_bc = [" + ", ".join(repr(x) for x in q[1:] + q[:1]) + "]")  # x y z w
print(tables)
PY
)" "$d/mav0/cam0/sensor.yaml" "$v" "$EXTRA_TOP" "$EXTRA_TABLES" > "$c"
    r="$OUT/runs/$scen-s$seed-$v"
    [ -f "$r/stats.csv" ] || "$BIN" run "$d" --frontend tracks --config "$c" --out "$r" \
        >"$r.log" 2>&1 || echo "FAILED $r (see $r.log)"
    python3 -c "$PYLIB
$(cat <<'PY'
import csv, os, sys
yaml, r, scen, seed, v = sys.argv[1:6]
p_true, q_true = true_extrinsic(yaml)
path = os.path.join(r, "stats.csv")
if not os.path.exists(path):
    print(f"{scen:<8} seed={seed} {v:<14} no stats.csv"); sys.exit(0)
pts = []
for row in csv.DictReader(open(path)):
    if not row["p_bc_x_m"]:
        continue
    dp = [float(row[k]) - t for k, t in zip(("p_bc_x_m", "p_bc_y_m", "p_bc_z_m"), p_true)]
    q = [float(row[k]) for k in ("q_bc_w", "q_bc_x", "q_bc_y", "q_bc_z")]
    sd = [float(row[k]) if row.get(k) else float("nan")
          for k in ("p_bc_sd_x_m", "p_bc_sd_y_m", "p_bc_sd_z_m")]
    # t_s is on the sequence clock; the simulator's first IMU sample is at 1 s.
    pts.append((float(row["t_s"]) - 1.0, dp, angle_deg(qmul(q, qinv(q_true))), sd))
def at(s):
    ks = [x for x in pts if x[0] <= s]
    return ks[-1] if ks else None
cells = []
for s in (5, 10, 20, 30, 1e9):
    x = at(s)
    cells.append("nan/nan" if x is None else f"{100*math.hypot(*x[1]):4.2f}/{x[2]:4.2f}")
end = [100 * x for x in pts[-1][1]] if pts else [float("nan")] * 3
# The translation's NEES against its marginal standard deviations (per axis, correlations left
# out; 3 when consistent): at the end, and the mean over the keyframes from 20 s on.
def nees(x):
    return sum((e / s) ** 2 for e, s in zip(x[1], x[3]))
sd_end = [100 * s for s in pts[-1][3]] if pts else [float("nan")] * 3
late = [nees(x) for x in pts if x[0] >= 20 and all(s == s for s in x[3])]
nees_end = nees(pts[-1]) if pts else float("nan")
nees_late = sum(late) / len(late) if late else float("nan")
ate = "nan"
for line in open(r + ".log"):
    if line.startswith("ATE"):
        ate = line.split()[1]
print(f"{scen:<8} seed={seed} {v:<14} err cm/deg @5,10,20,30,end: {' '.join(cells)}"
      f"  end dp_b cm [{end[0]:+.2f} {end[1]:+.2f} {end[2]:+.2f}]  ate={ate}"
      f"  sd_end cm [{sd_end[0]:.2f} {sd_end[1]:.2f} {sd_end[2]:.2f}]"
      f"  nees_p end {nees_end:.2f} mean>=20s {nees_late:.2f}")
PY
)" "$d/mav0/cam0/sensor.yaml" "$r" "$scen" "$seed" "$v" | tee -a "$RESULTS"
  done
done; done
python3 - "$RESULTS" <<'PY'
import re, sys, statistics as st
rows = {}
for line in open(sys.argv[1]):
    m = re.match(r"(\S+)\s+seed=\S+\s+(\S+)\s+err cm/deg @5,10,20,30,end: (.*?)  end dp_b.*ate=(\S+)", line)
    n = re.search(r"nees_p end (\S+) mean>=20s (\S+)", line)
    if not m:
        continue
    scen, v, cells, ate = m.groups()
    vals = [tuple(float(x) for x in c.split("/")) for c in cells.split()]
    rows.setdefault((scen, v), []).append((vals, float(ate), float(n.group(2)) if n else float("nan")))
print("\nmedians over seeds (extrinsic error cm/deg at 5, 10, 20, 30 s, end; ATE m; ATE / exact_fixed)")
for (scen, v), runs in rows.items():
    med = [f"{st.median(r[0][i][0] for r in runs):4.2f}/{st.median(r[0][i][1] for r in runs):4.2f}"
           for i in range(5)]
    ate = st.median(r[1] for r in runs)
    ref = rows.get((scen, "exact_fixed"))
    ratio = ate / st.median(r[1] for r in ref) if ref else float("nan")
    nees = st.median(r[2] for r in runs)
    print(f"{scen:<8} {v:<14} {' '.join(med)}  ate={ate:.4f}  x{ratio:.2f}  nees_p(>=20s)={nees:.2f}")
PY
