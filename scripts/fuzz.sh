#!/usr/bin/env bash
# Runs the cargo-fuzz targets of fuzz/ (issue 32 item 5) with Debian's rustc-web (rustup's
# stable cannot build sanitizer-instrumented code; RUSTC_BOOTSTRAP=1 allows the -Z flags
# cargo-fuzz passes). One target at a time, one worker (the machine is shared).
# Usage: scripts/fuzz.sh TARGET [SECONDS]   one target (default 60 s)
#        scripts/fuzz.sh all [SECONDS]      every target in turn
#        scripts/fuzz.sh list               the targets
#        scripts/fuzz.sh build              build them only
#        scripts/fuzz.sh cmin TARGET|all    minimize the corpus (keeps the inputs that add coverage)
#        scripts/fuzz.sh install            cargo-fuzz into target/cargo-fuzz (when none is found)
#        scripts/fuzz.sh ci [SECONDS]       CI's short form: install, build, every target for SECONDS
#                                           (default 10) from the committed corpus, writing nothing
#                                           into the repository; fails on any crash, hang or OOM
# cargo-fuzz is taken from CARGO_FUZZ_BIN, the PATH, or target/cargo-fuzz/bin (`install` puts
# cargo-fuzz 0.13.2 there, built with the same toolchain). No sanitizer (`-s none`): rustc-web ships no
# ASan runtime; libFuzzer still finds panics, hangs and OOMs, and the core forbids unsafe code.
# The corpus is fuzz/corpus/TARGET (new inputs
# are added to it: commit the ones worth keeping, small); a crash, hang (-timeout) or OOM leaves
# its input in fuzz/artifacts/TARGET/. tests/fuzz_corpora.rs replays both in `cargo test`.
# Extra libFuzzer flags: FUZZ_FLAGS="-max_len=65536" scripts/fuzz.sh mcap 60
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

# /usr/bin first: cargo-fuzz runs `cargo`, which must be Debian's.
export PATH="/usr/bin:/bin:$HOME/.cargo/bin"
export RUSTC=/usr/bin/rustc
export RUSTC_BOOTSTRAP=1
export CARGO=/usr/bin/cargo
export CARGO_TARGET_DIR="$root/target/fuzz"
# One build job beside other work; CI's form (nothing else runs then) uses every core: the cold
# build of the instrumented targets is one of its longest steps.
export CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-$([ "${1:-}" = ci ] && nproc || echo 1)}"
unset RUSTFLAGS
[ -x "$RUSTC" ] && [ -x "$CARGO" ] || { echo "fuzz: Debian rustc-web/cargo-web missing: run scripts/setup-cross.sh" >&2; exit 1; }
local_fuzz="$root/target/cargo-fuzz/bin/cargo-fuzz"
find_fuzz() { fuzz=${CARGO_FUZZ_BIN:-$(command -v cargo-fuzz || true)}; [ -n "$fuzz" ] || { [ -x "$local_fuzz" ] && fuzz=$local_fuzz; } || true; }
install_fuzz() {
  find_fuzz
  [ -n "$fuzz" ] && return 0
  echo "fuzz: installing cargo-fuzz 0.13.2 into target/cargo-fuzz"
  CARGO_TARGET_DIR="$root/target/cargo-fuzz/build" "$CARGO" install --quiet --locked --version 0.13.2 \
      --root "$root/target/cargo-fuzz" cargo-fuzz
  fuzz=$local_fuzz
}
find_fuzz
case "${1:-}" in install|ci) install_fuzz ;; esac
[ -n "$fuzz" ] || { echo "fuzz: cargo-fuzz missing: scripts/fuzz.sh install" >&2; exit 1; }

targets=$(sed -n 's/^name = "\(.*\)"$/\1/p' fuzz/Cargo.toml | grep -v '^povins-fuzz$')
cmd=${1:-}
secs=${2:-60}
case "$cmd" in
  list) echo "$targets"; exit 0 ;;
  build) (cd fuzz && "$fuzz" fuzz build -O -s none); exit 0 ;;
  install) echo "fuzz: $fuzz"; exit 0 ;;
  all) run=$targets ;;
  ci) run=$targets; secs=${2:-10}; ci=1 ;;
  cmin) list=$([ "${2:?cmin TARGET|all}" = all ] && echo "$targets" || echo "$2")
        for t in $list; do (cd fuzz && "$fuzz" fuzz cmin -O -s none "$t" "$root/fuzz/corpus/$t") > "$CARGO_TARGET_DIR/cmin-$t.log" 2>&1
          echo "$t: corpus $(ls "fuzz/corpus/$t" | wc -l) files, $(du -sb "fuzz/corpus/$t" | cut -f1) bytes"; done
        exit 0 ;;
  "") sed -n "2,15p" "$0"; exit 2 ;;
  *) echo "$targets" | grep -qx "$cmd" || { echo "fuzz: no target $cmd (scripts/fuzz.sh list)" >&2; exit 2; }
     run=$cmd ;;
esac

"$RUSTC" --version
(cd fuzz && "$fuzz" fuzz build -O -s none)
# Readers that only open paths get each input as a file here.
scratch=$(mktemp -d -p "$( [ -d /dev/shm ] && echo /dev/shm || echo "${TMPDIR:-/tmp}" )" povins-fuzz.XXXXXX)
trap 'rm -rf "$scratch"' EXIT
export POVINS_FUZZ_SCRATCH=$scratch
status=0
for t in $run; do
  # The CI form reads the committed corpus as seeds only (new inputs and crashes go to scratch)
  # and fuzzes in this process (its output straight into the log, no fuzz/fuzz-0.log).
  if [ -n "${ci:-}" ]; then
    corpus=("$scratch/corpus-$t" "$root/fuzz/corpus/$t"); artifacts="$scratch/artifacts-$t"
    mkdir -p "$scratch/corpus-$t" "$artifacts"; jobs=()
  else
    corpus=("$root/fuzz/corpus/$t"); artifacts="$root/fuzz/artifacts/$t"
    mkdir -p "fuzz/corpus/$t" "$artifacts"; jobs=(-jobs=1 -workers=1)
  fi
  log="$CARGO_TARGET_DIR/fuzz-${ci:+ci-}$t.log"
  echo "== $t for $secs s (log $log)"
  # -timeout: an input taking longer is a hang; -rss_limit_mb: more memory is an OOM.
  ok=1
  # shellcheck disable=SC2086
  (cd fuzz && "$fuzz" fuzz run -O -s none "$t" "${corpus[@]}" -- "${jobs[@]}" \
      -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
      -artifact_prefix="$artifacts/" ${FUZZ_FLAGS:-}) > "$log" 2>&1 || ok=0
  # With -jobs the fuzzing runs in a child process whose output goes to fuzz-JOB.log.
  if [ -z "${ci:-}" ] && [ -f fuzz/fuzz-0.log ]; then cat fuzz/fuzz-0.log >> "$log"; rm -f fuzz/fuzz-0.log; fi
  if [ "$ok" = 0 ]; then
    status=1; echo "   FAILED: see $log and $artifacts/"
    if [ -n "${ci:-}" ]; then
      grep -a -v '^#' "$log" | tail -40
      for a in "$artifacts"/*; do [ -f "$a" ] && { echo "   input $a:"; od -A d -t x1 "$a" | head -20; }; done
    fi
  fi
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  cov=$(grep -ao 'cov: [0-9]*' "$log" | tail -1 || true)
  echo "   $t: ${execs:-?} executions, ${rate:-?}/s, $cov, corpus $(ls "fuzz/corpus/$t" | wc -l) files"
done
exit $status
