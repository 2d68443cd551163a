//! Command-line switches of `povins run` / `demo` / `replay` / `timing` that override the
//! configuration file.

use povins_core::estimator::VisualMode;
use povins_core::lidar::{LdmMode, LidarConfig};

/// Visual mode names on the command line (`--mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModeArg {
    /// PO-VINS pose-only visual measurements.
    PoseOnly,
    /// Conventional inverse-depth bundle adjustment (LE-VINS-WO).
    InverseDepth,
}

impl From<ModeArg> for VisualMode {
    fn from(m: ModeArg) -> Self {
        match m {
            ModeArg::PoseOnly => VisualMode::PoseOnly,
            ModeArg::InverseDepth => VisualMode::InverseDepth,
        }
    }
}

/// LiDAR-depth measurement names on the command line (`--ldm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LdmArg {
    /// MSC-based LiDAR-depth measurement (PO-VINS, paper eq. 25-30).
    Msc,
    /// Direct LiDAR-depth measurement (paper eq. 24).
    Direct,
}

impl From<LdmArg> for LdmMode {
    fn from(m: LdmArg) -> Self {
        match m {
            LdmArg::Msc => LdmMode::Msc,
            LdmArg::Direct => LdmMode::Direct,
        }
    }
}

/// The command-line / JSON name of an LDM mode.
pub fn ldm_name(m: LdmMode) -> &'static str {
    match m {
        LdmMode::Msc => "msc",
        LdmMode::Direct => "direct",
    }
}

/// Run-time LiDAR switches (paper Table VI ablations); they override the TOML file.
#[derive(clap::Args, Debug, Clone, Default, PartialEq, Eq)]
pub struct LidarArgs {
    /// Ignore the LiDAR (PO-VINS-WO).
    #[arg(long)]
    pub no_lidar: bool,
    /// LiDAR-depth measurement model.
    #[arg(long, value_enum)]
    pub ldm: Option<LdmArg>,
    /// Keep every associated LiDAR depth (no uncertainty-based rejection).
    #[arg(long)]
    pub no_depth_outlier_rejection: bool,
    /// Skip the depth-only optimization of LiDAR landmarks.
    #[arg(long)]
    pub no_depth_only_opt: bool,
}

impl LidarArgs {
    /// Whether any switch was given.
    pub fn any(&self) -> bool {
        self.no_lidar
            || self.ldm.is_some()
            || self.no_depth_outlier_rejection
            || self.no_depth_only_opt
    }

    /// Applies the switches to `cfg`.
    pub fn apply(&self, cfg: &mut LidarConfig) {
        if self.no_lidar {
            cfg.enabled = false;
        }
        if let Some(m) = self.ldm {
            cfg.ldm = m.into();
        }
        if self.no_depth_outlier_rejection {
            cfg.depth_outlier_rejection = false;
        }
        if self.no_depth_only_opt {
            cfg.depth_only_opt = false;
        }
    }
}
