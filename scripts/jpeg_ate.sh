#!/usr/bin/env bash
# ATE raw vs JPEG: simulate handheld with images (no LiDAR, 30 s); raw = the EuRoC folder (the ROS
# bag of it replays bit-identically, tests/simulate_formats.rs), JPEG = ROS 1 bags with
# CompressedImage; each trajectory evaluated against the folder's ground truth (posyaw).
B=${POVINS:-target/release/povins}; D=${1:?usage: scripts/jpeg_ate.sh OUTDIR}; mkdir -p "$D"
common="--scenario handheld --images --duration 30 --lidar none"
for seed in 1 2 3; do
  $B simulate $common --seed $seed --format euroc --out $D/h$seed-raw > $D/h$seed-raw.sim.log 2>&1 || echo "sim fail raw $seed"
  $B run $D/h$seed-raw --out $D/out-h$seed-raw > $D/h$seed-raw.run.log 2>&1; rc=$?
  gt=$D/h$seed-raw/mav0/state_groundtruth_estimate0/data.csv
  echo "h$seed-raw rc=$rc $(du -sk $D/h$seed-raw | cut -f1)kB $($B eval --gt $gt --est $D/out-h$seed-raw/trajectory.tum 2>&1 | grep '^position' | awk '{print "ATE", $3}')"
  for q in 90 75; do
    n=h$seed-jpeg$q
    $B simulate $common --seed $seed --format rosbag1 --image-encoding jpeg=$q --out $D/$n.bag > $D/$n.sim.log 2>&1 || echo "sim fail $n"
    $B run $D/$n.bag --calib $D/$n-calib --out $D/out-$n > $D/$n.run.log 2>&1; rc=$?
    echo "$n rc=$rc $(du -k $D/$n.bag | cut -f1)kB $($B eval --gt $gt --est $D/out-$n/trajectory.tum 2>&1 | grep '^position' | awk '{print "ATE", $3}')"
  done
done
