//! A precompute in parts, for a farm (issue 16): `prm precompute --prepare`, `--shard I/N`
//! and `prm merge`. Each step is a process of its own, so any scheduler can run them (Ray,
//! a Slurm job array, a Kubernetes indexed Job: README):
//!
//! 1. **Plan** ([`plan`]): everything before the walks ([`Preamble`]: texels, entries and
//!    cells, clusters and groups, the near, echo and far fields, the smoothing), once, into a
//!    plan file. It is about a third of a one-machine precompute; made by every shard, it
//!    would cost N times that.
//! 2. **Shards** ([`run_shard`]): shard I of N walks the I-th of N equal runs of the covered
//!    texels (row-major, so a run is a band of atlas rows) and writes every texel's pane
//!    contributions, exactly as the walks return them, to its part file. A texel's walks
//!    depend on the texel alone (their random streams are seeded by its index), so the
//!    parts hold the same numbers a one-machine run computes, whatever N. Runs of texels,
//!    not zones or pages: equal runs balance the shards on any level, and no texel is walked
//!    twice (bands of encoded tiles would walk their smoothing margins twice: 34 rows of a
//!    256-row atlas at N = 8 doubled the walks).
//! 3. **Merge** ([`merge`]): the plan and all N parts, checked, then the panes encoded band by
//!    band from the parts' walks (streamed, a band's at a time), the drop rule and the file:
//!    the same code a one-machine precompute runs after its walks, so the same bytes.
//!
//! Refused: dipole panes (their frames are not in the plan), an update cache.
//!
//! The plan file, little-endian: magic `PRMPLAN\n`, version u32, then two sections in
//! postcard's format (its wire format is stable since 1.0). The first is what the walks need
//! (parameters, the level's geometry hash, texel set, entries, cell owners, clusters, near
//! links and their kept shares): its length u64, its bytes, their FNV-1a 64; a shard reads
//! only it ([`Plan::read_walks`]: on the 4 x 4 halls a third of the plan). The second is the
//! rest the encoding and the file need (the header's fingerprint, counts, cells, centroids,
//! groups, far field, near points, exact first bounce, echo, smoothing). Last, FNV-1a 64 of
//! everything before it: the plan's checksum, which every part records. A part: magic
//! `PRMPART\n`, version u32, the plan's checksum u64,
//! shard index u32, shard count u32, first texel u32, end texel u32; then chunks, each texel
//! count u32 (0 ends them), byte length u64 and the chunk's walks (postcard, per texel its
//! (cluster, RGB) pairs); then walks cut at the bounce cap u64, path vertices with no owning
//! entry u64, rays u64, virtual lights u64; FNV-1a 64 of everything before it.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use prm::fingerprint::{fnv1a, geometry_fingerprint, FNV_START};
use prm::fsutil::{temp_path, write_bytes_atomic};
use prm::prm_file::{Cells, Echo, Entry, Far, NearLink, NearPoint, Prm};
use prm::{Bvh, Scene, Smoothing, TexelSet};

use crate::cells::CellOwners;
use crate::cluster::Clustering;
use crate::parallel::{stop_if, Control};
use crate::precompute::{
    check_params, finish, walk_and_encode, Phase, Preamble, PrecomputeError, PrecomputeParams, Report, Walked,
};
use crate::transport::TexelPanes;

const PLAN_MAGIC: [u8; 8] = *b"PRMPLAN\n";
const PART_MAGIC: [u8; 8] = *b"PRMPART\n";
const VERSION: u32 = 1;
/// Texels walked and written at a time: a shard holds one chunk's walks.
const CHUNK_TEXELS: usize = 4096;
/// Most shards a precompute is cut into.
pub const MAX_SHARDS: u32 = 65536;
/// A part's header: magic, version, plan checksum, index, count, first and end texel.
const PART_HEADER: usize = 8 + 4 + 8 + 4 * 4;

/// Why a sharded step gave no result. Every message names the file it is about.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    #[error(transparent)]
    Precompute(#[from] PrecomputeError),
    /// A plan or part that cannot be read or is not what it should be.
    #[error("{}: {problem}", path.display())]
    File { path: PathBuf, problem: String },
    /// The parts given do not make up the plan's whole (missing, twice, mixed counts).
    #[error("{0}")]
    Parts(String),
    /// This step cannot be done with these inputs.
    #[error("{0}")]
    Refused(String),
}

fn file_error(path: &Path, problem: impl std::fmt::Display) -> ShardError {
    ShardError::File { path: path.to_path_buf(), problem: problem.to_string() }
}

/// A precompute's plan: its parameters and preamble, and the checksum its file ends with
/// (what every part records; 0 until it is written). The checksum (FNV-1a) guards against
/// accidents, not against a file edited on purpose, as the `.prm`'s does. Read for a shard
/// ([`Plan::read_walks`]) it holds only what the walks need, and the merge refuses it.
pub struct Plan {
    pub params: PrecomputeParams,
    pub preamble: Preamble,
    pub checksum: u64,
    walks_only: bool,
}

/// The plan's first section: what the walks need (a shard reads only it).
type Walks =
    (PrecomputeParams, u64, TexelSet, Vec<Entry>, CellOwners, Clustering, Vec<NearLink>, Option<Vec<f32>>);
type WalksRef<'a> = (
    &'a PrecomputeParams,
    u64,
    &'a TexelSet,
    &'a [Entry],
    &'a CellOwners,
    &'a Clustering,
    &'a [NearLink],
    &'a Option<Vec<f32>>,
);
/// Its second: what the encoding and the file need besides.
type Rest = (
    String,
    f32,
    usize,
    f64,
    Cells,
    Vec<glam::Vec3>,
    Option<Clustering>,
    Far,
    Vec<NearPoint>,
    Vec<TexelPanes>,
    Echo,
    Option<Smoothing>,
);
type RestRef<'a> = (
    &'a str,
    f32,
    usize,
    f64,
    &'a Cells,
    &'a [glam::Vec3],
    &'a Option<Clustering>,
    &'a Far,
    &'a [NearPoint],
    &'a [TexelPanes],
    &'a Echo,
    &'a Option<Smoothing>,
);

/// Make the plan (step 1): the preamble of a precompute of `scene` with `params`, timed into
/// the report. Write it ([`Plan::write`]) before running shards of it.
pub fn plan(
    scene: &Scene,
    bvh: &Bvh,
    params: &PrecomputeParams,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<(Plan, Report), ShardError> {
    check_params(scene, params)?;
    if params.dipole_block > 0 {
        return Err(ShardError::Refused(
            "a sharded precompute does not make dipole panes (their frames are not in the plan): \
             leave out --dipole-block"
                .into(),
        ));
    }
    let all = Instant::now();
    let mut report = Report::new(params);
    let preamble = Preamble::build(scene, bvh, params, None, |_| Ok(()), &mut report, progress, cancel)?;
    report.seconds_total = all.elapsed().as_secs_f64();
    // Its checksum is known once it is encoded ([`Plan::write`]).
    let plan = Plan { params: params.clone(), preamble, checksum: 0, walks_only: false };
    Ok((plan, report))
}

fn checksum_of(file: &[u8]) -> u64 {
    let tail: [u8; 8] = file[file.len().saturating_sub(8)..].try_into().unwrap_or_default();
    u64::from_le_bytes(tail)
}

impl Plan {
    /// The level's covered texels, which the shards share out.
    pub fn texels(&self) -> usize {
        self.preamble.set.len()
    }

    /// The plan file's bytes (module doc).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ShardError> {
        if self.walks_only {
            return Err(ShardError::Refused("a plan read for a shard cannot be written".into()));
        }
        let (p, pre) = (&self.params, &self.preamble);
        let walks: WalksRef =
            (p, pre.geometry, &pre.set, &pre.entries, &pre.owners, &pre.clustering, &pre.near, &pre.keep);
        let rest: RestRef = (
            &pre.fingerprint,
            pre.page_texel_size,
            pre.enclosed,
            pre.area_without_entry,
            &pre.cells,
            &pre.centroids,
            &pre.grouping,
            &pre.far,
            &pre.near_points,
            &pre.exact,
            &pre.echo,
            &pre.smoothing,
        );
        let encode = |e: postcard::Error| ShardError::Refused(format!("the plan cannot be encoded: {e}"));
        let walks = postcard::to_stdvec(&walks).map_err(encode)?;
        let rest = postcard::to_stdvec(&rest).map_err(encode)?;
        let mut out = Vec::with_capacity(walks.len() + rest.len() + 36);
        out.extend_from_slice(&PLAN_MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&(walks.len() as u64).to_le_bytes());
        out.extend_from_slice(&walks);
        out.extend_from_slice(&fnv1a(FNV_START, &walks).to_le_bytes());
        out.extend_from_slice(&rest);
        let sum = fnv1a(FNV_START, &out);
        out.extend_from_slice(&sum.to_le_bytes());
        Ok(out)
    }

    /// Write the plan file atomically, and set the checksum its parts will record; its size
    /// in bytes.
    pub fn write(&mut self, path: &Path) -> Result<usize, ShardError> {
        let bytes = self.to_bytes()?;
        write_bytes_atomic(path, &bytes).map_err(|e| file_error(path, format!("cannot be written: {e}")))?;
        self.checksum = checksum_of(&bytes);
        Ok(bytes.len())
    }

    /// Read a whole plan file, refusing one that is not a plan, of another version, or damaged.
    pub fn read(path: &Path) -> Result<Plan, ShardError> {
        let bytes = std::fs::read(path).map_err(|e| file_error(path, format!("cannot be read: {e}")))?;
        Plan::from_bytes(&bytes).map_err(|problem| file_error(path, problem))
    }

    /// Read only what a shard's walks need: the first section, checked by its own checksum,
    /// and the file's checksum (the rest is neither read nor decoded).
    pub fn read_walks(path: &Path) -> Result<Plan, ShardError> {
        let io = |e: std::io::Error| file_error(path, format!("cannot be read: {e}"));
        let mut file = File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut head = [0u8; 20];
        if len < 36 || file.read_exact(&mut head).is_err() {
            return Err(file_error(path, "not a precompute plan (from `prm precompute --prepare`)"));
        }
        let walks_len = check_plan_head(&head, len).map_err(|p| file_error(path, p))?;
        let mut walks = vec![0u8; walks_len as usize + 8];
        file.read_exact(&mut walks).map_err(io)?;
        file.seek(SeekFrom::End(-8)).map_err(io)?;
        let mut sum = [0u8; 8];
        file.read_exact(&mut sum).map_err(io)?;
        let (walks, walks_sum) = walks.split_at(walks_len as usize);
        if fnv1a(FNV_START, walks).to_le_bytes() != walks_sum {
            return Err(file_error(path, "damaged (its checksum does not match: truncated or altered)"));
        }
        let mut plan = Plan::from_walks(walks, u64::from_le_bytes(sum)).map_err(|p| file_error(path, p))?;
        plan.walks_only = true;
        Ok(plan)
    }

    fn from_walks(bytes: &[u8], checksum: u64) -> Result<Plan, String> {
        let (params, geometry, set, entries, owners, clustering, near, keep): Walks =
            postcard::from_bytes(bytes).map_err(|e| format!("damaged (cannot be decoded: {e})"))?;
        params.validate().map_err(|e| format!("damaged (bad parameter: {e})"))?;
        if set.texels.len() > u32::MAX as usize
            || clustering.assignment.len() != entries.len()
            || keep.as_ref().is_some_and(|k| k.len() != near.len())
        {
            return Err("damaged (its sections do not agree)".into());
        }
        let preamble = Preamble {
            set,
            entries,
            cells: Cells::default(),
            owners,
            clustering,
            centroids: Vec::new(),
            grouping: None,
            far: Far::default(),
            near,
            near_points: Vec::new(),
            keep,
            exact: Vec::new(),
            echo: Echo::default(),
            smoothing: None,
            frames: Vec::new(),
            dipoles: Vec::new(),
            fingerprint: String::new(),
            geometry,
            page_texel_size: 0.0,
            enclosed: 0,
            area_without_entry: 0.0,
        };
        Ok(Plan { params, preamble, checksum, walks_only: false })
    }

    fn from_bytes(bytes: &[u8]) -> Result<Plan, String> {
        if bytes.len() < 36 || bytes[..8] != PLAN_MAGIC {
            return Err("not a precompute plan (from `prm precompute --prepare`)".into());
        }
        let head: [u8; 20] = bytes[..20].try_into().unwrap_or_default();
        let walks_len = check_plan_head(&head, bytes.len() as u64)? as usize;
        let (body, sum) = bytes.split_at(bytes.len() - 8);
        let checksum = u64::from_le_bytes(sum.try_into().unwrap_or_default());
        if fnv1a(FNV_START, body) != checksum {
            return Err("damaged (its checksum does not match: truncated or altered)".into());
        }
        let mut plan = Plan::from_walks(&body[20..20 + walks_len], checksum)?;
        let rest: Rest = postcard::from_bytes(&body[28 + walks_len..])
            .map_err(|e| format!("damaged (cannot be decoded: {e})"))?;
        let pre = &mut plan.preamble;
        (pre.fingerprint, pre.page_texel_size, pre.enclosed, pre.area_without_entry) =
            (rest.0, rest.1, rest.2, rest.3);
        (pre.cells, pre.centroids, pre.grouping, pre.far) = (rest.4, rest.5, rest.6, rest.7);
        (pre.near_points, pre.exact, pre.echo, pre.smoothing) = (rest.8, rest.9, rest.10, rest.11);
        let clusters = pre.clustering.members.len();
        if pre.centroids.len() != clusters || (!pre.exact.is_empty() && pre.exact.len() != pre.set.len()) {
            return Err("damaged (its sections do not agree)".into());
        }
        Ok(plan)
    }
}

/// A plan file's first 20 bytes (magic, version, first section's length) checked against
/// its length; the first section's length.
fn check_plan_head(head: &[u8; 20], len: u64) -> Result<u64, String> {
    if head[..8] != PLAN_MAGIC {
        return Err("not a precompute plan (from `prm precompute --prepare`)".into());
    }
    let version = u32::from_le_bytes(head[8..12].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(format!("plan version {version}, this build reads {VERSION}: make it again"));
    }
    let walks = u64::from_le_bytes(head[12..20].try_into().unwrap_or_default());
    if walks > len.saturating_sub(36) {
        return Err("damaged (truncated, or its first section's length)".into());
    }
    Ok(walks)
}

/// The covered texels shard `index` of `count` walks: the index-th of `count` equal runs.
pub fn shard_texels(texels: usize, index: u32, count: u32) -> Range<usize> {
    let at = |i: u32| (texels as u128 * i as u128 / count.max(1) as u128) as usize;
    at(index)..at(index + 1)
}

/// What a shard did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ShardReport {
    pub index: u32,
    pub count: u32,
    pub texels: Range<usize>,
    pub bytes: u64,
    pub rays: u64,
    pub seconds_transport: f64,
}

/// A writer that keeps the FNV-1a 64 of what went through it.
struct Hashing<W: Write> {
    inner: W,
    hash: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash = fnv1a(self.hash, &buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Run shard `index` of `count` (step 2) of `plan` on `scene` (the level the plan was made
/// of: refused otherwise; its lightmap UVs are not used, so it may be loaded without them,
/// `prm::LoadOptions::skip_lightmap_uvs`), writing its part to `out` atomically.
#[allow(clippy::too_many_arguments)]
pub fn run_shard(
    scene: &Scene,
    bvh: &Bvh,
    plan: &Plan,
    index: u32,
    count: u32,
    out: &Path,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<ShardReport, ShardError> {
    if count == 0 || count > MAX_SHARDS || index >= count {
        return Err(ShardError::Refused(format!(
            "shard {index}/{count}: the count must be 1 to {MAX_SHARDS} and the index 0 to count - 1"
        )));
    }
    let (params, pre) = (&plan.params, &plan.preamble);
    let geometry = geometry_fingerprint(scene);
    if geometry != pre.geometry {
        return Err(ShardError::Refused(format!(
            "the level is not the one the plan was made of (its triangles and albedos hash to {geometry:016x}, \
             the plan's level to {:016x})",
            pre.geometry
        )));
    }
    let range = shard_texels(pre.set.len(), index, count);
    let linked = pre.linked();
    let transport = pre.transport(scene, bvh, linked.as_ref(), params);
    let prepared = transport.prepare(params.estimator);
    // What preparing counted (the scatter's virtual lights: their walks and rays) is counted
    // once, by shard 0: every shard prepares the same.
    let stats = &transport.stats;
    let prepared_counts = [&stats.truncated, &stats.unowned, &stats.rays, &stats.vpls].map(|c| {
        if index == 0 {
            0
        } else {
            c.load(Ordering::Relaxed) as u64
        }
    });
    let t = Instant::now();
    let tmp = temp_path(out);
    let written = (|| -> Result<u64, ShardError> {
        let file = File::create(&tmp).map_err(|e| file_error(out, format!("cannot be written: {e}")))?;
        let mut w = Hashing { inner: BufWriter::new(file), hash: FNV_START };
        let io = |e: std::io::Error| file_error(out, format!("cannot be written: {e}"));
        w.write_all(&PART_MAGIC).map_err(io)?;
        w.write_all(&VERSION.to_le_bytes()).map_err(io)?;
        w.write_all(&plan.checksum.to_le_bytes()).map_err(io)?;
        for v in [index, count, range.start as u32, range.end as u32] {
            w.write_all(&v.to_le_bytes()).map_err(io)?;
        }
        let mut bytes = PART_HEADER as u64;
        let mut at = range.start;
        while at < range.end {
            stop_if(cancel).map_err(PrecomputeError::from)?;
            let end = (at + CHUNK_TEXELS).min(range.end);
            let on_texels = |done| progress(Phase::Transport, at - range.start + done, range.len());
            let control = Control { progress: &on_texels, cancel };
            let walked = transport
                .run_texels(&prepared, &pre.set.texels[at..end], pre.set.width, control)
                .map_err(PrecomputeError::from)?;
            let panes: Vec<TexelPanes> = walked.into_iter().map(|(p, _)| p).collect();
            let chunk = postcard::to_stdvec(&panes)
                .map_err(|e| ShardError::Refused(format!("a chunk of walks cannot be encoded: {e}")))?;
            w.write_all(&((end - at) as u32).to_le_bytes()).map_err(io)?;
            w.write_all(&(chunk.len() as u64).to_le_bytes()).map_err(io)?;
            w.write_all(&chunk).map_err(io)?;
            bytes += 12 + chunk.len() as u64;
            at = end;
        }
        w.write_all(&0u32.to_le_bytes()).map_err(io)?;
        for (c, before) in
            [&stats.truncated, &stats.unowned, &stats.rays, &stats.vpls].iter().zip(prepared_counts)
        {
            w.write_all(&(c.load(Ordering::Relaxed) as u64 - before).to_le_bytes()).map_err(io)?;
        }
        let sum = w.hash;
        w.inner.write_all(&sum.to_le_bytes()).map_err(io)?;
        let file = w.inner.into_inner().map_err(|e| io(e.into_error()))?;
        file.sync_all().map_err(io)?;
        std::fs::rename(&tmp, out).map_err(io)?;
        Ok(bytes + 4 + 32 + 8)
    })();
    let bytes = match written {
        Ok(b) => b,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    Ok(ShardReport {
        index,
        count,
        texels: range,
        bytes,
        rays: stats.rays.load(Ordering::Relaxed) as u64 - prepared_counts[2],
        seconds_transport: t.elapsed().as_secs_f64(),
    })
}

/// One part, checked: where it is, which shard of how many, its texels and counters.
struct Part {
    path: PathBuf,
    index: u32,
    count: u32,
    texels: Range<usize>,
    /// Walks cut, unowned vertices, rays, virtual lights.
    counters: [u64; 4],
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
struct PartWalks {
    parts: Vec<Part>,
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
    /// The walks of texels `range` (ascending from one call to the next).
    fn take(&mut self, range: Range<usize>) -> Result<Vec<TexelPanes>, ShardError> {
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
    fn finish(&mut self) -> Result<(), ShardError> {
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
fn check_parts(plan: &Plan, paths: &[PathBuf]) -> Result<Vec<Part>, ShardError> {
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

/// Merge (step 3): the map a one-machine precompute with the plan's parameters makes, from
/// the plan and all its parts (any order), byte for byte.
pub fn merge(
    plan: Plan,
    parts: &[PathBuf],
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<(Prm, Report), ShardError> {
    let all = Instant::now();
    if plan.walks_only {
        return Err(ShardError::Refused("the merge needs the whole plan (Plan::read)".into()));
    }
    let parts = check_parts(&plan, parts)?;
    let Plan { params, preamble: pre, .. } = plan;
    let mut report = Report::new(&params);
    pre.count(&mut report);
    let counters = parts.iter().fold([0u64; 4], |mut a, p| {
        for (x, y) in a.iter_mut().zip(p.counters) {
            *x += y;
        }
        a
    });
    let mut walks =
        PartWalks { parts, current: 0, reader: None, next: 0, ahead: Default::default(), hash: FNV_START };
    let mut failed = None;
    let mut walk = |range: Range<usize>, control: Control| -> Result<Walked, PrecomputeError> {
        match walks.take(range) {
            Ok(w) => {
                (control.progress)(w.len());
                Ok(w.into_iter().map(|p| (p, Vec::new())).collect())
            }
            Err(e) => {
                failed = Some(e);
                Err(crate::parallel::Cancelled.into())
            }
        }
    };
    let acc = walk_and_encode(&pre, &params, &mut walk, None, progress, cancel, &mut report);
    if let Some(e) = failed {
        return Err(e);
    }
    let acc = acc?;
    walks.finish()?;
    let [truncated, unowned, rays, vpls] = counters;
    (report.walks_truncated, report.unowned_vertices) = (truncated as usize, unowned as usize);
    (report.rays, report.virtual_lights) = (rays as usize, vpls as usize);
    let prm = finish(pre, acc, &params, &mut report, all)?;
    progress(Phase::Panes, 1, 1);
    Ok((prm, report))
}
