//! The online camera-IMU delay converges from a blind start (issue 31, item 4): a simulated calm
//! flight with a true delay of -30 ms, run with `td_s = 0`, must be within 1.5 ms of the truth
//! at 20 s and at the end. Before 2026-12-02 the first keyframe's 5 ms delay prior, kept by the
//! marginalization, held this flight 3.6 ms off at 20 s (-26.4 ms; 0.03 ms off since).
//!
//! The rolling shutter (issue 31, item 7): a hand-held sequence whose rows are read out over
//! 30 ms is estimated about as well as the same sequence with a global shutter when the readout
//! is modelled, and breaks down when it is not.

mod common;

use common::{povins, simulate};

/// The keyframe delays `(t_s, td_ms)` of a run's `stats.csv`, columns selected by header name.
fn keyframe_delays(stats: &std::path::Path) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(stats).expect("stats.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (t, td) = (col("t_s"), col("td_ms"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[t].parse().expect("t_s"), f[td].parse().expect("td_ms"))
        })
        .collect()
}

#[test]
fn a_blind_delay_converges_on_a_calm_flight() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (data, out) = (dir.path().join("flight"), dir.path().join("run"));
    let cfg = dir.path().join("blind.toml");
    std::fs::write(&cfg, "td_s = 0.0\n").expect("config");
    simulate(
        "flight",
        "3",
        "60",
        "euroc",
        &data,
        &[
            "--td-ms",
            "-30",
            "--wrong-track-rate",
            "0.03",
            "--lidar",
            "none",
        ],
    );
    let (data, out, cfg) = (
        data.to_str().expect("utf-8"),
        out.to_str().expect("utf-8"),
        cfg.to_str().expect("utf-8"),
    );
    let (ok, _, err) = povins(&[
        "run",
        data,
        "--frontend",
        "tracks",
        "--config",
        cfg,
        "--out",
        out,
    ]);
    assert!(ok, "run: {err}");
    let delays = keyframe_delays(&dir.path().join("run").join("stats.csv"));
    let &(t_end, td_end) = delays.last().expect("keyframes");
    assert!(t_end > 55.0, "the run ended at {t_end} s");
    // The blind start stays at 0 until the data carry information on the delay.
    let (_, td_first) = delays[0];
    assert_eq!(td_first, 0.0);
    // 20 s after the first IMU sample (at 1 s on the sequence clock).
    let &(_, td_20) = delays
        .iter()
        .rfind(|(t, _)| *t <= 21.0)
        .expect("a keyframe by 21 s");
    for (when, td) in [("at 20 s", td_20), ("at the end", td_end)] {
        assert!(
            (td + 30.0).abs() <= 1.5,
            "the delay {when} is {td:.2} ms for a true -30 ms"
        );
    }
}

/// The position ATE of a run's `summary.json`, m.
fn ate_m(run: &std::path::Path) -> f64 {
    let text = std::fs::read_to_string(run.join("summary.json")).expect("summary.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    v["ate_pos_rmse_m"].as_f64().expect("ate_pos_rmse_m")
}

#[test]
fn a_rolling_shutter_is_modelled() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |n: &str| dir.path().join(n);
    let s = |n: &str| p(n).to_str().expect("utf-8").to_string();
    for (name, readout_ms) in [("global", "0"), ("rolling", "30")] {
        simulate(
            "handheld",
            "1",
            "30",
            "euroc",
            &p(name),
            &["--readout-ms", readout_ms, "--lidar", "none"],
        );
    }
    std::fs::write(p("no-readout.toml"), "[camera]\nreadout_s = 0.0\n").expect("config");
    let run = |data: &str, out: &str, extra: &[&str]| {
        let mut args = vec!["run", data, "--frontend", "tracks", "--out", out];
        args.extend_from_slice(extra);
        let (ok, _, err) = povins(&args);
        assert!(ok, "run {out}: {err}");
        ate_m(&p(out))
    };
    let global = run(&s("global"), &s("g"), &[]);
    // The calibration the simulator writes carries the readout: modelled by default.
    let modelled = run(&s("rolling"), &s("m"), &[]);
    let ignored = run(&s("rolling"), &s("u"), &["--config", &s("no-readout.toml")]);
    eprintln!("ATE global {global:.3} m, rolling modelled {modelled:.3} m, ignored {ignored:.3} m");
    // Measured 0.189 / 0.217 / 27.0 m on 2026-12-03.
    assert!(
        modelled <= 1.5 * global,
        "modelled {modelled} m against {global} m"
    );
    assert!(
        ignored >= 5.0 * modelled,
        "ignored {ignored} m against {modelled} m"
    );
}
