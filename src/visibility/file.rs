//! The visibility file (`.vis`): magic, version, the geometry fingerprint of the level it was
//! made for, the body (postcard), and an FNV-1a checksum of everything before it. Written
//! atomically; a wrong, truncated or damaged file is an error naming it.

use std::path::{Path, PathBuf};

use super::Visibility;
use crate::fingerprint::{fnv1a, FNV_START};

const MAGIC: [u8; 8] = *b"PRMVIS\0\n";
const VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum VisibilityError {
    #[error("{path}: cannot read or write the visibility file: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a visibility file, or damaged: {what}")]
    Corrupt { path: PathBuf, what: String },
    #[error("{path}: made for another level (fingerprint {found:016x}, this level {expected:016x}); run `prm visibility` again")]
    OtherLevel { path: PathBuf, found: u64, expected: u64 },
}

/// Write `vis` for the level with geometry fingerprint `level` to `path`, atomically.
pub fn write_visibility(path: &Path, vis: &Visibility, level: u64) -> Result<u64, VisibilityError> {
    let io = |source| VisibilityError::Io { path: path.into(), source };
    let body = postcard::to_stdvec(vis).map_err(|e| io(std::io::Error::other(format!("encoding: {e}"))))?;
    let mut bytes = Vec::with_capacity(body.len() + 36);
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&VERSION.to_le_bytes());
    bytes.extend_from_slice(&level.to_le_bytes());
    bytes.extend_from_slice(&(body.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&body);
    let sum = fnv1a(FNV_START, &bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    crate::fsutil::write_bytes_atomic(path, &bytes).map_err(io)?;
    Ok(bytes.len() as u64)
}

/// Read a visibility file made for the level with geometry fingerprint `level` and `texels`
/// texels; checks magic, version, length, checksum, level and the tables' consistency.
pub fn read_visibility(path: &Path, level: u64, texels: usize) -> Result<Visibility, VisibilityError> {
    let bytes = std::fs::read(path).map_err(|source| VisibilityError::Io { path: path.into(), source })?;
    let bad = |what: &str| VisibilityError::Corrupt { path: path.into(), what: what.into() };
    if bytes.len() < 36 || bytes[..8] != MAGIC {
        return Err(bad("no visibility header"));
    }
    let word = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap_or_default());
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(bad(&format!("version {version}, this build reads {VERSION}")));
    }
    let len = word(20) as usize;
    if bytes.len() != 28 + len + 8 {
        return Err(bad(&format!("{} bytes, the header says {}", bytes.len(), 28 + len + 8)));
    }
    if fnv1a(FNV_START, &bytes[..28 + len]) != word(28 + len) {
        return Err(bad("checksum mismatch"));
    }
    let found = word(12);
    if found != level {
        return Err(VisibilityError::OtherLevel { path: path.into(), found, expected: level });
    }
    let vis: Visibility =
        postcard::from_bytes(&bytes[28..28 + len]).map_err(|e| bad(&format!("body: {e}")))?;
    vis.check(texels).map_err(|e| bad(&e))?;
    Ok(vis)
}
