//! Helpers shared by the host-tools tests that run the `povins` binary.

use std::process::Command;

/// `povins ARGS` -> (success, stdout, stderr). With `POVINS_TEST_RUNNER` set (whitespace-separated
/// command, e.g. `qemu-aarch64-static -L /usr/aarch64-linux-gnu` in `scripts/cross-check.sh`), the
/// binary runs through it: a cross-compiled test cannot exec its target's binary directly.
pub fn povins(args: &[&str]) -> (bool, String, String) {
    let exe = env!("CARGO_BIN_EXE_povins");
    let runner = std::env::var("POVINS_TEST_RUNNER").unwrap_or_default();
    let mut parts = runner.split_whitespace();
    let mut cmd = match parts.next() {
        Some(program) => {
            let mut c = Command::new(program);
            c.args(parts).arg(exe);
            c
        }
        None => Command::new(exe),
    };
    let out = cmd
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {exe} (runner {runner:?}): {e}"));
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `povins simulate --scenario SCENARIO --seed SEED --duration SECONDS --format FORMAT --out
/// OUT` with `extra` arguments; panics with simulate's error when it fails, else returns its
/// stderr.
#[allow(dead_code)] // Not every test binary that includes this module simulates.
pub fn simulate(
    scenario: &str,
    seed: &str,
    seconds: &str,
    format: &str,
    out: &std::path::Path,
    extra: &[&str],
) -> String {
    let out = out.to_str().expect("utf-8 path");
    let mut args = vec![
        "simulate",
        "--scenario",
        scenario,
        "--seed",
        seed,
        "--duration",
        seconds,
        "--format",
        format,
        "--out",
        out,
    ];
    args.extend_from_slice(extra);
    let (ok, _, err) = povins(&args);
    assert!(
        ok,
        "simulate {scenario} seed {seed} as {format} failed: {err}"
    );
    err
}

/// [`simulate`] of the hand-held scenario (seed 3) with images, `seconds` long, written as
/// `format` to `out`, with `extra` arguments (e.g. `--lidar none`, `--compression lz4`).
#[allow(dead_code)] // Not every test binary that includes this module simulates.
pub fn simulate_handheld(
    format: &str,
    out: &std::path::Path,
    seconds: &str,
    extra: &[&str],
) -> String {
    let mut args = vec!["--images"];
    args.extend_from_slice(extra);
    simulate("handheld", "3", seconds, format, out, &args)
}
