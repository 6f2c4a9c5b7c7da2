//! Image I/O (in progress).
