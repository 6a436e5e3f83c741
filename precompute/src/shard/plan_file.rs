//! The plan file (module `shard` doc): its two sections, written and read.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use prm::fingerprint::{fnv1a, FNV_START};
use prm::fsutil::write_bytes_atomic;
use prm::prm_file::{Cells, Echo, Entry, Far, NearLink, NearPoint};
use prm::{Smoothing, TexelSet};

use super::{file_error, ShardError, PLAN_MAGIC, VERSION};
use crate::cells::CellOwners;
use crate::cluster::Clustering;
use crate::precompute::{Preamble, PrecomputeParams};
use crate::transport::NextBounce;

/// A precompute's plan: its parameters and preamble, and the checksum its file ends with
/// (what every part records; 0 until it is written). The checksum (FNV-1a) guards against
/// accidents, not against a file edited on purpose, as the `.prm`'s does. Read for a shard
/// ([`Plan::read_walks`]) it holds only what the walks need, and the merge refuses it.
pub struct Plan {
    pub params: PrecomputeParams,
    pub preamble: Preamble,
    pub checksum: u64,
    pub(super) walks_only: bool,
}

/// The plan's first section: what the walks need (a shard reads only it).
type Walks = (
    PrecomputeParams,
    u64,
    TexelSet,
    Vec<Entry>,
    CellOwners,
    Clustering,
    Vec<NearLink>,
    Option<Vec<f32>>,
    Option<NextBounce>,
);
type WalksRef<'a> = (
    &'a PrecomputeParams,
    u64,
    &'a TexelSet,
    &'a [Entry],
    &'a CellOwners,
    &'a Clustering,
    &'a [NearLink],
    &'a Option<Vec<f32>>,
    &'a Option<NextBounce>,
);
/// Its second: what the encoding and the file need besides.
type Rest = (
    String,
    f32,
    usize,
    f64,
    Cells,
    Vec<f32>,
    Vec<glam::Vec3>,
    Vec<glam::Vec3>,
    Option<Clustering>,
    Far,
    Vec<NearPoint>,
    Echo,
    Option<Smoothing>,
    Vec<f32>,
    (Vec<NearLink>, Vec<NearPoint>),
);
type RestRef<'a> = (
    &'a str,
    f32,
    usize,
    f64,
    &'a Cells,
    &'a [f32],
    &'a [glam::Vec3],
    &'a [glam::Vec3],
    &'a Option<Clustering>,
    &'a Far,
    &'a [NearPoint],
    &'a Echo,
    &'a Option<Smoothing>,
    &'a [f32],
    (&'a [NearLink], &'a [NearPoint]),
);

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
        let walks: WalksRef = (
            p,
            pre.geometry,
            &pre.set,
            &pre.entries,
            &pre.owners,
            &pre.clustering,
            &pre.near,
            &pre.keep,
            &pre.next,
        );
        let rest: RestRef = (
            &pre.fingerprint,
            pre.page_texel_size,
            pre.enclosed,
            pre.area_without_entry,
            &pre.cells,
            &pre.stays,
            &pre.gains,
            &pre.centroids,
            &pre.grouping,
            &pre.far,
            &pre.near_points,
            &pre.echo,
            &pre.smoothing,
            &pre.texel_areas,
            (&pre.crease_links, &pre.crease_points),
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
        let (params, geometry, set, entries, owners, clustering, near, keep, next): Walks =
            postcard::from_bytes(bytes).map_err(|e| format!("damaged (cannot be decoded: {e})"))?;
        params.validate().map_err(|e| format!("damaged (bad parameter: {e})"))?;
        if set.texels.len() > u32::MAX as usize
            || clustering.assignment.len() != entries.len()
            || keep.as_ref().is_some_and(|k| k.len() != near.len())
            || next
                .as_ref()
                .is_some_and(|n| !n.fits(entries.len(), clustering.members.len(), set.index.len()))
        {
            return Err("damaged (its sections do not agree)".into());
        }
        let next_on = next.is_some();
        let preamble = Preamble {
            set,
            texel_areas: Vec::new(),
            entries,
            cells: Cells::default(),
            stays: Vec::new(),
            gains: Vec::new(),
            owners,
            clustering,
            centroids: Vec::new(),
            grouping: None,
            far: Far::default(),
            near,
            near_points: Vec::new(),
            keep,
            next,
            next_on,
            entry_room: Vec::new(),
            samples: Default::default(),
            lit: Vec::new(),
            // The table is the plan's: a shard makes no row.
            cutoff: Default::default(),
            echo: Echo::default(),
            crease_links: Vec::new(),
            crease_points: Vec::new(),
            smoothing: None,
            rooms: None,
            untouched: None,
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
        (pre.cells, pre.stays, pre.gains, pre.centroids, pre.grouping, pre.far) =
            (rest.4, rest.5, rest.6, rest.7, rest.8, rest.9);
        (pre.near_points, pre.echo, pre.smoothing, pre.texel_areas) = (rest.10, rest.11, rest.12, rest.13);
        (pre.crease_links, pre.crease_points) = rest.14;
        let clusters = pre.clustering.members.len();
        let n = pre.entries.len();
        if pre.centroids.len() != clusters
            || [pre.stays.len(), pre.gains.len()] != [n; 2]
            || (plan.params.match_power && pre.texel_areas.len() != pre.set.texels.len())
        {
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
