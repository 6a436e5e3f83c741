//! The part files (module `shard` doc): the writer that hashes a part as a shard writes it,
//! and the merge's checks of the parts and its reading of their walks in texel order.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use prm::fingerprint::{fnv1a, FNV_START};

use super::{file_error, shard_texels, Plan, ShardError, PART_HEADER, PART_MAGIC, VERSION};
use crate::transport::TexelPanes;

/// A writer that keeps the FNV-1a 64 and the count of the bytes that went through it.
pub(super) struct Hashing<W: Write> {
    pub(super) inner: W,
    pub(super) hash: u64,
    pub(super) bytes: u64,
}

impl<W: Write> Hashing<W> {
    pub(super) fn new(inner: W) -> Self {
        Hashing { inner, hash: FNV_START, bytes: 0 }
    }
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash = fnv1a(self.hash, &buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// One part, checked: where it is, which shard of how many, its texels and counters.
pub(super) struct Part {
    path: PathBuf,
    index: u32,
    count: u32,
    texels: Range<usize>,
    /// Walks cut, unowned vertices, rays, virtual lights.
    pub(super) counters: [u64; 4],
    /// The checksum it ends with, and the file's length.
    checksum: u64,
    bytes: u64,
}

/// Read a part's header and end (its checksum is checked as it is read: `PartWalks`).
fn check_part(path: &Path) -> Result<(Part, u64), ShardError> {
    let bad = |problem: &str| file_error(path, problem);
    let io = |e: std::io::Error| file_error(path, format!("cannot be read: {e}"));
    let mut file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len < (PART_HEADER + 4 + 32 + 8) as u64 {
        return Err(bad("not a shard's part (too short)"));
    }
    let mut head = [0u8; PART_HEADER];
    file.read_exact(&mut head).map_err(io)?;
    if head[..8] != PART_MAGIC {
        return Err(bad("not a shard's part (from `prm precompute --shard`)"));
    }
    let u32_at = |k: usize| u32::from_le_bytes(head[k..k + 4].try_into().unwrap_or_default());
    if u32_at(8) != VERSION {
        return Err(bad(&format!(
            "part version {}, this build reads {VERSION}: run the shard again",
            u32_at(8)
        )));
    }
    let plan = u64::from_le_bytes(head[12..20].try_into().unwrap_or_default());
    // The end: the end marker, the counters and the checksum. The checksum itself is checked
    // as the merge reads the part (`PartWalks`): once, not twice.
    let mut tail = [0u8; 44];
    file.seek(SeekFrom::Start(len - 44)).map_err(io)?;
    file.read_exact(&mut tail).map_err(io)?;
    if tail[..4] != [0; 4] {
        return Err(bad("damaged (truncated, or its walks do not end where its counters start)"));
    }
    let word = |k: usize| u64::from_le_bytes(tail[4 + 8 * k..12 + 8 * k].try_into().unwrap_or_default());
    let part = Part {
        path: path.to_path_buf(),
        index: u32_at(20),
        count: u32_at(24),
        texels: u32_at(28) as usize..u32_at(32) as usize,
        counters: [word(0), word(1), word(2), word(3)],
        checksum: word(4),
        bytes: len,
    };
    Ok((part, plan))
}

/// The parts' walks in texel order, read a chunk at a time.
pub(super) struct PartWalks {
    pub(super) parts: Vec<Part>,
    /// The part being read (an index into `parts`) and its reader.
    current: usize,
    reader: Option<BufReader<File>>,
    /// The texel the next walk read belongs to.
    next: usize,
    /// Walks read and not yet taken, from texel `next - ahead.len()`.
    ahead: std::collections::VecDeque<TexelPanes>,
    /// FNV-1a 64 of the current part's bytes read so far.
    hash: u64,
}

impl PartWalks {
    pub(super) fn new(parts: Vec<Part>) -> PartWalks {
        PartWalks { parts, current: 0, reader: None, next: 0, ahead: Default::default(), hash: FNV_START }
    }

    /// The walks of texels `range` (ascending from one call to the next).
    pub(super) fn take(&mut self, range: Range<usize>) -> Result<Vec<TexelPanes>, ShardError> {
        while self.next < range.end {
            self.read_chunk()?;
        }
        let first = self.next - self.ahead.len();
        let skip = range.start.saturating_sub(first).min(self.ahead.len());
        self.ahead.drain(..skip);
        Ok(self.ahead.drain(..range.len().min(self.ahead.len())).collect())
    }

    /// Read what is left of every part, checking their checksums (the last part's end has
    /// not been read when the last texel has).
    pub(super) fn finish(&mut self) -> Result<(), ShardError> {
        while self.current < self.parts.len() {
            self.read_chunk()?;
            self.ahead.clear();
        }
        Ok(())
    }

    fn read_chunk(&mut self) -> Result<(), ShardError> {
        let Some(part) = self.parts.get(self.current) else {
            return Err(ShardError::Parts("the parts hold fewer texels than the plan".into()));
        };
        let path = part.path.clone();
        let io = |e: std::io::Error| file_error(&path, format!("cannot be read: {e}"));
        let reader = match self.reader.as_mut() {
            Some(r) => r,
            None => {
                let mut reader = BufReader::with_capacity(1 << 20, File::open(&path).map_err(io)?);
                let mut head = [0u8; PART_HEADER];
                reader.read_exact(&mut head).map_err(io)?;
                self.hash = fnv1a(FNV_START, &head);
                self.reader.insert(reader)
            }
        };
        let mut word = [0u8; 4];
        reader.read_exact(&mut word).map_err(io)?;
        self.hash = fnv1a(self.hash, &word);
        let texels = u32::from_le_bytes(word) as usize;
        if texels == 0 {
            let mut counters = [0u8; 32];
            reader.read_exact(&mut counters).map_err(io)?;
            if fnv1a(self.hash, &counters) != part.checksum {
                return Err(file_error(&path, "damaged (its checksum does not match: truncated or altered)"));
            }
            if self.next != part.texels.end {
                return Err(file_error(&path, "damaged (fewer texels than its header says)"));
            }
            (self.current, self.reader) = (self.current + 1, None);
            return Ok(());
        }
        let mut long = [0u8; 8];
        reader.read_exact(&mut long).map_err(io)?;
        self.hash = fnv1a(self.hash, &long);
        let len = u64::from_le_bytes(long);
        if len > part.bytes {
            return Err(file_error(&path, "damaged (a chunk's length)"));
        }
        let mut bytes = vec![0u8; len as usize];
        reader.read_exact(&mut bytes).map_err(io)?;
        self.hash = fnv1a(self.hash, &bytes);
        let walks: Vec<TexelPanes> = postcard::from_bytes(&bytes)
            .map_err(|e| file_error(&path, format!("damaged (a chunk cannot be decoded: {e})")))?;
        if walks.len() != texels || self.next + texels > part.texels.end {
            return Err(file_error(&path, "damaged (a chunk's texel count)"));
        }
        self.next += texels;
        self.ahead.extend(walks);
        Ok(())
    }
}

/// Check that `parts` are all the shards of `plan`, once each, in any order: each part's
/// shard and the plan's checksum it records.
pub(super) fn check_parts(plan: &Plan, paths: &[PathBuf]) -> Result<Vec<Part>, ShardError> {
    if paths.is_empty() {
        return Err(ShardError::Parts("no parts given".into()));
    }
    let mut parts = Vec::with_capacity(paths.len());
    for path in paths {
        let (part, of_plan) = check_part(path)?;
        if of_plan != plan.checksum {
            return Err(file_error(
                path,
                format!(
                    "a part of another plan (plan checksum {of_plan:016x}, this plan's {:016x}): another \
                     level, other parameters or another --prepare",
                    plan.checksum
                ),
            ));
        }
        parts.push(part);
    }
    let count = parts[0].count;
    if let Some(p) = parts.iter().find(|p| p.count != count) {
        return Err(file_error(
            &p.path,
            format!("shard {} of {}, but {} is of {count}", p.index, p.count, parts[0].path.display()),
        ));
    }
    let texels = plan.preamble.set.len();
    for p in &parts {
        if p.index >= count || p.texels != shard_texels(texels, p.index, count) {
            return Err(file_error(&p.path, "damaged (its shard and texels do not agree with the plan)"));
        }
    }
    parts.sort_by_key(|p| p.index);
    for w in parts.windows(2) {
        if w[0].index == w[1].index {
            return Err(ShardError::Parts(format!(
                "shard {}/{count} given twice: {} and {}",
                w[0].index,
                w[0].path.display(),
                w[1].path.display()
            )));
        }
    }
    let missing: Vec<String> = (0..count)
        .filter(|i| parts.binary_search_by_key(i, |p| p.index).is_err())
        .map(|i| i.to_string())
        .collect();
    if !missing.is_empty() {
        return Err(ShardError::Parts(format!(
            "shard{} {} of {count} missing (given {} parts)",
            if missing.len() > 1 { "s" } else { "" },
            missing.join(", "),
            parts.len()
        )));
    }
    Ok(parts)
}
