#!/usr/bin/env bash
# Proves povins-core is no_std and heap-free on ARM, and bit-identical on aarch64:
#  1. builds povins-core for thumbv7em-none-eabihf and aarch64-unknown-none with -Zbuild-std=core
#     (no std and no alloc exist for these targets, so anything in the graph needing them fails);
#     the default features are built (code generated), the variants (`defmt`, and without the
#     `lidar` storage) are type-checked, which is where a missing std/alloc shows;
#  2. runs on aarch64-unknown-linux-gnu under qemu what proves bit-identity with x86-64, with
#     povins-core alone (building the host tools for aarch64 took 22 of this script's minutes):
#     the whole estimator on real EuRoC data (core/tests/estimator_golden.rs: default window,
#     online extrinsic, and with synthetic LiDAR sweeps; each run twice, every IMU-rate state and
#     keyframe report hashed), the
#     preintegration over the real EuRoC IMU log (core/tests/inertial_golden.rs) and the image
#     front end over real EuRoC and DM-VIO frames (core/tests/frontend_image.rs, an #[ignore]d
#     test run explicitly): bit-identical or red; and the README's footprint table
#     (core/tests/footprint.rs: size_of on aarch64). The facade's golden replays through the host
#     tools' runner (tests/estimator_determinism.rs) and the rest of the suite run on x86-64 in
#     CI, and on aarch64 with --all;
#  3. each hash is asserted against the constant in its test (the same constants the x86-64
#     `cargo test` of CI asserts); this script checks that all were printed on aarch64.
# Usage: scripts/cross-check.sh [--all]   (run scripts/setup-cross.sh once first)
#   --all: every test of the workspace under qemu instead of the subset above (about 40 min on 2
#          cores; passed on 2026-11-25), the accuracy replays (tests/estimator_accuracy.rs) among
#          them; binaries the tests spawn run through $POVINS_TEST_RUNNER.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

# Debian's toolchain (has rust-src), not rustup's.
export PATH=/usr/bin:/bin
export RUSTC=/usr/bin/rustc
export RUSTC_BOOTSTRAP=1
export CARGO_TARGET_DIR="$root/target/cross"
unset RUSTFLAGS
# No debug info: the tests' panics still name file and line; compiling and linking ~40% less.
export CARGO_PROFILE_TEST_DEBUG=0 CARGO_PROFILE_DEV_DEBUG=0
CARGO=/usr/bin/cargo
[ -x "$RUSTC" ] && [ -x "$CARGO" ] || { echo "cross-check: Debian rustc-web/cargo-web missing: run scripts/setup-cross.sh" >&2; exit 1; }
"$RUSTC" --version

for target in thumbv7em-none-eabihf aarch64-unknown-none; do
  echo "== build povins-core for $target"
  "$CARGO" build -q --release -p povins-core -Zbuild-std=core --target "$target"
  echo "== check povins-core for $target with defmt and serde, and without LiDAR storage (--no-default-features)"
  "$CARGO" check -q --release -p povins-core -Zbuild-std=core --target "$target" --features defmt,serde
  "$CARGO" check -q --release -p povins-core -Zbuild-std=core --target "$target" --no-default-features
done

arm=(-Zbuild-std --target aarch64-unknown-linux-gnu)
export POVINS_TEST_RUNNER="qemu-aarch64-static -L /usr/aarch64-linux-gnu"
if [ "${1:-}" = "--all" ]; then
  echo "== every workspace test on aarch64-unknown-linux-gnu under qemu"
else
  echo "== the core's golden runs and hash tests on aarch64 under qemu"
fi
log_arm="$CARGO_TARGET_DIR/core-tests-aarch64.log"
status=0
if [ "${1:-}" = "--all" ]; then
  "$CARGO" test -q --workspace "${arm[@]}" -- --nocapture > "$log_arm" 2>&1 || status=$?
else
  "$CARGO" test -q -p povins-core --test estimator_golden --test inertial_golden --test frontend_image --test footprint "${arm[@]}" -- --nocapture > "$log_arm" 2>&1 || status=$?
fi
# The image front end's hash test reads ../shared/data and is #[ignore]d by default: run it here.
"$CARGO" test -q -p povins-core -Zbuild-std --target aarch64-unknown-linux-gnu --test frontend_image -- --ignored --nocapture frontend_determinism_hash >> "$log_arm" 2>&1 || status=$?
grep -E "^test result|POVINS_|FAILED|panicked" "$log_arm" || true
[ "$status" -eq 0 ] || { tail -40 "$log_arm"; echo "cross-check: aarch64 tests failed (see $log_arm)" >&2; exit 1; }

hashes=$(grep -oE "POVINS_[A-Z_]+=[0-9a-f]+" "$log_arm" | sort)
echo "aarch64: $(echo $hashes)"
for h in POVINS_PREINT_HASH POVINS_FRONTEND_HASH POVINS_ESTIMATOR_HASH_DEFAULT POVINS_ESTIMATOR_HASH_EXTRINSIC POVINS_ESTIMATOR_HASH_LIDAR; do
  echo "$hashes" | grep -q "^$h=" || { echo "cross-check: $h was not printed on aarch64 (test skipped?)" >&2; exit 1; }
done
echo "cross-check: OK (bare-metal builds, aarch64 tests pass, the estimator, preintegration and front-end hashes bit-identical)"
