//! Hand-rolled dense solver: caller-owned workspaces, symmetric block assembly, in-place LDLT, Levenberg-Marquardt, Schur marginalization into a square-root prior.
