//! The fp32 product kernel of the Winograd convolution lives in
//! `nst3d_core::microkernel` (NNST matching uses it too).

pub(crate) use nst3d_core::microkernel::{has_avx2, has_avx512, kernel, Blocking, NR_MIN, ROW_ALIGN};
