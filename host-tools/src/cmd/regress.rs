//! `povins regress`: the accuracy regression suite (see [`crate::regress`]).

use crate::config::RunConfigFile;
use crate::progress::Progress;
use crate::regress::{compare, render, render_variant_figures, run_all, sequences, Baseline};
use anyhow::{bail, Context, Result};
use std::path::PathBuf;

/// Arguments of `povins regress`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The CI form: eight 30 s seeds per scenario instead of ten of 60 s (real sequences whole;
    /// two seeds were a coin flip, see `regress::QUICK_SEEDS`).
    #[arg(long)]
    pub quick: bool,
    /// Seeds per scenario (default 10, or 8 with `--quick`); the stored figures cover seeds
    /// 1-20 of 60 s and 1-8 of 30 s, a scenario with a seed beyond them is judged on divergence
    /// only.
    #[arg(long)]
    pub seeds: Option<u64>,
    /// Add these variant sequences (on the same seeds, each variant its own group; comma
    /// separated): `delays` (true delays of -30, -10 and +30 ms, not told), `delay-step` (+10 ms
    /// at half the sequence), `motion-start` (the rest and ramp cut away, `--init auto`),
    /// `extrinsic` (the extrinsic started 2 cm and 2 degrees off, estimated).
    #[arg(long, value_delimiter = ',')]
    pub variants: Vec<crate::regress::VariantGroup>,
    /// Folder of the shared datasets.
    #[arg(long, default_value = "../shared/data")]
    pub data: PathBuf,
    /// Stored figures to compare with.
    #[arg(long, default_value = "regress/baseline.json")]
    pub baseline: PathBuf,
    /// Parallel runs.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Store this run's figures as the new baseline (the smoother's figures are kept).
    #[arg(long)]
    pub bless: bool,
    /// Lay this TOML file's keys over every run's configuration (an experiment: the stored
    /// figures are those of the defaults; `--bless` refuses it).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Also write every run's figures as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// First seed of each scenario (1: the stored figures' seeds; a later one runs fresh seeds,
    /// judged on divergence against the stored figures, and fairly with `--compare`).
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Also compare this run sequence by sequence with an earlier run's `--json` file: per
    /// scenario the medians, the geometric mean of the per-seed ratios and the seeds it is
    /// better on (printed; it does not change the exit status).
    #[arg(long)]
    pub compare: Option<PathBuf>,
}

/// Runs the command; an error (non-zero exit) when a figure regressed or a run diverged.
pub fn run(args: Args) -> Result<()> {
    if args.bless && args.config.is_some() {
        bail!("--bless stores the defaults' figures: drop --config");
    }
    let overlay = args
        .config
        .as_deref()
        .map(RunConfigFile::read)
        .transpose()?;
    let old = args
        .compare
        .as_deref()
        .map(crate::regress_paired::read_old)
        .transpose()?;
    if args.bless && args.first_seed != 1 {
        bail!("--bless stores the figures of seeds from 1: drop --first-seed");
    }
    let seqs = sequences(
        &args.data,
        args.quick,
        args.seeds,
        args.first_seed,
        &args.variants,
    );
    let progress = Progress::new(seqs.len() as u64, "regress");
    let runs = run_all(&seqs, overlay.as_ref(), args.jobs, &progress)?;
    let mut base = if args.baseline.exists() {
        Baseline::read(&args.baseline)?
    } else if args.bless {
        Baseline::default()
    } else {
        bail!(
            "no baseline at {} (run with --bless to create it)",
            args.baseline.display()
        );
    };
    let rows = compare(&runs, &base);
    println!("{}", render(&rows));
    if let Some(t) = render_variant_figures(&runs) {
        println!("{t}");
    }
    if let (Some(old), Some(p)) = (&old, &args.compare) {
        let paired = crate::regress_paired::paired(old, &runs);
        let name = p.display().to_string();
        println!("{}", crate::regress_paired::render_paired(&paired, &name));
    }
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&runs)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if args.bless {
        // A run that never started has no figure to store (JSON has no infinity).
        for r in runs.iter().filter(|r| r.ate_m.is_finite()) {
            base.ate_m.insert(r.name.clone(), r.ate_m);
        }
        let text = serde_json::to_string_pretty(&base)? + "\n";
        std::fs::write(&args.baseline, text)
            .with_context(|| format!("cannot write {}", args.baseline.display()))?;
        println!(
            "stored {} figures in {}",
            runs.len(),
            args.baseline.display()
        );
        return Ok(());
    }
    let failed: Vec<&str> = rows
        .iter()
        .filter(|r| !r.pass)
        .map(|r| r.name.as_str())
        .collect();
    if !failed.is_empty() {
        bail!(
            "accuracy regression (more than {:.0}% worse than stored, or diverged): {}",
            100.0 * (crate::regress::TOLERANCE - 1.0),
            failed.join(", ")
        );
    }
    Ok(())
}
