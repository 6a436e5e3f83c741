//! A precompute in parts, for a farm (issue 16): `prm precompute --prepare`, `--shard I/N`
//! and `prm merge`. Each step is a process of its own, so any scheduler can run them (Ray,
//! a Slurm job array, a Kubernetes indexed Job: `docs/farm.md`):
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
//! Refused: an update cache.
//!
//! The plan file, little-endian: magic `PRMPLAN\n`, version u32, then two sections in
//! postcard's format (its wire format is stable since 1.0). The first is what the walks need
//! (parameters, the level's geometry hash, texel set, entries, cell owners, clusters, near
//! links and their kept shares): its length u64, its bytes, their FNV-1a 64; a shard reads
//! only it ([`Plan::read_walks`]: on the 4 x 4 halls a third of the plan). The second is the
//! rest the encoding and the file need (the header's fingerprint, counts, cells, stay shares,
//! bounce gains, centroids, groups, far field, near points, echo, smoothing, the texels'
//! visible areas). Last, FNV-1a 64 of
//! everything before it: the plan's checksum, which every part records. A part: magic
//! `PRMPART\n`, version u32, the plan's checksum u64,
//! shard index u32, shard count u32, first texel u32, end texel u32; then chunks, each texel
//! count u32 (0 ends them), byte length u64 and the chunk's walks (postcard, per texel its
//! (cluster, RGB) pairs); then walks cut at the bounce cap u64, path vertices with no owning
//! entry u64, rays u64, virtual lights u64; FNV-1a 64 of everything before it.

use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use prm::fingerprint::geometry_fingerprint;
use prm::fsutil::write_atomic;
use prm::prm_file::Prm;
use prm::{Bvh, Scene};

use crate::parallel::{stop_if, Control};
use crate::precompute::{
    check_params, finish, walk_and_encode, Phase, Preamble, PrecomputeError, PrecomputeParams, Report, Walked,
};

mod part_file;
mod plan_file;

pub use plan_file::Plan;

use part_file::{check_parts, Hashing, PartWalks};

const PLAN_MAGIC: [u8; 8] = *b"PRMPLAN\n";
const PART_MAGIC: [u8; 8] = *b"PRMPART\n";
/// Plan and part file version (4: the next-bounce table may leave rows out; 5: the entries'
/// stay shares; 6: the table's cutoff of weak elements, a parameter; 7: the far field's
/// energies are left out, the merge adds them up, beside the first bounce where it makes one;
/// 8: the parameters lost `dipole_block`; 9: the entries' bounce gains; 10: the texels'
/// visible areas and the `match_power` parameter; 11: the near links' hidden triangles; 12: the
/// echo's crease points).
const VERSION: u32 = 12;
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
    /// Writing a part failed (named by the caller: [`run_shard`] turns it into `File`).
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

fn file_error(path: &Path, problem: impl std::fmt::Display) -> ShardError {
    ShardError::File { path: path.to_path_buf(), problem: problem.to_string() }
}

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
    let all = Instant::now();
    let mut report = Report::new(params);
    let preamble = Preamble::build(
        scene,
        bvh,
        params,
        None,
        None,
        false,
        false,
        |_| Ok(()),
        &mut report,
        progress,
        cancel,
    )?;
    report.seconds_total = all.elapsed().as_secs_f64();
    // Its checksum is known once it is encoded ([`Plan::write`]).
    let plan = Plan { params: params.clone(), preamble, checksum: 0, walks_only: false };
    Ok((plan, report))
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
    // The walks trace with the rooms' trees, as the one-machine precompute's do (where the
    // plan was made in this process, the BVH has them already and this does nothing).
    if !bvh.is_localised() {
        bvh.localise(scene, &prm::rooms::Rooms::of_scene(scene));
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
    let mut bytes = 0;
    write_atomic(out, |file| -> Result<(), ShardError> {
        let mut w = Hashing::new(file);
        w.write_all(&PART_MAGIC)?;
        w.write_all(&VERSION.to_le_bytes())?;
        w.write_all(&plan.checksum.to_le_bytes())?;
        for v in [index, count, range.start as u32, range.end as u32] {
            w.write_all(&v.to_le_bytes())?;
        }
        let mut at = range.start;
        while at < range.end {
            stop_if(cancel).map_err(PrecomputeError::from)?;
            let end = (at + CHUNK_TEXELS).min(range.end);
            let on_texels = |done| progress(Phase::Transport, at - range.start + done, range.len());
            let control = Control { progress: &on_texels, cancel };
            let walked = transport
                .run_texels(&prepared, &pre.set.texels[at..end], pre.set.width, control)
                .map_err(PrecomputeError::from)?;
            let chunk = postcard::to_stdvec(&walked)
                .map_err(|e| ShardError::Refused(format!("a chunk of walks cannot be encoded: {e}")))?;
            w.write_all(&((end - at) as u32).to_le_bytes())?;
            w.write_all(&(chunk.len() as u64).to_le_bytes())?;
            w.write_all(&chunk)?;
            at = end;
        }
        w.write_all(&0u32.to_le_bytes())?;
        for (c, before) in
            [&stats.truncated, &stats.unowned, &stats.rays, &stats.vpls].iter().zip(prepared_counts)
        {
            w.write_all(&(c.load(Ordering::Relaxed) as u64 - before).to_le_bytes())?;
        }
        let sum = w.hash;
        w.write_all(&sum.to_le_bytes())?;
        bytes = w.bytes;
        Ok(())
    })
    .map_err(|e| match e {
        ShardError::Io(e) => file_error(out, format!("cannot be written: {e}")),
        e => e,
    })?;
    Ok(ShardReport {
        index,
        count,
        texels: range,
        bytes,
        rays: stats.rays.load(Ordering::Relaxed) as u64 - prepared_counts[2],
        seconds_transport: t.elapsed().as_secs_f64(),
    })
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
    let mut walks = PartWalks::new(parts);
    let mut failed = None;
    let mut walk = |range: Range<usize>, control: Control| -> Result<Walked, PrecomputeError> {
        match walks.take(range) {
            Ok(w) => {
                (control.progress)(w.len());
                Ok(w)
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
