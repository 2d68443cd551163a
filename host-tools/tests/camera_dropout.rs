//! Issue 32: a 3 s camera dropout costs the run little. The window cannot hold the dropout (its
//! open interval fills up after 2.5 s) and is dropped, the INS goes on alone, and the frames after
//! the dropout start a new window: from the dropped window's covariance propagated over the
//! dropout, not from the wide re-initialization prior, which lost what the healthy window knew
//! of velocity and biases (the fault suite's flight seeds 1-3: ATE 2.9-4.0x the fault-free run
//! with the wide prior, 1.7-2.7x with the dropped window's covariance). The median is taken over
//! nine seeds (single runs are chaotic: since the anchor's bearing is solved for, session 51,
//! seeds 1-3 alone give 1.66 / 3.81 / 3.81 and seeds 1-9 a median of 1.86; before it 1.74).

use povins_host_tools::regress::{run_sequence, Fault, Sequence, Variant};
use povins_host_tools::sim::Scenario;

fn run(seed: u64, variant: Variant) -> povins_host_tools::regress::RunResult {
    let seq = Sequence::Sim {
        scenario: Scenario::Flight,
        seed,
        duration_s: 30.0,
        variant,
    };
    run_sequence(&seq, None).expect("the suite's sequence runs")
}

#[test]
fn a_camera_dropout_restarts_from_the_dropped_windows_covariance() {
    let mut ratios = Vec::new();
    for seed in 1..=9 {
        let clean = run(seed, Variant::Standard);
        let r = run(seed, Variant::Fault(Fault::CameraDropout));
        assert_eq!(r.resets, 0, "seed {seed}: {r:?}");
        assert_eq!(r.reinitializations, 1, "seed {seed}: one new window, {r:?}");
        assert!(r.coverage > 0.95, "seed {seed}: {r:?}");
        ratios.push(r.ate_m / clean.ate_m);
    }
    ratios.sort_by(f64::total_cmp);
    println!("ATE ratios dropout / clean, flight seeds 1-9: {ratios:.2?}");
    // The wide prior's median (seeds 1-3): 3.53.
    assert!(ratios[4] < 2.5, "{ratios:?}");
}
