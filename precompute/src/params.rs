//! Parameter errors shared by the bakers' parameter structs: which parameter, its value and
//! what it may be, so the CLI and a library caller get the same message.

use std::fmt::Display;

/// A parameter outside what the baker accepts.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{name} {value} must be {allowed}")]
pub struct ParamError {
    /// The parameter, as the CLI names it (without the dashes; words, not hyphens).
    pub name: &'static str,
    /// Its value, as given.
    pub value: String,
    /// What it may be.
    pub allowed: &'static str,
}

/// `Err` naming `name`, `value` and `allowed` unless `ok`.
pub(crate) fn require(
    ok: bool,
    name: &'static str,
    value: impl Display,
    allowed: &'static str,
) -> Result<(), ParamError> {
    if ok {
        Ok(())
    } else {
        Err(ParamError { name, value: value.to_string(), allowed })
    }
}

/// A lightmap atlas a baker accepts: pages of 1 to 8192 texels a side, 1 to
/// [`prm::density::MAX_PAGES`] of them.
pub(crate) fn require_atlas(atlas: prm::density::Atlas) -> Result<(), ParamError> {
    require((1..=8192).contains(&atlas.side), "atlas", atlas.side, "1 to 8192")?;
    require((1..=prm::density::MAX_PAGES).contains(&atlas.pages), "atlas pages", atlas.pages, "1 to 256")
}
