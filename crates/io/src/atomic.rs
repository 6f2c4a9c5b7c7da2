//! Atomic output (in progress).
