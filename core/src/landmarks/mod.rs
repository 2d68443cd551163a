//! Landmark geometry: pose-only depth and its analytic uncertainty, landmark bookkeeping.

pub mod manager;
