//! Host package for workspace tests and benches.
