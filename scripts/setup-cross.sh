#!/usr/bin/env bash
# Installs Debian's Rust toolchain with std sources (rustc-web 1.96 + rust-web-src), the aarch64
# cross linker/libc and qemu-user, which together build povins-core for bare-metal ARM targets and run
# its tests on aarch64 Linux under emulation, and g++ (libFuzzer's build, scripts/fuzz.sh). rustup
# cannot add targets on this machine kind, so the cross builds use `-Zbuild-std` with this
# toolchain instead. Idempotent; needs root (or sudo).
set -euo pipefail

need=()
for p in rustc-web cargo-web rust-web-src gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user-static g++; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if [ ${#need[@]} -eq 0 ]; then
  echo "setup-cross: all packages present"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
# The image's apt config deletes downloaded .debs between dpkg runs; keep our own archive dir so a
# large install does not fail half-way.
cache="${TMPDIR:-/tmp}/povins-apt-archives"
mkdir -p "$cache/partial"
echo "setup-cross: installing ${need[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
  -o Dir::Cache::Archives="$cache" "${need[@]}" >/dev/null
# Do NOT add the arm64 dpkg architecture (libc6:arm64): mixing it with the cross libc makes
# threaded programs hang under qemu.
echo "setup-cross: done"
