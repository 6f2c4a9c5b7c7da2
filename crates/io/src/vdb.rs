//! OpenVDB reading and writing (in progress).
