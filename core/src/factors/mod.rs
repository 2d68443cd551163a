//! Residual factors: IMU preintegration, pose-only visual reprojection, inverse-depth reprojection (baseline), time-delay random walk.
