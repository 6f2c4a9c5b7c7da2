//! Binary USD crate files (`.usdc`, and `.usd` files that start with
//! `PXR-USDC`): a reader that turns a crate file's specs into the text
//! layer the text reader reads, and a writer of the groom layer.
//!
//! The format: an 88-byte bootstrap header gives the version and where the
//! table of contents is; the table names six sections. `TOKENS` holds
//! every name, `STRINGS` indexes tokens, `FIELDS` pairs a name with a
//! 64-bit value representation, `FIELDSETS` lists each spec's fields,
//! `PATHS` codes the path tree and `SPECS` ties a path to its fields and
//! kind (pseudo-root, prim, attribute, ...). Values too large for their
//! representation live elsewhere in the file at the offset it gives.
//! Versions 0.4.0 and later are read (all of them compress the sections:
//! LZ4 blocks and an integer coding, [`codec`]); the writer writes 0.8.0,
//! the reference library's default. One file per job: [`toc`] (bootstrap
//! and table of contents), [`sections`] (the structural tables),
//! [`codec`] (compression), [`unpack`] (value representations to
//! [`value::Value`]s), [`text`] (specs to a text layer), [`build`] (a groom
//! to specs) and [`pack`] (specs to bytes).

mod build;
mod codec;
mod pack;
mod sections;
mod text;
mod toc;
mod unpack;
pub(crate) mod value;

pub(crate) use build::unwritable;
pub(crate) use toc::MAGIC;

use crate::groom::{Groom, UsdPrimvars};
use crate::ErrorKind;

/// The crate file `bytes` as a text layer (see [`text`] for what it holds).
pub(crate) fn layer_text(bytes: &[u8]) -> Result<String, ErrorKind> {
    let toc = toc::read_toc(bytes)?;
    let tables = sections::read_tables(bytes, &toc)?;
    let u = unpack::Unpacker::new(bytes, &tables, &toc);
    text::layer_text(&u)
}

/// `groom` and `primvars` as a crate file (see [`build`]); the caller has
/// checked them as the text writer does.
pub(crate) fn groom_bytes(groom: &Groom, primvars: &UsdPrimvars) -> Result<Vec<u8>, String> {
    pack::pack(&build::groom_specs(groom, primvars))
}
