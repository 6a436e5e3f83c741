//! The far field (`prm::prm_file::Far`): what the near links leave out of the first bounce of
//! light that is uneven over a cluster.
//!
//! A pane answers irradiance spread evenly over its cluster; the runtime's near links add, per
//! texel, `albedo_j (E_j - w_c t_j)` times cell j's first bounce for the cells within
//! `reach + size_j` of the texel. Beyond that the deviation `E_j - w_c t_j` was dropped on the
//! grounds that deviations sum to zero over a cluster. They do, but a cluster is metres across:
//! a lamp 5 cm from a wall lights one end of it, and a pillar face 3 m away that sees that end
//! at a grazing angle gets 2-3x the light a cluster-wide spread gives it (measured on the
//! chamber: a torch 5 cm from a wall 21 % off against the ground truth with near links alone,
//! 11 % with this far field).
//!
//! So every frame the runtime sends each entry's deviation flux `phi_j = albedo_j (A/N) (E_j -
//! w_c t_j)` to every texel x as from a point, `phi_j cos_x cos_j / (pi r²)`, times the far
//! share [`prm::prm_file::far_share`] of `|x - centroid_j|` (0 up to `reach`, 1 from `reach +
//! size_j`; the near links keep the rest, [`crate::near::near_links`]), and a visibility. Only the
//! entries carrying a share of the deviation are sent (`prm_runtime::cpu::far_sources`).
//!
//! What is precomputed: the visibility, and per entry what the far field delivers of a unit of
//! its deviation, for the runtime's cluster balance (`far_energy`). The visibility is a bit per
//! pair of entries within the far radius (one ray each; pairs that face away from each other
//! get none), kept by blocks of 32 entries
//! ([`prm::prm_file::Far`]; the blocks are runs of the entries' order, which follows the
//! triangles: compact where the level's triangles are), and per texel its nearest entries that face its way, with
//! inverse-square-distance weights: a texel's visibility of entry j is the
//! weighted vote of its nearest entries' bits. The geometry (distance, cosines) is evaluated at
//! the texel's own point and normal, so a curved pillar gets its shading right even where its
//! entries are sparse (borrowing whole values from the nearest entries instead cost 1-2 points
//! on the chamber's torches).

use std::collections::HashMap;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{IVec3, Vec3};
use prm::prm_file::{far_share, far_vote, Entry, Far, FarTexel};
use prm::{luminance, Bvh, TexelSet};
use rayon::prelude::*;

/// Blocks of entries farther apart than this many entry spacings are traced pair by pair only
/// when a probe of [`PROBE_SIDE`]² rays between them finds a way through (or none of those
/// pairs could exchange light). Rooms shut off from each other then cost a probe per pair of
/// blocks, not a ray per pair of entries: the far field's cost grows with the level, not
/// with how many rooms lie within its radius. What it may miss is a pair of blocks that see
/// each other through so small an opening that no probe passes: at 1/20 of their pairs
/// visible, 4 % of such blocks (on the chamber, 0.08 % of the bits a ray per pair sets).
const PROBE_GAP: f32 = 8.0;

/// Entries of each block a probe uses (evenly spread over the block).
const PROBE_SIDE: usize = 8;

/// Entries a texel borrows its visibility from.
pub const NEIGHBOURS: usize = 4;

/// An entry lends its visibility only to texels whose normal is within 60 degrees of its own.
const MIN_NORMAL_DOT: f32 = 0.5;

/// The far field for these entries: visibility bits between the pairs within `radius` of each
/// other that could exchange light, each covered texel's neighbours, and each entry's energy
/// (`far_energy`: what the runtime's far field delivers of it; with `sum_energy` false left
/// empty, for [`EnergySum`] to add up beside the first bounce, or [`energies`] after). `reach` and `radius` are in scene
/// units; `cell` is each entry's cell centroid and area; `room` each entry's room
/// (`prm::rooms`; empty: not known): two blocks of entries whose rooms all differ exchange
/// no light and are not traced.
#[allow(clippy::too_many_arguments)]
pub fn far_field(
    bvh: &Bvh,
    set: &TexelSet,
    entries: &[Entry],
    room: &[u32],
    texel_room: &[Option<u32>],
    cell: &[(Vec3, f32)],
    reach: f32,
    radius: f32,
    reuse: Option<&FarReuse>,
    sum_energy: bool,
) -> Far {
    let n = entries.len();
    // Within the near reach the links carry everything: a radius no longer has nothing to send.
    if n == 0 || !(reach >= 0.0) || !(radius > reach) {
        return Far::default();
    }
    let texels = texel_neighbours(set, entries, room, texel_room);
    if texels.is_empty() {
        return Far::default();
    }
    let reuse = reuse.filter(|r| {
        let blocks = Far::blocks(entries.len());
        r.old.block_first.len() == blocks + 1
            && r.old.energy.len() == entries.len()
            && r.entry.len() == entries.len()
            && r.settled.len() == blocks
            && r.same.len() == blocks
            && r.old_room.len() == entries.len()
    });
    let (block_first, pair_block, visible) = pair_visibility(bvh, entries, room, radius, reuse);
    let mut far = Far {
        reach,
        radius,
        block_first,
        pair_block,
        visible,
        texels,
        energy: Vec::new(),
        areas: Vec::new(),
    };
    if sum_energy {
        far.energy = far_energy(&far, entries, cell, reuse);
    }
    far
}

/// What an update (`crate::update`) takes from the old bake's far field: the visibility of
/// every pair of entry blocks both `settled` (each entry as it was, in a room the edit did
/// not touch: `crate::update::Untouched::blocks`), and the energy of each settled `entry`.
/// Such a pair's rays run through free space the edit did not reach, so they meet what they
/// met before; such an entry's energy is a sum over the far texels its pairs' bits light,
/// which lie in its room, as they were (`far_energy`; a texel in no room borrows from any,
/// and on edited geometry could differ: left as it is).
///
/// A pair of blocks in rooms the edit touched is also taken when both blocks' entries are as
/// they were (`same`, per block) and the box holding both blocks' entries misses every box of
/// the edit (`boxes`: `crate::update::Untouched::boxes`): each of the pair's rays runs between
/// points of that box, so it meets the triangles it met before. The rooms must part the two
/// blocks now as they did then (`old_room`, per entry, in the old level's labels): two
/// blocks in rooms apart are not traced at all. On a level whose rooms are joined by doors, an
/// edit touches the one room, and without this every pair was traced again.
pub struct FarReuse<'a> {
    pub old: &'a Far,
    pub settled: &'a [bool],
    pub entry: &'a [bool],
    pub same: &'a [bool],
    pub old_room: &'a [u32],
    pub boxes: &'a crate::update::EditBoxes,
    /// How many pairs were tested and taken by geometry (counted as it goes).
    pub by_geometry: AtomicUsize,
}

impl FarReuse<'_> {
    /// The old bits of blocks a <= b (None: they saw nothing of each other).
    fn bits(&self, a: usize, b: usize) -> Option<[u32; Far::BLOCK]> {
        let old = self.old;
        let run = old.block_first[a] as usize..old.block_first[a + 1] as usize;
        let k = run.start + old.pair_block.get(run)?.binary_search(&(b as u32)).ok()?;
        old.visible.get(k * Far::BLOCK..(k + 1) * Far::BLOCK)?.try_into().ok()
    }
}

/// Far texels per part of [`far_energy`]'s sweep: each part sums its texels in their order,
/// and the parts are added in theirs, so the sums are the same at any thread count. A part is
/// also what [`FirstBounce::add`] sums on one thread: a band of one tile row holds a few
/// thousand far texels, so at 1,024 a band ran on two or three threads.
const ENERGY_PART: usize = 128;

/// Parts of [`far_energy`]'s sweep made at once before they are added (each holds a sum per
/// entry it reached: on the 16 chambers a few thousand).
const ENERGY_PARTS_AT_ONCE: usize = 64;

/// Per entry j, the energy (luminance summed over texels, a pane's unit) the far field
/// delivers per W/m² of deviation: `albedo_j (A/N) sum over far texels x of w_j(x)`, where
/// `w_j(x)` is what the runtime's far field sends to x per W of deviation flux (the share,
/// the neighbours' vote and the kernel from the cell's centroid: [`Visit::sources`]). The
/// cluster balance counts it with the near links' energy: without it the far field's light came
/// on top of a cluster's panes, which already carry all of it (a lamp 1 cm over a closed
/// box's floor: 6 % more indirect light than the power allows).
///
/// It is the runtime's own sum, not an estimate of the light's true path: the balance sets
/// the panes for what the far field does bring. It was estimated from 64 cosine rays per entry
/// and a texel density per UV chart; summed over a level that was within 7 % of what the far
/// field delivers, but entry by entry off by up to 2x (a floor cell under a lamp 3 cm up: 5.78
/// counted, 2.87 delivered), and next to a near light one entry carries most of its cluster's
/// deviation: a small pillar room's indirect light came out 1.20 of the ground truth's under a
/// spot at a wall's foot. An update (`reuse`) keeps an entry's old energy where it is settled
/// ([`FarReuse`]), and walks only the blocks of entries that are not.
fn far_energy(far: &Far, entries: &[Entry], cell: &[(Vec3, f32)], reuse: Option<&FarReuse>) -> Vec<f32> {
    let n = entries.len();
    let kept = |j: usize| reuse.filter(|r| r.entry[j]).map(|r| r.old.energy[j]);
    // The blocks holding an entry whose energy is summed: an update's edit touches few.
    let mut wanted = vec![false; Far::blocks(n)];
    for j in (0..n).filter(|&j| kept(j).is_none()) {
        wanted[j / Far::BLOCK] = true;
    }
    let sum = far_sums(far, entries, cell, &wanted);
    entries.iter().enumerate().map(|(j, e)| kept(j).unwrap_or_else(|| energy_of(e, sum[j]))).collect()
}

/// [`far_energy`]'s sums of the kernel per entry, over the entries of the blocks `wanted`
/// marks (0 for the others).
fn far_sums(far: &Far, entries: &[Entry], cell: &[(Vec3, f32)], wanted: &[bool]) -> Vec<f64> {
    let n = entries.len();
    let mut sum = vec![0.0f64; n];
    if !wanted.contains(&true) {
        return sum;
    }
    let sources = Sources::new(entries, cell, far.reach, &[]);
    for group in far.texels.chunks(ENERGY_PART * ENERGY_PARTS_AT_ONCE) {
        let parts: Vec<Vec<(u32, f64)>> = group
            .par_chunks(ENERGY_PART)
            .map_init(
                || (vec![0.0f64; n], Vec::new(), Visit::new(n)),
                |(acc, touched, visit): &mut (Vec<f64>, Vec<u32>, Visit), part| {
                    for t in part {
                        visit.sources(far, entries, &sources, t, Some(wanted), |j, _, w| {
                            add_energy(acc, touched, j, w);
                        });
                    }
                    take_part(acc, touched)
                },
            )
            .collect();
        for (j, w) in parts.into_iter().flatten() {
            sum[j as usize] += w;
        }
    }
    sum
}

/// Each entry's far-field energy (`far_energy`, the sweep) for a level, not an update.
pub fn energies(far: &Far, entries: &[Entry], cell: &[(Vec3, f32)]) -> Vec<f32> {
    far_energy(far, entries, cell, None)
}

/// One term of an entry's far-field energy, into a part's sums (`touched` lists the entries
/// it holds).
#[inline]
fn add_energy(acc: &mut [f64], touched: &mut Vec<u32>, j: usize, w: f32) {
    if acc[j] == 0.0 {
        touched.push(j as u32);
    }
    acc[j] += w as f64;
}

/// A part's sums, entries ascending, and the scratch cleared for the next part.
fn take_part(acc: &mut [f64], touched: &mut Vec<u32>) -> Vec<(u32, f64)> {
    touched.sort_unstable();
    touched.dedup();
    touched.drain(..).map(|j| (j, std::mem::take(&mut acc[j as usize]))).collect()
}

/// Entry `e`'s far-field energy from the sum of its kernel over the far texels.
fn energy_of(e: &Entry, sum: f64) -> f32 {
    (luminance(e.albedo) as f64 * e.area as f64 * sum) as f32
}

/// `far_energy` added up while the first bounce is made ([`FirstBounce::add`] visits the
/// same sources at the same far texels): the sweep of its own was 0.38 s of the chamber's
/// 5.4 s. The terms are added in `far_energy`'s order, part by part of `ENERGY_PART` far
/// texels, a part that runs across two calls carried from one to the next, so the energies
/// are the same to the bit (an update sums only the entries it changed, with `far_energy`,
/// and must agree with a full precompute). A call that counts nothing leaves the carried part
/// as it is. A far texel seen again (calls whose runs of texels overlap; `walk_and_encode`'s
/// do not) is not counted again; one missed, or a call whose lists differ in length, leave the
/// sum unfinished ([`EnergySum::finish`] gives None, and the caller sums alone).
pub struct EnergySum {
    sum: Vec<f64>,
    /// The far texels added so far (they come in order).
    next: usize,
    /// The part the last call ended in, not yet added: its index and sums.
    carry: Option<(usize, Vec<(u32, f64)>)>,
    broken: bool,
}

impl EnergySum {
    pub fn new(entries: usize) -> EnergySum {
        EnergySum { sum: vec![0.0; entries], next: 0, carry: None, broken: false }
    }

    fn close(&mut self, part: Vec<(u32, f64)>) {
        for (j, w) in part {
            if let Some(s) = self.sum.get_mut(j as usize) {
                *s += w;
            }
        }
    }

    /// The energies, if every far texel of `far` was added once, in order.
    pub fn finish(self, far: &Far, entries: &[Entry]) -> Option<Vec<f32>> {
        let sums = self.sums(far).filter(|s| s.len() == entries.len())?;
        Some(entries.iter().zip(&sums).map(|(e, &s)| energy_of(e, s)).collect())
    }

    /// The sums of the kernel per entry ([`far_sums`]'s), if every far texel of `far` was
    /// added once, in order.
    fn sums(mut self, far: &Far) -> Option<Vec<f64>> {
        if self.broken || self.next != far.texels.len() {
            return None;
        }
        if let Some((_, part)) = self.carry.take() {
            self.close(part);
        }
        Some(self.sum)
    }
}

/// The entries' visibility by blocks of [`Far::BLOCK`] ([`Far`]): `(block_first, pair_block,
/// visible)`. Entries i and j get their bit when they are within `radius` of each other, see
/// each other, and at least one faces the other with the other not turned more than 60 degrees
/// away (a texel near either may face the other even where its entry only grazes it). A pair of
/// blocks is kept when any of its bits is set. Each pair of entries is traced once (from the
/// lower block, or the lower entry within a block) and its bit set both ways.
fn pair_visibility(
    bvh: &Bvh,
    entries: &[Entry],
    room: &[u32],
    radius: f32,
    reuse: Option<&FarReuse>,
) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    const B: usize = Far::BLOCK;
    let n = entries.len();
    let spacing = entries.first().map_or(0.0, |e| e.area.max(0.0).sqrt());
    let exchange = |i: usize, j: usize| -> bool {
        let (p, np, q, nq) = (entries[i].position, entries[i].normal, entries[j].position, entries[j].normal);
        let d = q - p;
        if d.length() > radius {
            return false;
        }
        let d = d.normalize_or_zero();
        let (ci, cj) = (np.dot(d), -nq.dot(d));
        (ci > 0.0 && cj > -MIN_NORMAL_DOT) || (cj > 0.0 && ci > -MIN_NORMAL_DOT)
    };
    let blocks = Far::blocks(n);
    let members = |a: usize| a * B..((a + 1) * B).min(n);
    let bounds: Vec<(Vec3, Vec3)> = (0..blocks)
        .map(|a| {
            entries[members(a)].iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), e| {
                (lo.min(e.position), hi.max(e.position))
            })
        })
        .collect();
    // Each block's rooms, ascending (None: not known, so it may see any).
    let block_rooms = |room: &[u32]| -> Vec<Option<Vec<u32>>> {
        (0..blocks)
            .map(|a| {
                let mut r = room.get(members(a))?.to_vec();
                r.sort_unstable();
                r.dedup();
                Some(r)
            })
            .collect()
    };
    let rooms = block_rooms(room);
    // Free space joins no room to another: blocks whose rooms are known and all differ see
    // nothing of each other (the 16 chambers' neighbours a metre apart were traced ray by ray
    // through their walls: 33x the one chamber's pair time).
    let parted = |rooms: &[Option<Vec<u32>>], a: usize, b: usize| match (&rooms[a], &rooms[b]) {
        (Some(x), Some(y)) => !x.iter().any(|r| y.binary_search(r).is_ok()),
        _ => false,
    };
    let apart = |a: usize, b: usize| parted(&rooms, a, b);
    // An update's pairs kept by geometry (`FarReuse`): the rooms as baked, and whether the box
    // of two blocks' entries, grown by the rays' offsets off their surfaces, meets the edit.
    let old_rooms = reuse.map(|r| block_rooms(r.old_room));
    let kept_by_geometry = |r: &FarReuse, a: usize, b: usize| -> bool {
        if !(r.same[a] && r.same[b]) {
            return false;
        }
        if old_rooms.as_ref().is_none_or(|old| parted(old, a, b) != apart(a, b)) {
            return false;
        }
        let (lo, hi) = (bounds[a].0.min(bounds[b].0), bounds[a].1.max(bounds[b].1));
        let clear = r.boxes.clear(bvh, lo, hi);
        if clear {
            r.by_geometry.fetch_add(1, Ordering::Relaxed);
        }
        clear
    };
    // Gap between two boxes: no pair of their entries is closer.
    let gap = |a: usize, b: usize| {
        let ((la, ha), (lb, hb)) = (bounds[a], bounds[b]);
        (la - hb).max(lb - ha).max(Vec3::ZERO).length()
    };
    // Whether blocks a and b (apart) may see each other: a ray between each of a few pairs
    // spread over both that could exchange light; with none of those, the whole pair is traced.
    let probe = |a: usize, b: usize| -> bool {
        let spread = |x: usize| members(x).step_by(B / PROBE_SIDE);
        let mut tried = false;
        for i in spread(a) {
            for j in spread(b) {
                if exchange(i, j) {
                    tried = true;
                    let (ei, ej) = (&entries[i], &entries[j]);
                    if bvh.visible(ei.position, ei.normal, ej.position, ej.normal) {
                        return true;
                    }
                }
            }
        }
        !tried
    };
    // Per block a, the blocks b >= a it sees anything of, with a's rows' bits over b.
    let upper: Vec<Vec<(u32, [u32; B])>> = (0..blocks)
        .into_par_iter()
        .map(|a| {
            let mut kept = Vec::new();
            for b in a..blocks {
                // (Settled pairs first: those are not counted as kept by geometry.)
                if let Some(r) = reuse.filter(|r| (r.settled[a] && r.settled[b]) || kept_by_geometry(r, a, b))
                {
                    kept.extend(r.bits(a, b).map(|bits| (b as u32, bits)));
                    continue;
                }
                if gap(a, b) > radius || apart(a, b) {
                    continue;
                }
                if gap(a, b) > PROBE_GAP * spacing && !probe(a, b) {
                    continue;
                }
                let mut bits = [0u32; B];
                for i in members(a) {
                    let (p, np) = (entries[i].position, entries[i].normal);
                    let from = if a == b { i + 1 } else { b * B };
                    for (j, e) in entries.iter().enumerate().take(((b + 1) * B).min(n)).skip(from) {
                        if exchange(i, j) && bvh.visible(p, np, e.position, e.normal) {
                            bits[i - a * B] |= 1 << (j - b * B);
                        }
                    }
                }
                if a == b {
                    // Within a block, the lower triangle mirrors the upper.
                    for r in 0..B {
                        for c in r + 1..B {
                            if bits[r] >> c & 1 == 1 {
                                bits[c] |= 1 << r;
                            }
                        }
                    }
                }
                if bits.iter().any(|&w| w != 0) {
                    kept.push((b as u32, bits));
                }
            }
            kept
        })
        .collect();
    // Every row: its own upper pairs, and the transposes of the lower blocks' pairs naming it.
    let mut rows: Vec<Vec<(u32, [u32; B])>> = vec![Vec::new(); blocks];
    for (a, pairs) in upper.iter().enumerate() {
        for &(b, bits) in pairs {
            rows[a].push((b, bits));
            if b as usize != a {
                let mut t = [0u32; B];
                for (r, w) in bits.iter().enumerate() {
                    for (c, tc) in t.iter_mut().enumerate() {
                        if w >> c & 1 == 1 {
                            *tc |= 1 << r;
                        }
                    }
                }
                rows[b as usize].push((a as u32, t));
            }
        }
    }
    let mut block_first = Vec::with_capacity(blocks + 1);
    let (mut pair_block, mut visible) = (Vec::new(), Vec::new());
    for mut row in rows {
        block_first.push(pair_block.len() as u32);
        row.sort_by_key(|&(b, _)| b);
        for (b, bits) in row {
            pair_block.push(b);
            visible.extend_from_slice(&bits);
        }
    }
    block_first.push(pair_block.len() as u32);
    (block_first, pair_block, visible)
}

/// Per covered texel (atlas order), its [`NEIGHBOURS`] nearest entries facing within 60 degrees
/// of its normal, weighted by `1 / (d² + (s/4)²)` (s: the entry spacing) and normalised; texels
/// with none are left out (the far field does not light them). The facing test keeps a texel
/// from borrowing across a thin wall or a corner; a shadow ray to each neighbour would also
/// refuse the next facet of a convex pillar (the chord runs inside it), and measured 1-2 points
/// worse on the chamber's torches. Where rooms are known (`room` per entry, `texel_room` per
/// covered texel in set order; empty or None: not known), a texel takes only entries of its
/// own room: a floor facing up by the wall to the next room has that room's floor, facing up
/// too, within an entry spacing, and borrowed its light (on the 2 x 2 chambers, every pane
/// lit tiles of the neighbouring chambers, dropped later as below the drop rule but walked,
/// smoothed and encoded: 46 % of the tiles encoded).
/// How far, in entry spacings, a texel with sparse surroundings looks for its far-field
/// neighbours ([`texel_neighbours`]).
const FALLBACK_SPACINGS: f32 = 16.0;

fn texel_neighbours(
    set: &TexelSet,
    entries: &[Entry],
    room: &[u32],
    texel_room: &[Option<u32>],
) -> Vec<FarTexel> {
    let spacing = entries[0].area.max(0.0).sqrt();
    let cell = (2.0 * spacing).max(1e-6);
    let key = |p: Vec3| (p / cell).floor().as_ivec3();
    let mut grid: HashMap<IVec3, Vec<u32>> = HashMap::new();
    for (j, e) in entries.iter().enumerate() {
        grid.entry(key(e.position)).or_default().push(j as u32);
    }
    let soft = (0.25 * spacing).powi(2).max(1e-12);
    let width = set.width as usize;
    let mut texels: Vec<FarTexel> = set
        .texels
        .par_iter()
        .enumerate()
        .filter_map(|(k, t)| {
            let own = texel_room.get(k).copied().flatten();
            let facing = |j: usize| {
                entries[j].normal.dot(t.normal) > MIN_NORMAL_DOT
                    && own.is_none_or(|r| room.get(j).is_none_or(|&e| e == r))
            };
            let by_distance = |mut c: Vec<(f32, u32)>| {
                c.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                c
            };
            let around = key(t.position);
            let mut near: Vec<(f32, u32)> = Vec::new();
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        for &j in grid.get(&(around + IVec3::new(dx, dy, dz))).into_iter().flatten() {
                            if facing(j as usize) {
                                near.push((entries[j as usize].position.distance_squared(t.position), j));
                            }
                        }
                    }
                }
            }
            let mut candidates = by_distance(near);
            if candidates.len() < NEIGHBOURS {
                // Sparse surroundings (a small detail far from most entries): every entry
                // within FALLBACK_SPACINGS. Unbounded, the texels of a strip along one
                // chamber's dais side took the dais side of another chamber 21 m away (the
                // strips' entries share a room label), so an edit there changed their first
                // bounce's inputs.
                let reach2 = (FALLBACK_SPACINGS * spacing).powi(2);
                let all = (0..entries.len())
                    .filter(|&j| facing(j))
                    .map(|j| (entries[j].position.distance_squared(t.position), j as u32))
                    .filter(|&(d2, _)| d2 <= reach2)
                    .collect();
                candidates = by_distance(all);
            }
            let mut out = FarTexel {
                texel: (t.j as usize * width + t.i as usize) as u32,
                position: t.position,
                normal: t.normal,
                ..Default::default()
            };
            for (k, &(d2, j)) in candidates.iter().take(NEIGHBOURS).enumerate() {
                out.entries[k] = j;
                out.weights[k] = 1.0 / (d2 + soft);
            }
            let sum: f32 = out.weights.iter().sum();
            (sum > 0.0).then(|| {
                out.weights = out.weights.map(|w| w / sum);
                out
            })
        })
        .collect();
    texels.sort_by_key(|t| t.texel);
    texels
}

/// Which covered texels (the set's order) the far field lights: those whose first bounce
/// [`FirstBounce`] gives whole, with the links'.
pub fn far_lit(set: &TexelSet, far: &Far) -> Vec<bool> {
    let mut lit = vec![false; set.len()];
    for t in &far.texels {
        if let Some(&k) = set.index.get(t.texel as usize).filter(|&&k| (k as usize) < set.len()) {
            lit[k as usize] = true;
        }
    }
    lit
}

/// One far-field source as [`Visit::sources`] reads it.
struct Source {
    centroid: Vec3,
    normal: Vec3,
    flux: Vec3,
    size: f32,
    cluster: u32,
    /// Squared distances from the centroid past which its far share is 1, and under which 0.
    whole: f32,
    none: f32,
}

/// A block of [`Far::BLOCK`] sources' geometry, one array per coordinate: what
/// [`Visit::sources`] reads of a whole block at once, so that the block's lanes go through
/// the kernel's arithmetic together (the scalar loop over lit sources was a fifth of a
/// chamber's precompute, run twice: the far energies and the first bounce). Lanes past the
/// last entry have a zero normal, which faces nothing.
#[derive(Clone, Copy)]
struct Lanes {
    centroid: [[f32; Far::BLOCK]; 3],
    normal: [[f32; Far::BLOCK]; 3],
    size2: [f32; Far::BLOCK],
}

/// The far-field sources of a level's entries ([`Source`]), and by blocks ([`Lanes`]).
struct Sources {
    each: Vec<Source>,
    blocks: Vec<Lanes>,
}

impl Sources {
    /// Each entry's, with its cell's centroid and area (`cell`) and its cluster (0 where
    /// `assignment` has none: `far_energy` passes none); `flux` per W/m² of irradiance over
    /// the cell.
    fn new(entries: &[Entry], cell: &[(Vec3, f32)], reach: f32, assignment: &[u32]) -> Sources {
        let each: Vec<Source> = entries
            .iter()
            .zip(cell)
            .enumerate()
            .map(|(j, (e, &(centroid, area)))| {
                let size = area.max(0.0).sqrt();
                Source {
                    centroid,
                    normal: e.normal,
                    flux: e.albedo * area,
                    size,
                    cluster: assignment.get(j).copied().unwrap_or(0),
                    // With a margin for the square root's rounding: past `whole` the share
                    // computed is exactly 1, under `none` exactly 0.
                    whole: ((reach + size.max(1e-6)) * (1.0 + 1e-5)).powi(2),
                    none: (reach * (1.0 - 1e-5)).max(0.0).powi(2),
                }
            })
            .collect();
        let blocks = each
            .chunks(Far::BLOCK)
            .map(|block| {
                let mut lanes = Lanes {
                    centroid: [[0.0; Far::BLOCK]; 3],
                    normal: [[0.0; Far::BLOCK]; 3],
                    size2: [0.0; Far::BLOCK],
                };
                for (r, s) in block.iter().enumerate() {
                    for a in 0..3 {
                        lanes.centroid[a][r] = s.centroid[a];
                        lanes.normal[a][r] = s.normal[a];
                    }
                    lanes.size2[r] = s.size * s.size;
                }
                lanes
            })
            .collect();
        Sources { each, blocks }
    }
}

/// The far field's part of every cluster's first bounce at a texel (the links carry the rest,
/// `precompute::exact_first_bounce`).
///
/// Per unit of cluster irradiance, entry j's cell sends `albedo_j A_j` W, and the far field
/// delivers it as it delivers a deviation (`prm_runtime::cpu::far_field`): `share V cos_x cos_j
/// / (pi r² max(r², s_j²))` from the cell's centroid, with the texel's neighbours' vote for V.
/// The links keep `1 - share`, so the two together are the cluster's whole first bounce out
/// to the far radius, with no walk noise in it. The walks' first hits used to carry it: a
/// texel 8 m from a hot cluster met it once in a hundred walks, and the pane filter spread
/// that one hit over eight texels.
///
/// It is a few hundred clusters at every texel, so it is made where it is used (a band of
/// texels at a time, or a few texels per cell for the walks' table), never held for the
/// whole level: on the sixteen chambers that was 2.5 GB.
pub struct FirstBounce<'a> {
    set: &'a TexelSet,
    entries: &'a [Entry],
    /// Per entry, what is read of its cell: in one record each, as the inner loop of
    /// [`FirstBounce::add`] reads them (apart, they cost a cache line each), and by blocks.
    sources: Sources,
    far: &'a Far,
    assignment: &'a [u32],
    clusters: usize,
}

impl<'a> FirstBounce<'a> {
    /// For `entries` with their cells' centroids and areas (`cell`) in `clusters` clusters.
    pub fn new(
        set: &'a TexelSet,
        entries: &'a [Entry],
        cell: &[(Vec3, f32)],
        far: &'a Far,
        assignment: &'a [u32],
        clusters: usize,
    ) -> Self {
        let sources = Sources::new(entries, cell, far.reach, assignment);
        FirstBounce { set, entries, sources, far, assignment, clusters }
    }

    /// Per covered texel (set order), a digest of everything [`FirstBounce::add`] reads for it
    /// (0 for a texel the far field does not light), floats at the update's precision
    /// (`crate::update::coarse`): two bakes whose digests agree at a texel give it the same
    /// first bounce. It costs a few words per texel where [`FirstBounce::add`] costs every
    /// entry in view: per entry, once, its row of pair bits and the entries those bits say it
    /// sees (cells, normals, flux, clusters); per texel, its own point and its neighbours'.
    pub fn input_digests(&self) -> Vec<u64> {
        use crate::update::{mix_floats, mix_word};
        const B: usize = Far::BLOCK;
        let (entries, far) = (self.entries, self.far);
        if far.texels.is_empty() {
            return vec![0; self.set.len()];
        }
        // What a texel reads of an entry it is lit by.
        let source: Vec<u64> = (0..entries.len())
            .into_par_iter()
            .map(|j| {
                let h = mix_floats(mix_word(0, j as u64), &self.sources.each[j].centroid.to_array());
                let h = mix_floats(h, &entries[j].normal.to_array());
                let h = mix_floats(h, &[self.sources.each[j].size]);
                let h = mix_floats(h, &self.sources.each[j].flux.to_array());
                mix_word(h, u64::from(self.assignment[j]))
            })
            .collect();
        // Per entry, all it lends a texel as a neighbour: its facing plane, its bits and the
        // entries they say it sees (itself included). An edit elsewhere in a block it sees
        // part of leaves its digest alone.
        let neighbour: Vec<u64> = (0..entries.len())
            .into_par_iter()
            .map(|q| {
                let b = q / B;
                let run = match (far.block_first.get(b), far.block_first.get(b + 1)) {
                    (Some(&from), Some(&to)) => from as usize..to as usize,
                    _ => 0..0,
                };
                let mut h = mix_floats(mix_word(0, q as u64), &entries[q].normal.to_array());
                h = mix_floats(h, &self.sources.each[q].centroid.to_array());
                h = mix_word(h, source[q]);
                for a in run {
                    let (other, mut word) = (far.pair_block[a] as usize, far.visible[a * B + q % B]);
                    // A pair in which it sees nothing lends nothing: its block's pairs with
                    // another room's blocks (a block of entries of both rooms is traced with
                    // every block) come and go with edits there.
                    if word == 0 {
                        continue;
                    }
                    h = mix_word(h, (other as u64) << 32 | u64::from(word));
                    while word != 0 {
                        let c = word.trailing_zeros() as usize;
                        word &= word - 1;
                        h = mix_word(h, source.get(other * B + c).copied().unwrap_or(0));
                    }
                }
                h
            })
            .collect();
        let reach = u64::from(crate::update::coarse(far.reach));
        (0..self.set.len())
            .into_par_iter()
            .map(|k| {
                let t = &self.set.texels[k];
                let atlas = t.j * self.set.width + t.i;
                let Ok(i) = far.texels.binary_search_by_key(&atlas, |f| f.texel) else { return 0 };
                let f = &far.texels[i];
                let mut h = mix_word(reach, u64::from(f.texel));
                h = mix_floats(h, &f.position.to_array());
                h = mix_floats(h, &f.normal.to_array());
                h = mix_floats(h, &f.weights);
                // A slot of no weight holds entry 0 and lends nothing ([`FirstBounce::add`]).
                for (&q, _) in f.entries.iter().zip(&f.weights).filter(|(_, &w)| w > 0.0) {
                    h = mix_word(h, neighbour.get(q as usize).copied().unwrap_or(0));
                }
                h
            })
            .collect()
    }

    /// Adds the far field's first bounce at covered texels `texels` (set indices, ascending) to
    /// `out` (one per texel, clusters ascending; what the links gave is already there). Texels
    /// the far field does not light get nothing. With `energy`, the far texels' terms of
    /// `far_energy` are added up there too ([`EnergySum`]).
    pub fn add(
        &self,
        texels: &[usize],
        out: &mut [crate::transport::TexelPanes],
        energy: Option<&mut EnergySum>,
    ) {
        let (set, far) = (self.set, self.far);
        if far.texels.is_empty() {
            return;
        }
        let far_index = |k: usize| {
            let t = set.texels.get(k)?;
            let atlas = t.j * set.width + t.i;
            far.texels.binary_search_by_key(&atlas, |f| f.texel).ok()
        };
        let (n, marks) = (self.entries.len(), self.clusters.div_ceil(64));
        let plain = |out: &mut [crate::transport::TexelPanes]| {
            out.par_iter_mut().zip(texels).for_each_init(
                || (vec![Vec3::ZERO; self.clusters], vec![0u64; marks], Visit::new(n)),
                |(acc, marks, visit), (out, &k)| {
                    let Some(i) = far_index(k) else { return };
                    self.one_texel(&far.texels[i], out, acc, marks, visit, |_, _| {});
                },
            );
        };
        let Some(sum) = energy.filter(|s| !s.broken) else {
            plain(out);
            return;
        };
        if out.len() != texels.len() {
            sum.broken = true;
            plain(out);
            return;
        }
        // Per texel its far texel, and whether its terms are added (the next far texel in
        // order: one before it was added already, one after it means a texel was missed).
        let far_of: Vec<Option<(usize, bool)>> = texels
            .iter()
            .map(|&k| {
                let i = far_index(k)?;
                let counted = !sum.broken && i == sum.next;
                if counted {
                    sum.next += 1;
                } else if i > sum.next {
                    sum.broken = true;
                }
                Some((i, counted))
            })
            .collect();
        // Runs of texels whose counted far texels lie in one part of ENERGY_PART; the texels
        // not counted join the run they lie in (or the first).
        let mut runs: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
        for (x, f) in far_of.iter().enumerate() {
            match (runs.last_mut(), f.filter(|(_, counted)| *counted).map(|(i, _)| i / ENERGY_PART)) {
                (Some((p, r)), Some(part)) if *p == part => r.end = x + 1,
                (Some((_, r)), None) => r.end = x + 1,
                (Some((_, r)), Some(part)) => {
                    let start = r.end;
                    runs.push((part, start..x + 1));
                }
                (None, Some(part)) => runs.push((part, 0..x + 1)),
                (None, None) => {}
            }
        }
        let Some(&(first_part, _)) = runs.first() else {
            // Nothing counted here: the carried part waits for the next call.
            plain(out);
            return;
        };
        if let Some((_, r)) = runs.last_mut() {
            r.end = texels.len();
        }
        // The part carried from the last call goes on in the first run if it is the same.
        let carried = match sum.carry.take() {
            Some((p, part)) if p == first_part => Some(part),
            Some((_, part)) => {
                sum.close(part);
                None
            }
            None => None,
        };
        let mut pieces: Vec<(&mut [crate::transport::TexelPanes], std::ops::Range<usize>)> = Vec::new();
        let mut rest = out;
        for (_, r) in &runs {
            let (piece, tail) = rest.split_at_mut(r.len());
            pieces.push((piece, r.clone()));
            rest = tail;
        }
        let far_of = &far_of;
        let parts: Vec<Vec<(u32, f64)>> = pieces
            .into_par_iter()
            .enumerate()
            .map_init(
                || {
                    (
                        vec![Vec3::ZERO; self.clusters],
                        vec![0u64; marks],
                        Visit::new(n),
                        vec![0.0f64; n],
                        Vec::new(),
                    )
                },
                |(acc, marks, visit, energy, listed), (x, (piece, r))| {
                    if x == 0 {
                        for &(j, w) in carried.iter().flatten() {
                            energy[j as usize] = w;
                            listed.push(j);
                        }
                    }
                    for (out, x) in piece.iter_mut().zip(r) {
                        let Some((i, counted)) = far_of[x] else { continue };
                        self.one_texel(&far.texels[i], out, acc, marks, visit, |j, w| {
                            if counted {
                                add_energy(energy, listed, j, w);
                            }
                        });
                    }
                    take_part(energy, listed)
                },
            )
            .collect();
        let mut parts: Vec<(usize, Vec<(u32, f64)>)> = runs.iter().map(|(p, _)| *p).zip(parts).collect();
        if let Some((p, last)) = parts.pop() {
            for (_, part) in parts {
                sum.close(part);
            }
            sum.carry = Some((p, last));
        }
    }

    /// The far field's first bounce at far texel `t` added to its list `out` (clusters
    /// ascending), each source's term also given to `term(j, w)`. `marks` has a bit per
    /// cluster, zero on entry and on return: the clusters lit are read back from it in order
    /// (a sort of them per texel was a tenth of the sweep).
    fn one_texel(
        &self,
        t: &FarTexel,
        out: &mut crate::transport::TexelPanes,
        acc: &mut [Vec3],
        marks: &mut [u64],
        visit: &mut Visit,
        mut term: impl FnMut(usize, f32),
    ) {
        visit.sources(self.far, self.entries, &self.sources, t, None, |j, src, w| {
            let c = src.cluster as usize;
            marks[c / 64] |= 1 << (c % 64);
            acc[c] += src.flux * w;
            term(j, w);
        });
        for &(c, v) in out.iter() {
            marks[c as usize / 64] |= 1 << (c % 64);
            acc[c as usize] += v;
        }
        out.clear();
        // Room for exactly what comes: grown by doubling, a band's lists held 40 %
        // more than they used (50 MB on the 16 chambers).
        out.reserve_exact(marks.iter().map(|w| w.count_ones() as usize).sum());
        for (i, w) in marks.iter_mut().enumerate() {
            let mut word = std::mem::take(w);
            while word != 0 {
                let c = i * 64 + word.trailing_zeros() as usize;
                word &= word - 1;
                let v = std::mem::take(&mut acc[c]);
                if v != Vec3::ZERO {
                    out.push((c as u32, v));
                }
            }
        }
    }
}

/// Scratch for walking the far-field sources a far texel sees ([`Visit::sources`]): the
/// blocks its neighbours see something of.
struct Visit {
    blocks: Vec<u32>,
    seen: Vec<u64>,
}

impl Visit {
    fn new(entries: usize) -> Visit {
        Visit { blocks: Vec::new(), seen: vec![0u64; Far::blocks(entries).div_ceil(64)] }
    }

    /// Calls `f(j, source, w)` for each source j (ascending) that lights far texel `t` (of the
    /// blocks of [`Far::BLOCK`] entries `wanted` marks, where given), with
    /// `w = share V cos_x cos_j / (pi r² max(r², s_j²))`: what it delivers there per W of
    /// deviation flux, as the runtime's far field (`prm_runtime::cpu::far_field`) computes it.
    ///
    /// A block's geometry goes through the kernel lane by lane ([`Lanes`]), the share and the
    /// vote then source by source where they are not 1 (few: the sources past the near reach
    /// that every neighbour sees). The operations are the scalar formula's, in its order, so
    /// `w` is the same to the bit.
    #[inline]
    fn sources(
        &mut self,
        far: &Far,
        entries: &[Entry],
        sources: &Sources,
        t: &FarTexel,
        wanted: Option<&[bool]>,
        mut f: impl FnMut(usize, &Source, f32),
    ) {
        const B: usize = Far::BLOCK;
        // The run of block pairs of the block holding entry q.
        let run = |q: usize| {
            let b = q / B;
            match (far.block_first.get(b), far.block_first.get(b + 1)) {
                (Some(&from), Some(&to)) => from as usize..to as usize,
                _ => 0..0,
            }
        };
        let (blocks, seen) = (&mut self.blocks, &mut self.seen);
        let q: [usize; NEIGHBOURS] = std::array::from_fn(|k| t.entries[k] as usize);
        // A slot of no weight (fewer neighbours than NEIGHBOURS) holds entry 0 and lends
        // nothing: no blocks, no bits, and no say in whether every neighbour sees.
        let real: [bool; NEIGHBOURS] = std::array::from_fn(|k| t.weights[k] > 0.0);
        let runs: [Range<usize>; NEIGHBOURS] =
            std::array::from_fn(|k| if real[k] { run(q[k]) } else { 0..0 });
        // The blocks any neighbour sees something of (an entry sees itself), ascending:
        // marked in a bit set and read back in order, which a sort of the four runs
        // (a few hundred blocks each) cost several times over.
        let mut mark = |b: usize| {
            if let Some(w) = seen.get_mut(b / 64) {
                *w |= 1 << (b % 64);
            }
        };
        for k in (0..NEIGHBOURS).filter(|&k| real[k]) {
            far.pair_block[runs[k].clone()].iter().for_each(|&b| mark(b as usize));
            mark(q[k] / B);
        }
        blocks.clear();
        for (i, w) in seen.iter_mut().enumerate() {
            let mut word = std::mem::take(w);
            while word != 0 {
                blocks.push((i * 64) as u32 + word.trailing_zeros());
                word &= word - 1;
            }
        }
        let each = &sources.each;
        // Each neighbour's facing test as a plane: n_q . c_j > n_q . c_q.
        let planes: [(Vec3, f32); NEIGHBOURS] =
            std::array::from_fn(|k| (entries[q[k]].normal, entries[q[k]].normal.dot(each[q[k]].centroid)));
        let mut at = runs.clone().map(|r| r.start);
        let (p, n) = (t.position, t.normal);
        for &b in blocks.iter() {
            let b = b as usize;
            if wanted.is_some_and(|w| !w.get(b).copied().unwrap_or(false)) {
                continue;
            }
            let Some(lanes) = sources.blocks.get(b) else { continue };
            let bits: [u32; NEIGHBOURS] = std::array::from_fn(|k| {
                while at[k] < runs[k].end && (far.pair_block[at[k]] as usize) < b {
                    at[k] += 1;
                }
                let mut w = 0;
                if at[k] < runs[k].end && far.pair_block[at[k]] as usize == b {
                    w = far.visible[at[k] * B + q[k] % B];
                }
                if real[k] && q[k] / B == b {
                    w |= 1 << (q[k] % B);
                }
                w
            });
            // An entry no neighbour sees gets no light from the vote.
            let mut any = bits.iter().fold(0, |a, w| a | w);
            if any == 0 {
                continue;
            }
            let every = bits.iter().zip(real).filter(|(_, r)| *r).fold(u32::MAX, |a, (w, _)| a & w);
            // The kernel in every lane: the cosines, r² and `cos_x cos_j / (pi r² max(r², s²))`
            // (the whole of w where the share and the vote are 1), and which lanes face.
            let (mut cosx, mut cosy, mut dist2, mut kernel) =
                ([0.0f32; B], [0.0f32; B], [0.0f32; B], [0.0f32; B]);
            let mut facing = 0u32;
            for r in 0..B {
                let d = [lanes.centroid[0][r] - p.x, lanes.centroid[1][r] - p.y, lanes.centroid[2][r] - p.z];
                let cx = n.x * d[0] + n.y * d[1] + n.z * d[2];
                let cy = -(lanes.normal[0][r] * d[0] + lanes.normal[1][r] * d[1] + lanes.normal[2][r] * d[2]);
                let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                cosx[r] = cx;
                cosy[r] = cy;
                dist2[r] = r2;
                kernel[r] = cx * cy / (std::f32::consts::PI * r2 * r2.max(lanes.size2[r]));
                facing |= u32::from(cx > 0.0 && cy > 0.0) << r;
            }
            any &= facing;
            while any != 0 {
                let r = any.trailing_zeros() as usize;
                any &= any - 1;
                let j = b * B + r;
                let Some(src) = each.get(j) else { continue };
                let r2 = dist2[r];
                // The far share without its square root and division where it is 0 or 1
                // (most sources: the same values).
                let share = if r2 >= src.whole {
                    1.0
                } else if r2 <= src.none {
                    0.0
                } else {
                    far_share(r2.sqrt(), far.reach, src.size)
                };
                if share <= 0.0 {
                    continue;
                }
                // Every neighbour sees it: the vote is 1 whichever of them face it.
                let v = if every >> r & 1 == 1 {
                    1.0
                } else {
                    let centroid = src.centroid;
                    far_vote(
                        &t.weights,
                        |k| bits[k] >> r & 1 == 1,
                        |k| planes[k].0.dot(centroid) > planes[k].1,
                    )
                };
                if v <= 0.0 {
                    continue;
                }
                let w = if share == 1.0 && v == 1.0 {
                    kernel[r]
                } else {
                    let s2 = lanes.size2[r];
                    share * v * cosx[r] * cosy[r] / (std::f32::consts::PI * r2 * r2.max(s2))
                };
                f(j, src, w);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prm::Scene;

    /// A lightmap of one covered texel.
    fn one_texel(texel: prm::Texel) -> TexelSet {
        TexelSet {
            width: 1,
            height: 1,
            texels: vec![texel],
            index: vec![0],
            dilation: Vec::new(),
            zero_uv_area_triangles: 0,
            shared_gutter_texels: 0,
            buried: Default::default(),
            buried_centres: Vec::new(),
        }
    }

    fn entry(p: Vec3, n: Vec3) -> Entry {
        Entry { position: p, normal: n, albedo: Vec3::splat(0.5), area: 0.04, triangle: 0 }
    }

    /// A texel with fewer than [`NEIGHBOURS`] entries about it takes the nearest ones of its
    /// room within [`FALLBACK_SPACINGS`], not those of the same room across the level (two
    /// chambers' dais sides 21 m apart shared a room label and so a texel's neighbours).
    #[test]
    fn sparse_texels_keep_their_neighbours_near() {
        // Spacing 0.2 m (area 0.04): two entries 0.3 m from the texel, eight at 20 m.
        let mut entries =
            vec![entry(Vec3::new(0.3, 0.0, 0.0), Vec3::Y), entry(Vec3::new(-0.3, 0.0, 0.0), Vec3::Y)];
        entries.extend((0..8).map(|k| entry(Vec3::new(20.0 + 0.2 * k as f32, 0.0, 0.0), Vec3::Y)));
        let texel = prm::Texel {
            i: 0,
            j: 0,
            position: Vec3::ZERO,
            normal: Vec3::Y,
            triangle: 0,
            bary: Vec3::splat(1.0 / 3.0),
        };
        let set = one_texel(texel);
        let far = texel_neighbours(&set, &entries, &vec![0; entries.len()], &[Some(0)]);
        assert_eq!(far.len(), 1);
        let taken: Vec<u32> =
            far[0].entries.iter().zip(&far[0].weights).filter(|(_, &w)| w > 0.0).map(|(&j, _)| j).collect();
        assert_eq!(taken.len(), 2, "{:?}", far[0]);
        assert!(taken.iter().all(|&j| j < 2), "a neighbour 20 m away: {:?}", far[0]);
        // Those far entries in reach (spacing 2 m) are taken.
        let wide: Vec<Entry> = entries.iter().map(|e| Entry { area: 4.0, ..*e }).collect();
        let far = texel_neighbours(&set, &wide, &vec![0; wide.len()], &[Some(0)]);
        assert!(far[0].weights.iter().all(|&w| w > 0.0), "{:?}", far[0]);
    }

    /// A texel's input digest ([`FirstBounce::input_digests`]) follows what
    /// [`FirstBounce::add`] reads for it: two blocks of entries on a floor facing a texel on the
    /// ceiling, whose neighbours see entry 37 of the second block and not entry 38. Moving 38 to
    /// another cluster changes neither the texel's first bounce nor its digest; moving 37 changes
    /// both, and so does its flux, or a neighbour's bit.
    /// The energies added up beside the first bounce ([`EnergySum`]) are [`far_energy`]'s to
    /// the bit, over calls that split parts, make a run of texels twice (as bands do) and pass
    /// texels the far field does not light; a far texel missed leaves the sum unfinished. And
    /// the first bounce is the same with the sum as without.
    #[test]
    #[allow(clippy::single_range_in_vec_init)] // one call over a run of texels
    fn energies_summed_with_the_first_bounce_are_the_sweep_s() {
        const B: usize = Far::BLOCK;
        let (w, h) = (64u32, 48u32);
        // 64 floor entries on an 8 x 8 grid, two blocks that see each other and themselves
        // by a scatter of bits.
        let entries: Vec<Entry> = (0..2 * B)
            .map(|j| Entry {
                position: Vec3::new((j % 8) as f32 * 0.8, 0.0, (j / 8) as f32 * 0.6),
                normal: Vec3::Y,
                albedo: Vec3::new(0.6, 0.5, 0.4),
                area: 0.4,
                triangle: j as u32,
            })
            .collect();
        let mut state = 0x9e37_79b9u32;
        let mut bits = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state | state >> 3
        };
        let visible: Vec<u32> = (0..4 * B).map(|_| bits()).collect();
        // A texel facing down at every atlas texel but every fifth; every seventh has no far
        // texel.
        let mut set = TexelSet {
            width: w,
            height: h,
            texels: Vec::new(),
            index: vec![TexelSet::EMPTY; (w * h) as usize],
            dilation: Vec::new(),
            zero_uv_area_triangles: 0,
            shared_gutter_texels: 0,
            buried: Default::default(),
            buried_centres: Vec::new(),
        };
        let mut texels = Vec::new();
        for a in (0..w * h).filter(|a| a % 5 != 0) {
            let (i, j) = (a % w, a / w);
            // Heights from 0.6 m to 6 km: terms over 20 orders of magnitude, so that the f64
            // sums depend on the order they are added in.
            let position =
                Vec3::new(i as f32 * 0.1, 0.55 + 0.05 * 1.7f32.powi((a % 23) as i32), j as f32 * 0.1);
            set.index[a as usize] = set.texels.len() as u32;
            set.texels.push(prm::Texel {
                i,
                j,
                position,
                normal: Vec3::NEG_Y,
                triangle: 0,
                bary: Vec3::splat(1.0 / 3.0),
            });
            if a % 7 != 0 {
                let q = (a as usize * 7) % (2 * B);
                texels.push(FarTexel {
                    texel: a,
                    position,
                    normal: Vec3::NEG_Y,
                    entries: [q as u32, ((q + 1) % (2 * B)) as u32, ((q + 8) % (2 * B)) as u32, 3],
                    weights: [0.4, 0.3, 0.2, 0.1],
                });
            }
        }
        assert!(texels.len() > 2 * ENERGY_PART, "{} far texels", texels.len());
        let far = Far {
            reach: 0.5,
            radius: 100.0,
            block_first: vec![0, 2, 4],
            pair_block: vec![0, 1, 0, 1],
            visible,
            texels,
            energy: Vec::new(),
            areas: Vec::new(),
        };
        let cell: Vec<(Vec3, f32)> = entries.iter().map(|e| (e.position + Vec3::X * 0.05, e.area)).collect();
        let assignment: Vec<u32> = (0..2 * B as u32).map(|j| j % 5).collect();
        let first = FirstBounce::new(&set, &entries, &cell, &far, &assignment, 5);
        let sweep = far_energy(&far, &entries, &cell, None);
        assert!(sweep.iter().all(|&e| e > 0.0), "{sweep:?}");
        let n = set.len();
        let calls = |ranges: &[std::ops::Range<usize>], sum: Option<&mut EnergySum>| {
            let mut sum = sum;
            let mut lists = vec![Vec::new(); n];
            for r in ranges {
                let texels: Vec<usize> = r.clone().collect();
                let mut out = vec![vec![(0u32, Vec3::splat(1e-3))]; r.len()];
                first.add(&texels, &mut out, sum.as_deref_mut());
                lists[r.clone()].clone_from_slice(&out);
            }
            lists
        };
        let plain = calls(&[0..n], None);
        // The f64 sums, which an order of additions other than the sweep's moves in their
        // last bits (the f32 energies hide that but for one entry in 2^29).
        let sweep_sums = far_sums(&far, &entries, &cell, &[true, true]);
        let bits64 = |e: &[f64]| e.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let Some(lone) = (720..n).find(|&k| {
            let t = &set.texels[k];
            far.texels.binary_search_by_key(&(t.j * w + t.i), |f| f.texel).is_err()
        }) else {
            panic!("the set has a texel with no far texel past 720");
        };
        let orders: [&[std::ops::Range<usize>]; 5] = [
            // Overlapping runs, one of a single texel.
            &[0..700, 500..1900, 1900..1901, 1901..n],
            // A call of no texels, and one of a texel the far field does not light.
            &[0..700, 700..700, 700..lone, lone..lone + 1, lone + 1..n],
            // A run that goes back into parts before the one carried.
            &[0..300, 100..1200, 1200..n],
            &[0..n],
            // One texel at a time for a while.
            &[0..5, 5..6, 6..7, 7..8, 8..n],
        ];
        for order in orders {
            let mut sum = EnergySum::new(entries.len());
            assert_eq!(
                calls(order, Some(&mut sum)),
                plain,
                "the first bounce moved with the sum ({order:?})"
            );
            assert_eq!(sum.sums(&far).map(|s| bits64(&s)), Some(bits64(&sweep_sums)), "{order:?}");
        }
        let mut sum = EnergySum::new(entries.len());
        calls(orders[0], Some(&mut sum));
        let Some(summed) = sum.finish(&far, &entries) else { panic!("every far texel was added") };
        let bits = |e: &[f32]| e.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&summed), bits(&sweep));
        let mut gap = EnergySum::new(entries.len());
        calls(&[0..700, 900..n], Some(&mut gap));
        assert!(gap.finish(&far, &entries).is_none(), "texels 700..900 were missed");
        let mut short = EnergySum::new(entries.len());
        calls(&[0..700], Some(&mut short));
        assert!(short.finish(&far, &entries).is_none(), "the sum stopped at texel 700");
    }

    #[test]
    fn input_digests_follow_what_the_first_bounce_reads() {
        const B: usize = Far::BLOCK;
        let floor = |j: usize| Entry {
            position: Vec3::new(j as f32 * 0.1, 0.0, 0.0),
            normal: Vec3::Y,
            albedo: Vec3::splat(0.5),
            area: 0.01,
            triangle: j as u32,
        };
        let entries: Vec<Entry> = (0..2 * B).map(floor).collect();
        let texel = prm::Texel {
            i: 0,
            j: 0,
            position: Vec3::new(3.0, 2.0, 0.0),
            normal: Vec3::NEG_Y,
            triangle: 0,
            bary: Vec3::splat(1.0 / 3.0),
        };
        let set = one_texel(texel);
        // Block 0 pairs with block 1 only; its entries 0..4 see entry 37 (bit 5 of block 1).
        let mut visible = vec![0u32; 2 * B];
        visible[..4].fill(1 << 5);
        let far = Far {
            reach: 0.0,
            radius: 100.0,
            block_first: vec![0, 1, 1],
            pair_block: vec![1],
            visible,
            texels: vec![FarTexel {
                texel: 0,
                position: texel.position,
                normal: texel.normal,
                entries: [0, 1, 2, 3],
                weights: [0.25; 4],
            }],
            energy: vec![0.0; 2 * B],
            areas: Vec::new(),
        };
        let cell: Vec<(Vec3, f32)> = entries.iter().map(|e| (e.position, e.area)).collect();
        let lit = |far: &Far, assignment: &[u32], cell: &[(Vec3, f32)]| {
            let first = FirstBounce::new(&set, &entries, cell, far, assignment, 4);
            let mut out = vec![Vec::new()];
            first.add(&[0], &mut out, None);
            (out.remove(0), first.input_digests()[0])
        };
        let assignment = vec![0u32; 2 * B];
        let (value, digest) = lit(&far, &assignment, &cell);
        assert!(value.iter().any(|&(c, v)| c == 0 && v.x > 0.0), "{value:?}");
        let mut unseen = assignment.clone();
        unseen[38] = 1;
        assert_eq!(lit(&far, &unseen, &cell), (value.clone(), digest), "an unseen entry moved the texel");
        let mut seen = assignment.clone();
        seen[37] = 1;
        let (v37, d37) = lit(&far, &seen, &cell);
        assert!(v37 != value && d37 != digest, "entry 37 changed cluster: {v37:?}, digest {d37} {digest}");
        let mut brighter = cell.clone();
        brighter[37].1 *= 2.0;
        let (vf, df) = lit(&far, &assignment, &brighter);
        assert!(vf != value && df != digest, "entry 37's flux doubled");
        let mut blind = far.clone();
        blind.visible[2] = 0;
        let (vb, db) = lit(&blind, &assignment, &cell);
        assert!(vb != value && db != digest, "a neighbour lost its bit");
        // A pair in which no neighbour sees anything (block 0 with itself here; on a level of
        // rooms, a block of two rooms' entries with a block of the other room) lends nothing:
        // it may come and go with an edit in the other room.
        let mut idle = far.clone();
        idle.block_first = vec![0, 2, 2];
        idle.pair_block = vec![1, 0];
        idle.visible.extend(std::iter::repeat_n(0, B));
        assert_eq!(
            lit(&idle, &assignment, &cell),
            (value.clone(), digest),
            "a pair of no bits moved the texel"
        );
        // A texel of two neighbours (1 and 2) has entry 0 in its empty slots, at no weight.
        // What entry 0 sees (38 here, and 37) is none of its business: on the 16 chambers such
        // texels on every chamber's dais side followed edits of the first chamber's carpet,
        // which entry 0 (on that chamber's ceiling) sees.
        let mut sparse = far.clone();
        sparse.texels[0].entries = [1, 2, 0, 0];
        sparse.texels[0].weights = [0.5, 0.5, 0.0, 0.0];
        sparse.visible[0] |= 1 << 6;
        let (value, digest) = lit(&sparse, &assignment, &cell);
        assert!(value.iter().any(|&(c, v)| c == 0 && v.x > 0.0), "{value:?}");
        assert_eq!(lit(&sparse, &unseen, &cell), (value.clone(), digest), "entry 0's view moved the texel");
        let mut blind0 = sparse.clone();
        blind0.visible[0] = 0;
        assert_eq!(lit(&blind0, &assignment, &cell), (value.clone(), digest), "entry 0 lost its bits");
        let mut blind1 = sparse.clone();
        blind1.visible[1] = 0;
        assert!(lit(&blind1, &assignment, &cell) != (value, digest), "a real neighbour lost its bit");
    }

    /// Two pairs facing each other across x = 0, one behind a square blocker there and one
    /// above it, and an entry facing away: only the open facing pair gets its bit.
    #[test]
    fn pair_bits_follow_the_rays() {
        let pos = vec![
            Vec3::new(0.0, -1.0, -1.0),
            Vec3::new(0.0, 1.0, -1.0),
            Vec3::new(0.0, 1.0, 1.0),
            Vec3::new(0.0, -1.0, 1.0),
        ];
        let uv = vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE, glam::Vec2::Y];
        let scene = Scene::from_mesh(pos, uv, &[0, 1, 2, 0, 2, 3]);
        let bvh = Bvh::build(&scene);
        let entries = [
            entry(Vec3::new(-1.0, 0.0, 0.0), Vec3::X),
            entry(Vec3::new(1.0, 0.0, 0.0), Vec3::NEG_X),
            entry(Vec3::new(-1.0, 3.0, 0.0), Vec3::X),
            entry(Vec3::new(1.0, 3.0, 0.0), Vec3::NEG_X),
            entry(Vec3::new(3.0, 3.0, 0.0), Vec3::X),
        ];
        let (block_first, pair_block, visible) = pair_visibility(&bvh, &entries, &[], 100.0, None);
        let far = Far { radius: 100.0, block_first, pair_block, visible, ..Far::default() };
        let n = entries.len();
        let open = [(2, 3), (0, 3), (1, 2)];
        for i in 0..n {
            assert!(far.sees(i, i));
            for j in 0..n {
                let want = i == j || open.contains(&(i.min(j), i.max(j)));
                assert_eq!(far.sees(i, j), want, "pair {i} {j}");
            }
        }
        // Within a radius of 3, the open pairs 2.2 and 3.2 apart (entries 0-3 and 1-2) go.
        let (block_first, pair_block, visible) = pair_visibility(&bvh, &entries, &[], 3.0, None);
        let near = Far { radius: 3.0, block_first, pair_block, visible, ..Far::default() };
        assert!(near.sees(2, 3) && near.sees(3, 2) && !near.sees(0, 3) && !near.sees(1, 2));
    }

    /// A BVH of one triangle on the plane x = 0, between the lines' first entries, and 100
    /// entries on two facing lines 2 apart, spread 0 .. 40 along z: four blocks.
    fn two_lines() -> (Bvh, Vec<Entry>) {
        let pos = vec![Vec3::new(0.0, -1.0, -1.0), Vec3::new(0.0, 1.0, -1.0), Vec3::new(0.0, 1.0, 1.0)];
        let uv = vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE];
        let bvh = Bvh::build(&Scene::from_mesh(pos, uv, &[0, 1, 2]));
        let entries = (0..100)
            .map(|k| {
                let (x, n) = if k % 2 == 0 { (-1.0, Vec3::X) } else { (1.0, Vec3::NEG_X) };
                entry(Vec3::new(x, 0.3 * (k % 7) as f32, 0.4 * k as f32), n)
            })
            .collect();
        (bvh, entries)
    }

    /// Entries in several blocks, some beyond the radius: every bit is the brute-force answer
    /// (facing, within the radius, a ray), in both orders, and pairs of blocks with nothing to
    /// see are not kept.
    #[test]
    fn block_bits_are_the_brute_force_pairs() {
        let (bvh, entries) = two_lines();
        let radius = 6.0;
        let (block_first, pair_block, visible) = pair_visibility(&bvh, &entries, &[], radius, None);
        let far = Far { radius, block_first, pair_block, visible, ..Far::default() };
        for i in 0..entries.len() {
            for j in 0..entries.len() {
                let (a, b) = (&entries[i], &entries[j]);
                let d = (b.position - a.position).normalize_or_zero();
                let facing = a.normal.dot(d) > 0.0 && -b.normal.dot(d) > 0.0;
                let (lo, hi) = if i < j { (a, b) } else { (b, a) };
                let want = i == j
                    || (facing
                        && a.position.distance(b.position) <= radius
                        && bvh.visible(lo.position, lo.normal, hi.position, hi.normal));
                assert_eq!(far.sees(i, j), want, "pair {i} {j}");
            }
        }
        // Blocks 0 (z 0 .. 12.4) and 3 (z 38.4 .. 39.6) are 26 apart: not kept.
        assert_eq!((far.pair(0, 3), far.pair(3, 0)), (None, None));
        assert!(far.pair(0, 1).is_some() && far.pair(1, 0).is_some());
    }

    /// An update keeps a pair of blocks by geometry (`FarReuse`): both blocks' entries as they
    /// were, the box of their entries clear of the edit's boxes, and the rooms parting them as
    /// before. The old bake here is marked (every bit set), so a kept pair reads all ones and
    /// a pair traced again reads the true bits. The blocks of `block_bits_are_the_brute_force_pairs`
    /// along z (0 .. 12.4, 12.8 .. 25.2, 25.6 .. 38, 38.4 .. 39.6), an edit at z = 30.
    #[test]
    fn pairs_apart_from_the_edit_are_kept_by_geometry() {
        const B: usize = Far::BLOCK;
        let (bvh, entries) = two_lines();
        let (radius, room) = (6.0, vec![0u32; 100]);
        let far_of = |(block_first, pair_block, visible): (Vec<u32>, Vec<u32>, Vec<u32>)| Far {
            radius,
            block_first,
            pair_block,
            visible,
            ..Far::default()
        };
        let fresh = far_of(pair_visibility(&bvh, &entries, &room, radius, None));
        let marked = Far { visible: vec![u32::MAX; fresh.visible.len()], ..fresh.clone() };
        let bits =
            |far: &Far, a: usize, b: usize| far.pair(a, b).map(|k| far.visible[k * B..(k + 1) * B].to_vec());
        let boxes =
            crate::update::EditBoxes::new(vec![(Vec3::new(-0.5, 0.0, 29.5), Vec3::new(0.5, 1.0, 30.5))]);
        let (settled, energy_settled) = (vec![false; 4], vec![false; 100]);
        let run_with = |same: &[bool], old_room: &[u32], boxes: &crate::update::EditBoxes| {
            let reuse = FarReuse {
                old: &marked,
                settled: &settled,
                entry: &energy_settled,
                same,
                old_room,
                boxes,
                by_geometry: Default::default(),
            };
            far_of(pair_visibility(&bvh, &entries, &room, radius, Some(&reuse)))
        };
        let run = |same: &[bool], old_room: &[u32]| run_with(same, old_room, &boxes);
        let pairs = [(0, 0), (0, 1), (1, 1), (1, 2), (2, 2), (2, 3), (3, 3)];
        assert!(pairs.iter().all(|&(a, b)| fresh.pair(a, b).is_some()), "every listed pair sees something");
        let check = |far: &Far, kept: &[(usize, usize)]| {
            for &(a, b) in &pairs {
                let want = if kept.contains(&(a, b)) { bits(&marked, a, b) } else { bits(&fresh, a, b) };
                assert_eq!(bits(far, a, b), want, "pair {a} {b}, kept: {kept:?}");
            }
        };
        // The boxes of (1, 2), (2, 2) and (2, 3) hold z = 30.
        check(&run(&[true; 4], &room), &[(0, 0), (0, 1), (1, 1), (3, 3)]);
        // An entry of block 1 moved: its pairs are traced again.
        check(&run(&[true, false, true, true], &room), &[(0, 0), (3, 3)]);
        // Block 0 lay in another room before: (0, 1) was not traced then, so it is now.
        let mut old_room = room.clone();
        old_room[..32].fill(1);
        check(&run(&[true; 4], &old_room), &[(0, 0), (1, 1), (3, 3)]);
        // An edit of more boxes than `MAX_GEOMETRY` keeps nothing by geometry, even where every
        // box is far away.
        let far_away = (Vec3::splat(1e3), Vec3::splat(1e3 + 1.0));
        let wide = crate::update::EditBoxes::new(vec![far_away; crate::update::MAX_GEOMETRY + 1]);
        check(&run_with(&[true; 4], &room, &wide), &[]);
        let few = crate::update::EditBoxes::new(vec![far_away; crate::update::MAX_GEOMETRY]);
        check(&run_with(&[true; 4], &room, &few), &pairs);
    }

    /// Two rows of 64 entries facing each other 2 m apart (within the probe gap, so traced
    /// ray by ray), in rooms 0 and 1: no bit across, every bit within a row as without rooms;
    /// with the second row's third block in both rooms, that block is traced as before.
    #[test]
    fn blocks_in_different_rooms_are_not_traced() {
        let pos = vec![Vec3::new(50.0, 0.0, 0.0), Vec3::new(50.0, 1.0, 0.0), Vec3::new(50.0, 0.0, 1.0)];
        let scene = Scene::from_mesh(pos, vec![glam::Vec2::ZERO; 3], &[0, 1, 2]);
        let bvh = Bvh::build(&scene);
        let entries: Vec<Entry> = (0..128)
            .map(|k| {
                let (x, n) = if k < 64 { (-1.0, Vec3::X) } else { (1.0, Vec3::NEG_X) };
                entry(Vec3::new(x, 0.1 * (k % 64) as f32, 0.1 * (k % 3) as f32), n)
            })
            .collect();
        let far_of = |room: &[u32]| {
            let (block_first, pair_block, visible) = pair_visibility(&bvh, &entries, room, 100.0, None);
            Far { radius: 100.0, block_first, pair_block, visible, ..Far::default() }
        };
        let open = far_of(&[]);
        let rooms: Vec<u32> = (0..128).map(|k| (k >= 64) as u32).collect();
        let parted = far_of(&rooms);
        let mut both = rooms.clone();
        both[70] = 0;
        let half = far_of(&both);
        let mut across = 0;
        for i in 0..128 {
            for j in 0..128 {
                if (i < 64) == (j < 64) {
                    assert_eq!(parted.sees(i, j), open.sees(i, j), "pair {i} {j}");
                } else {
                    across += open.sees(i, j) as usize;
                    assert!(!parted.sees(i, j), "pair {i} {j} across rooms");
                    assert_eq!(
                        half.sees(i, j),
                        open.sees(i, j) && (i >= 64 || j >= 64) && (i.max(j) / 32 == 2)
                    );
                }
            }
        }
        assert!(across > 1000, "the rows see each other without rooms: {across}");
    }

    /// Two rows of 64 entries 10 m apart facing each other (blocks far past the probe gap),
    /// across a wall at x = 0 with an opening `hole` metres high: every bit is the brute-force
    /// answer whether the wall shuts them off (none), is open over half its height, or is
    /// not there (all).
    #[test]
    fn probed_blocks_keep_the_brute_force_bits() {
        let entries: Vec<Entry> = (0..128)
            .map(|k| {
                let (x, n) = if k < 64 { (-5.0, Vec3::X) } else { (5.0, Vec3::NEG_X) };
                entry(Vec3::new(x, 0.25 * (k % 64) as f32 - 8.0, 0.1 * (k % 5) as f32), n)
            })
            .collect();
        for hole in [0.0f32, 8.0, 40.0] {
            // The wall: y from -20 to 20 except (-hole/2, hole/2), z from -5 to 5.
            let mut pos = Vec::new();
            for (y0, y1) in [(-20.0, -hole / 2.0), (hole / 2.0, 20.0)] {
                if y1 > y0 {
                    for (y, z) in [(y0, -5.0), (y1, -5.0), (y1, 5.0), (y0, -5.0), (y1, 5.0), (y0, 5.0)] {
                        pos.push(Vec3::new(0.0, y, z));
                    }
                }
            }
            let mut uv = vec![glam::Vec2::ZERO; pos.len()];
            if pos.is_empty() {
                // No wall: a triangle far away keeps the scene valid.
                pos = vec![Vec3::new(50.0, 0.0, 0.0), Vec3::new(50.0, 1.0, 0.0), Vec3::new(50.0, 0.0, 1.0)];
                uv = vec![glam::Vec2::ZERO; 3];
            }
            let idx: Vec<u32> = (0..pos.len() as u32).collect();
            let scene = Scene::from_mesh(pos, uv, &idx);
            let bvh = Bvh::build(&scene);
            let (block_first, pair_block, visible) = pair_visibility(&bvh, &entries, &[], 100.0, None);
            let far = Far { radius: 100.0, block_first, pair_block, visible, ..Far::default() };
            let mut across = 0;
            for i in 0..64 {
                for j in 64..128 {
                    let (a, b) = (&entries[i], &entries[j]);
                    let want = bvh.visible(a.position, a.normal, b.position, b.normal);
                    assert_eq!(far.sees(i, j), want, "hole {hole}: pair {i} {j}");
                    assert_eq!(far.sees(j, i), want);
                    across += want as usize;
                }
            }
            match hole {
                // A ray exactly along the wall's diagonal may slip between its two triangles
                // (both answers agree on it): a few, not the rows' 4096.
                0.0 => assert!(across * 100 < 64 * 64, "{across} through the wall"),
                40.0 => assert_eq!(across, 64 * 64),
                _ => assert!(across > 0 && across < 64 * 64, "{across}"),
            }
        }
    }
}
