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
