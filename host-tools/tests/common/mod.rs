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

/// `$env_var`, else the interpreter of the venv `<repo>/target/<venv>` holding `pkgs` (pip
/// requirements; `imports` is the import line that proves them installed), made on first use by
/// `scripts/pyenv.sh` (needs PyPI; without it the calling test fails saying so).
#[allow(dead_code)]
pub fn venv_python(env_var: &str, venv: &str, imports: &str, pkgs: &[&str]) -> std::path::PathBuf {
    if let Some(p) = std::env::var_os(env_var) {
        return p.into();
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = Command::new("bash")
        .arg(root.join("scripts/pyenv.sh"))
        .arg(root.join("target").join(venv))
        .arg(imports)
        .args(pkgs)
        .output()
        .unwrap_or_else(|e| panic!("scripts/pyenv.sh: could not start bash: {e}"));
    assert!(
        out.status.success(),
        "scripts/pyenv.sh failed (needs PyPI for {pkgs:?}): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::path::PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// The independent ROS tools (`rosbags`, `mcap`, `mcap-ros1-support`, numpy):
/// [`venv_python`] of `target/pyenv-rosbags`, or `POVINS_ROSBAGS_PYTHON`.
#[allow(dead_code)]
pub fn rosbags_python() -> std::path::PathBuf {
    venv_python(
        "POVINS_ROSBAGS_PYTHON",
        "pyenv-rosbags",
        "rosbags, yaml, mcap, mcap_ros1, numpy",
        &[
            "rosbags==0.11.9",
            "pyyaml",
            "mcap==1.6.0",
            "mcap-ros1-support==0.9.0",
            "numpy",
        ],
    )
}

/// Python with the Ouster SDK (`ouster-sdk` 1.0.1, which pins `rosbags` 0.9, hence a venv of its
/// own): [`venv_python`] of `target/pyenv-ouster`, or `POVINS_OUSTER_PYTHON` (the same venv as
/// `platform/tests/ouster_sdk.rs`).
#[allow(dead_code)]
pub fn ouster_python() -> std::path::PathBuf {
    venv_python(
        "POVINS_OUSTER_PYTHON",
        "pyenv-ouster",
        "ouster.sdk.pcap, numpy",
        &["ouster-sdk==1.0.1"],
    )
}

/// Python with `pymavlink` 2.4.49: [`venv_python`] of `target/pyenv-mavlink`, or
/// `POVINS_MAVLINK_PYTHON`.
#[allow(dead_code)]
pub fn pymavlink_python() -> std::path::PathBuf {
    venv_python(
        "POVINS_MAVLINK_PYTHON",
        "pyenv-mavlink",
        "pymavlink",
        &["pymavlink==2.4.49"],
    )
}

/// Python with `websockets` and `protobuf` (an independent Foxglove WebSocket client,
/// `scripts/foxglove_client.py`): [`venv_python`] of `target/pyenv-foxglove`, or
/// `POVINS_FOXGLOVE_PYTHON`.
#[allow(dead_code)]
pub fn foxglove_python() -> std::path::PathBuf {
    venv_python(
        "POVINS_FOXGLOVE_PYTHON",
        "pyenv-foxglove",
        "websockets, google.protobuf",
        &["websockets==15.0.1", "protobuf==6.31.1"],
    )
}

/// The (offset, length) of every chunk record (opcode, length and body) of MCAP bytes `d`.
#[allow(dead_code)]
pub fn mcap_chunks(d: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= d.len() {
        let len = u64::from_le_bytes(d[pos + 1..pos + 9].try_into().expect("8 bytes")) as usize;
        match d[pos] {
            0x06 => out.push((pos, 9 + len)),
            0x02 => break,
            _ => {}
        }
        pos += 9 + len;
    }
    out
}
