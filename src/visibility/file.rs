//! The visibility file (`.vis`): magic, version, the geometry fingerprint of the level it was
//! made for, the atlas width and height, the body's length and the body (postcard), and an
//! FNV-1a checksum of everything before it (little-endian throughout). Written
//! atomically; a wrong, truncated or damaged file is an error naming it.

use std::path::{Path, PathBuf};

use super::Visibility;
use crate::fingerprint::{fnv1a, FNV_START};

const MAGIC: [u8; 8] = *b"PRMVIS\0\n";
const VERSION: u32 = 2;
/// Bytes before the body.
const HEADER: usize = 36;

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
    let mut bytes = Vec::with_capacity(body.len() + HEADER + 8);
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&VERSION.to_le_bytes());
    bytes.extend_from_slice(&level.to_le_bytes());
    bytes.extend_from_slice(&vis.width.to_le_bytes());
    bytes.extend_from_slice(&vis.height.to_le_bytes());
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
    let len = check_header(path, &bytes)?;
    if bytes.len() != HEADER + len + 8 {
        return Err(bad(&format!("{} bytes, the header says {}", bytes.len(), HEADER + len + 8)));
    }
    if fnv1a(FNV_START, &bytes[..HEADER + len]) != word(&bytes, HEADER + len) {
        return Err(bad("checksum mismatch"));
    }
    let found = word(&bytes, 12);
    if found != level {
        return Err(VisibilityError::OtherLevel { path: path.into(), found, expected: level });
    }
    let vis: Visibility =
        postcard::from_bytes(&bytes[HEADER..HEADER + len]).map_err(|e| bad(&format!("body: {e}")))?;
    vis.check(texels).map_err(|e| bad(&e))?;
    Ok(vis)
}

/// The atlas width and height a visibility file was made for, from its header alone (to load
/// the level at that size before reading the rest).
pub fn visibility_atlas(path: &Path) -> Result<(u32, u32), VisibilityError> {
    let mut head = [0u8; HEADER];
    let io = |source| VisibilityError::Io { path: path.into(), source };
    let mut f = std::fs::File::open(path).map_err(io)?;
    std::io::Read::read_exact(&mut f, &mut head)
        .map_err(|_| VisibilityError::Corrupt { path: path.into(), what: "no visibility header".into() })?;
    check_header(path, &head)?;
    let half = |at: usize| u32::from_le_bytes(head[at..at + 4].try_into().unwrap_or_default());
    Ok((half(20), half(24)))
}

/// Magic and version; the body's length.
fn check_header(path: &Path, bytes: &[u8]) -> Result<usize, VisibilityError> {
    let bad = |what: &str| VisibilityError::Corrupt { path: path.into(), what: what.into() };
    if bytes.len() < HEADER || bytes[..8] != MAGIC {
        return Err(bad("no visibility header"));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(bad(&format!("version {version}, this build reads {VERSION}")));
    }
    Ok(usize::try_from(word(bytes, 28)).unwrap_or(usize::MAX).min(1 << 40))
}

fn word(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap_or_default())
}
