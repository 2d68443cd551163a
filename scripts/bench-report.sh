#!/usr/bin/env bash
# Reproduces the accuracy and timing figures of BENCHMARKS.md: builds the release binary, runs
# the estimator on the shared datasets and the simulator's scenarios, and prints one summary
# line per run (ATE posyaw, back-end time per keyframe and per camera frame).
# Usage: scripts/bench-report.sh [OUT_DIR]   (needs ../shared/data; ~12 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/bench}
data=../shared/data
mkdir -p "$out"
cargo build --release -q -p povins-host-tools
bin=target/release/povins

line() { # name summary.json
  python3 - "$1" "$2" <<'PY'
import json, sys
s = json.load(open(sys.argv[2]))
ate = s.get("ate_pos_rmse_m"); rot = s.get("ate_rot_rmse_deg")
print(f"{sys.argv[1]:<44} ATE {ate if ate is None else round(ate, 4)} m {rot if rot is None else round(rot, 3)} deg | "
      f"keyframes {s['keyframes']:4d} | landmarks used (median) {s['landmarks_used_median']:.0f} | back end median "
      f"{s['backend_ms_median']:.3f} p99 {s['backend_ms_p99']:.3f} max {s['backend_ms_max']:.3f} ms/kf | "
      f"{s['backend_ms_per_camera_frame']:.3f} ms/camera frame"
      + (f" | LiDAR association {s['association_ms_median']:.3f} ms/kf, {s['ldm_per_kf']:.1f} LDM/kf"
         if s.get("lidar") else ""))
PY
}

run() { # name dataset args...
  local name=$1 ds=$2; shift 2
  "$bin" run "$ds" --out "$out/$name" "$@" > /dev/null
  line "$name" "$out/$name/summary.json"
}

run euroc-v101-30s/static/pose-only "$data/euroc-v101-30s-features" --config configs/euroc.toml --init static
run euroc-v101-30s/static/inverse-depth "$data/euroc-v101-30s-features" --config configs/euroc.toml --init static --mode inverse-depth
run euroc-v101-30s/groundtruth/pose-only "$data/euroc-v101-30s-features" --config configs/euroc.toml --init groundtruth
run openvins-corridor/groundtruth/pose-only "$data/openvins-sim-corridor-mono" --init groundtruth
run openvins-corridor/groundtruth/inverse-depth "$data/openvins-sim-corridor-mono" --init groundtruth --mode inverse-depth
for sc in robot handheld vehicle; do
  for seed in 1 2; do
    "$bin" simulate --scenario "$sc" --seed "$seed" --duration 60 --lidar none --out "$out/sim-$sc-$seed.mcap" 2> /dev/null
    run "sim-$sc-seed$seed/groundtruth/pose-only" "$out/sim-$sc-$seed.mcap" --init groundtruth
    run "sim-$sc-seed$seed/groundtruth/inverse-depth" "$out/sim-$sc-$seed.mcap" --init groundtruth --mode inverse-depth
  done
done
# LiDAR enhancement (issue 5): the same scenarios with the simulator's default LiDAR.
for sc in robot handheld vehicle; do
  "$bin" simulate --scenario "$sc" --seed 1 --duration 60 --out "$out/simL-$sc-1.mcap" 2> /dev/null
  run "sim-$sc-seed1-lidar/groundtruth/po-vins" "$out/simL-$sc-1.mcap" --init groundtruth
  run "sim-$sc-seed1-lidar/groundtruth/po-vins-wo" "$out/simL-$sc-1.mcap" --init groundtruth --no-lidar
done
# The ablation table (Table VI): 3 scenarios x 3 seeds x 5 variants, one job for clean timings.
"$bin" ablation --jobs 1 --out "$out/ablation" 2> /dev/null | sed -n '1,9p'
