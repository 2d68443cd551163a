#!/usr/bin/env bash
# Proves povins-core is no_std and heap-free on ARM, and bit-identical on aarch64:
#  1. builds povins-core for thumbv7em-none-eabihf and aarch64-unknown-none with -Zbuild-std=core
#     (no std and no alloc exist for these targets, so anything in the graph needing them fails),
#     with and without the `defmt` feature;
#  2. runs core's and the platform's tests for aarch64-unknown-linux-gnu under qemu-user, and the
#     estimator's golden replays (tests/estimator_determinism.rs: EuRoC, simulated robot with and
#     without LiDAR; tests/estimator_static.rs; tests/estimator_accuracy.rs), which compare every
#     state and report with the golden files written on x86-64: bit-identical or red;
#  3. checks that the golden hashes printed there (preintegration over the real EuRoC IMU log; the
#     image front end over real EuRoC and DM-VIO frames, an #[ignore]d test run explicitly) equal
#     the x86-64 ones.
# Usage: scripts/cross-check.sh [--all]   (run scripts/setup-cross.sh once first)
#   --all: every test of the workspace under qemu instead of the subset above (about 40 min on 2
#          cores; passed on 2026-11-25); binaries the tests spawn run through $POVINS_TEST_RUNNER.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

# Debian's toolchain (has rust-src), not rustup's.
export PATH=/usr/bin:/bin
export RUSTC=/usr/bin/rustc
export RUSTC_BOOTSTRAP=1
export CARGO_TARGET_DIR="$root/target/cross"
unset RUSTFLAGS
CARGO=/usr/bin/cargo
[ -x "$RUSTC" ] && [ -x "$CARGO" ] || { echo "cross-check: Debian rustc-web/cargo-web missing: run scripts/setup-cross.sh" >&2; exit 1; }
"$RUSTC" --version

for target in thumbv7em-none-eabihf aarch64-unknown-none; do
  for feat in "" "defmt"; do
    echo "== build povins-core for $target ${feat:+(feature $feat)}"
    "$CARGO" build -q --release -p povins-core -Zbuild-std=core --target "$target" ${feat:+--features "$feat"}
  done
  echo "== build povins-core for $target without LiDAR storage (--no-default-features)"
  "$CARGO" build -q --release -p povins-core -Zbuild-std=core --target "$target" --no-default-features
done

arm=(-Zbuild-std --target aarch64-unknown-linux-gnu)
export POVINS_TEST_RUNNER="qemu-aarch64-static -L /usr/aarch64-linux-gnu"
if [ "${1:-}" = "--all" ]; then
  echo "== every workspace test on aarch64-unknown-linux-gnu under qemu"
else
  echo "== core and platform tests, and the estimator's golden replays, on aarch64 under qemu"
fi
log_arm="$CARGO_TARGET_DIR/core-tests-aarch64.log"
status=0
if [ "${1:-}" = "--all" ]; then
  "$CARGO" test -q --workspace "${arm[@]}" -- --nocapture > "$log_arm" 2>&1 || status=$?
else
  "$CARGO" test -q -p povins-core -p povins-platform "${arm[@]}" -- --nocapture > "$log_arm" 2>&1 || status=$?
  "$CARGO" test -q -p povins --test estimator_determinism --test estimator_static --test estimator_accuracy "${arm[@]}" -- --nocapture >> "$log_arm" 2>&1 || status=$?
fi
# The image front end's hash test reads ../shared/data and is #[ignore]d by default: run it here.
"$CARGO" test -q -p povins-core -Zbuild-std --target aarch64-unknown-linux-gnu --test frontend_image -- --ignored --nocapture frontend_determinism_hash >> "$log_arm" 2>&1 || status=$?
grep -E "^test result|POVINS_|FAILED|panicked" "$log_arm" || true
[ "$status" -eq 0 ] || { tail -40 "$log_arm"; echo "cross-check: aarch64 tests failed (see $log_arm)" >&2; exit 1; }

echo "== core tests on x86_64 (same toolchain) for the hash comparison"
log_x86="$CARGO_TARGET_DIR/core-tests-x86_64.log"
"$CARGO" test -q -p povins-core -- --nocapture > "$log_x86" 2>&1 || { tail -40 "$log_x86"; echo "cross-check: x86-64 core tests failed (see $log_x86)" >&2; exit 1; }
"$CARGO" test -q -p povins-core --test frontend_image -- --ignored --nocapture frontend_determinism_hash >> "$log_x86" 2>&1 || { tail -40 "$log_x86"; echo "cross-check: x86-64 front-end hash test failed (see $log_x86)" >&2; exit 1; }

hashes() { grep -oE "POVINS_[A-Z_]+=[0-9a-f]+" "$1" | sort; }
h_arm=$(hashes "$log_arm"); h_x86=$(hashes "$log_x86")
if [ -z "$h_x86" ]; then echo "cross-check: no POVINS_*_HASH lines printed by the tests" >&2; exit 1; fi
echo "x86_64 : $(echo $h_x86)"
echo "aarch64: $(echo $h_arm)"
if [ "$h_arm" != "$h_x86" ]; then echo "cross-check: aarch64 and x86-64 results differ" >&2; exit 1; fi
echo "cross-check: OK (bare-metal builds, aarch64 tests pass, golden replays and hashes bit-identical)"
