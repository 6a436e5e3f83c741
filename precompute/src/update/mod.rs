//! `prm precompute --update OLD.prm LEVEL.glb -o NEW.prm` (issue 14, item 3): after an edit,
//! walk again only the texels whose panes the edit can change, and write the file a full
//! precompute with OLD's clusters would write, byte for byte.
//!
//! **What is kept.** The walks are the precompute's cost (3.6 s of the chamber's 5.8 s); the
//! rest (texels, entries, near and far fields, smoothing) is recomputed, which is also what
//! makes every tile's other inputs comparable, but for what lies in rooms the edit did not
//! touch ([`Untouched`], below under *Rooms*): there the far field's pairs of entry blocks and
//! the texels' near links are the old bake's (on 16 chambers those two were 19 of a plain
//! update's 44 s). In a touched room they are the old bake's too where geometry shows the edit
//! cannot reach them (`crate::far::FarReuse`, `crate::near::NearReuse`): a pair of unchanged
//! blocks whose entries' box misses the edit's boxes, a texel none of whose candidate cells
//! changed and whose box with them misses the edit's (on the halls, one room joined by doors,
//! far 7.0 -> 2.7 s). A ray the two trees answer differently where it grazes an edge (one
//! pair of 256,367 on the halls) then keeps the old bake's answer: a difference from the twin
//! of that one bit, not of the byte. Every tile's digest is still made again: a tile of an
//! untouched room can carry a trace (1e-11) of a touched room's clusters through the far
//! field's first bounce.
//! That digest holds what the exact first bounce is made of, not its values: per texel its
//! far-field neighbours' pair bits and the cells, normals, flux and clusters of the entries
//! those bits say they see, and its links' cells (`Preamble::exact_digests`). The values
//! cost the far field's sum over every entry in view at every texel, 8 s of an update of the
//! 16 chambers; the inputs cost a few words per texel.
//! The clustering is OLD's: k-means over all entries moves every cluster a little when one
//! object moves, and a pane of a cluster whose members changed cannot be reused. So an update
//! writes what a full precompute *given OLD's clusters* writes
//! ([`crate::precompute::Reuse::Clusters`]), the twin its tests hold it to (to the byte, or
//! within float noise: below); against a fresh precompute (which re-clusters) it is within the
//! distance between two fresh precomputes of different seeds. A material edit leaves the
//! entries where they were, so the clusters agree and so does everything: the update is then
//! byte for byte the fresh precompute.
//!
//! **What is walked again.** A texel's walks give the same contributions after the edit when
//! every segment of them stayed clear of everything the edit changed: the triangles whose
//! corners, normals, UVs or material changed (where they were and where they are), and the
//! cells and sites of entries that moved (the gather credits a hit to the nearest entry on the
//! triangle hit), and the cells whose row of the walks' next-bounce table changed
//! (`crate::transport::NextBounce`: a walk through such a cell reads its row, so an edit that
//! shades a cell reaches every walk through it; the cache keeps a digest per row, of its
//! values and of its inputs, and an update makes again only the rows whose inputs changed to
//! compare their values). The table the walks read holds only the rows of the rooms they can
//! reach: those the walked tiles' walks lay in when baked, and those the edit touched; a walk
//! that meets a row left out (a gap narrower than the rooms' voxels, below) refuses the update
//! (`TransportStats::rows_left_out`), which then runs a full precompute. The bake
//! of OLD recorded, per atlas tile, the voxels its texels' walks passed
//! through ([`footprint`]), and a digest of the tile's other inputs (its texels, what their
//! exact first bounce is made of, their near-link shares, their smoothing taps, the dilation
//! into the tile). A
//! tile is *hit* when its footprint meets the edit's voxels (grown by one, which makes the
//! coarse footprint conservative) or its digest changed; a tile is *re-encoded* when it is hit
//! or one of its texels reads a hit tile's texel through the smoothing's taps or the
//! dilation's sources; and the texels walked again are those the re-encoded tiles' values are
//! made of (their taps' taps). Every other tile's codes and energies come from OLD's cache.
//!
//! **Rooms.** The footprint grid is coarse on a large level (1.1 m voxels on 16 chambers), so
//! grown by one it reaches through a wall into the next room, whose walks never meet the
//! edit. The bake also records, per tile, the rooms (`prm::rooms`) its walks' segments lay in
//! (a few points of each segment that fall in free voxels, `Rooms::rooms_on_segment`; a texel
//! none of whose walks was placed makes the tile's rooms [`ANY_ROOM`]). A walk is a path
//! through connected free space, so it lies in one room, the room of every walk from the
//! same texel (a walk of short segments in corners may not be placed itself), and a walk
//! that passed through what an edit changed lies in a room with free voxels within two
//! voxels of the edit's boxes ([`Edit::rooms`],
//! found in the level as baked, rebuilt from the cache's triangles). A tile is then hit by
//! the footprint only if its rooms meet those. What this can miss: a walk through a gap
//! narrower than about two voxels (which parts rooms), placed on one side of it only, that
//! met the edit on the other; or one that met the edit only in a slot narrower than about
//! two voxels, whose free voxels lie further from it. (Points on surfaces seen along their
//! normals, `Rooms::room_of`, were tried first: on the 16 chambers a third of them found
//! no free voxel, and some found the hollow of a pillar through its wall.) The rooms are
//! labelled in voxel order, so an edit can renumber them: the tiles taken from the cache have
//! their rooms mapped to the edited level's labels ([`relabel`]).
//!
//! **Float noise.** Moving an object rounds its corners where they now are, so its
//! triangles' areas move in their last bits. The entries' strata are laid out over areas
//! rounded to 16 mantissa bits (`crate::entries::sample_entries`), so unless a moved
//! triangle's area crosses a rounding step no other entry moves at all, and the update is its
//! twin to the byte (the test's case). As a second guard the digests and the entry comparison
//! hold floats to 16 mantissa bits (1.5e-5): where a crossing does move entries by an ulp,
//! tiles whose inputs moved by less are still reused, and the update then differs from its
//! twin by that noise (the tests hold maps to 1e-4), not by the byte.
//!
//! **When an update is refused** (the caller then runs a full precompute): other parameters;
//! triangles added or removed; a different number of entries (the edit changed the surface's
//! area, or what lies inside solids); the level's bounds moved (every ray's offsets follow
//! its diagonal, so nothing traced before is what a full precompute traces); the MIS or
//! scatter estimators (their walks depend on every cluster's entries).
//!
//! **Texels.** A texel keeps its near and echo links (settled, or by geometry) only where the
//! old bake had the same texel at its atlas index ([`same_texels`]): an edit of lightmap UVs
//! can give an atlas slot to another triangle, and moved geometry can move an unchanged
//! triangle's buried sample point (a review found both, session 68).

pub mod cache;
pub mod footprint;

use glam::Vec3;
use prm::fingerprint::{fnv1a, FNV_START};
use prm::prm_file::{Cells, Entry};
use prm::rooms::Rooms;
use prm::{Scene, Smoothing, TexelSet};

pub use cache::{CacheError, CachedTile, TileRecord, UpdateCache};
pub use footprint::{Recorder, VoxelGrid};

use crate::transport::{LinkedCells, ANY_ROOM};

/// Why an update cannot reuse OLD's bake (module doc): the caller runs a full precompute.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct Refused(pub String);

/// A triangle's corners and the digest of everything the walks read of it.
pub type TriangleDigest = ([Vec3; 3], u64);

/// Per triangle: its corners and a digest of everything the walks read of it: corners, shading
/// normals, lightmap and albedo UVs, the material's albedo, sidedness and texture.
pub fn triangle_digests(scene: &Scene) -> Vec<TriangleDigest> {
    let textures: Vec<u64> = scene
        .textures
        .iter()
        .map(|t| {
            let h = fnv1a(FNV_START, &[t.width.to_le_bytes(), t.height.to_le_bytes()].concat());
            t.texels.iter().fold(h, |h, v| mix(h, &v.to_array()))
        })
        .collect();
    (0..scene.triangles.len())
        .map(|t| {
            let tri = &scene.triangles[t];
            let corners = scene.corners(t);
            let mut h = FNV_START;
            for (k, &v) in tri.v.iter().enumerate() {
                let v = v as usize;
                h = mix(h, &corners[k].to_array());
                h = mix(h, &scene.normals[v].to_array());
                h = mix(h, &scene.uv1[v].to_array());
                h = mix(h, &scene.uv_albedo[v].to_array());
            }
            let m = scene.material(t);
            h = mix(h, &m.albedo.to_array());
            h = fnv1a(h, &[m.double_sided as u8]);
            let tex = m.albedo_texture.and_then(|i| textures.get(i as usize)).copied().unwrap_or(0);
            (corners, fnv1a(h, &tex.to_le_bytes()))
        })
        .collect()
}

/// FNV-1a over floats' bytes.
fn mix(h: u64, xs: &[f32]) -> u64 {
    xs.iter().fold(h, |h, x| fnv1a(h, &x.to_le_bytes()))
}

/// A float to 16 of its 23 mantissa bits (1.5e-5 relative), rounded: what a tile's digest
/// compares (module doc, float noise).
pub(crate) fn coarse(x: f32) -> u32 {
    round16(x).to_bits()
}

/// Mixes a word into a digest (splitmix64's finaliser over `h ^ w`): the input digests'
/// step, a word at a time where FNV-1a goes a byte at a time.
pub(crate) fn mix_word(h: u64, w: u64) -> u64 {
    let mut z = (h ^ w).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// [`mix_word`] over floats at [`coarse`] precision.
pub(crate) fn mix_floats(h: u64, xs: &[f32]) -> u64 {
    xs.iter().fold(h, |h, &x| mix_word(h, u64::from(coarse(x))))
}

/// `x` rounded to 16 of its 23 mantissa bits (1.5e-5 relative): the precision at which an
/// update takes values as unchanged, and at which entry strata are laid out
/// (`crate::entries::sample_entries`), so float noise from a moved object does not spread.
pub fn round16(x: f32) -> f32 {
    f32::from_bits(x.to_bits().wrapping_add(0x40) & !0x7f)
}

/// FNV-1a over floats at [`coarse`] precision.
fn mix_coarse(h: u64, xs: &[f32]) -> u64 {
    xs.iter().fold(h, |h, &x| fnv1a(h, &coarse(x).to_le_bytes()))
}

/// Two points equal to within [`coarse`]'s precision of the larger.
fn near(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() <= 3e-5 * a.abs().max(b.abs()).max_element().max(1e-3)
}

/// Two entries the same but for float noise (module doc: what an update takes as unchanged).
fn same_entry(a: &Entry, b: &Entry) -> bool {
    a.triangle == b.triangle
        && near(a.position, b.position)
        && near(a.normal, b.normal)
        && near(a.albedo, b.albedo)
        && (a.area - b.area).abs() <= 3e-5 * a.area.abs().max(b.area.abs())
}

/// Two cells the same but for float noise.
fn same_cell(a: &[[Vec3; 3]], b: &[[Vec3; 3]]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (0..3).all(|k| near(x[k], y[k])))
}

/// Atlas tile of a texel.
pub fn tile_of(i: u32, j: u32, tile_size: u32, tiles_x: usize) -> usize {
    (j / tile_size) as usize * tiles_x + (i / tile_size) as usize
}

/// Per atlas tile, a digest of what its own covered texels' values are made of besides their
/// walks (module doc): the texels, what their exact first bounce is made of (`exact`, per
/// covered texel: `Preamble::exact_digests`), their near-link shares, their smoothing taps and
/// the dilation records whose target lies in the tile.
pub fn tile_digests(
    set: &TexelSet,
    tile_size: u32,
    smoothing: Option<&Smoothing>,
    linked: Option<&LinkedCells>,
    exact: &[u64],
) -> Vec<u64> {
    let tx = set.width.div_ceil(tile_size) as usize;
    let ty = set.height.div_ceil(tile_size) as usize;
    let mut h = vec![FNV_START; tx * ty];
    for (k, t) in set.texels.iter().enumerate() {
        let d = &mut h[tile_of(t.i, t.j, tile_size, tx)];
        let atlas = t.j * set.width + t.i;
        let mut x = fnv1a(*d, &[t.i.to_le_bytes(), t.j.to_le_bytes(), t.triangle.to_le_bytes()].concat());
        for v in [t.position, t.normal, t.bary] {
            x = mix_coarse(x, &v.to_array());
        }
        x = fnv1a(x, &exact.get(k).copied().unwrap_or(0).to_le_bytes());
        if let Some(l) = linked {
            let (links, keep) = l.of(atlas);
            for (link, &s) in links.iter().zip(keep) {
                x = fnv1a(x, &link.entry.to_le_bytes());
                x = mix_coarse(x, &[link.factor, s]);
            }
        }
        if let Some(s) = smoothing {
            for &(n, w) in s.taps(0, k).iter().chain(s.taps(1, k)) {
                x = fnv1a(x, &n.to_le_bytes());
                x = mix_coarse(x, &[w]);
            }
        }
        *d = x;
    }
    for dl in &set.dilation {
        let (i, j) = (dl.target % set.width, dl.target / set.width);
        let d = &mut h[tile_of(i, j, tile_size, tx)];
        *d = fnv1a(*d, &dl.target.to_le_bytes());
        for &s in &dl.sources[..dl.count as usize] {
            *d = fnv1a(*d, &s.to_le_bytes());
        }
    }
    h
}

/// What an edit changed (module doc): the footprint grid's voxels, grown by one, and the
/// boxes they were marked from.
pub struct Edit {
    pub voxels: Vec<u64>,
    pub boxes: Vec<(Vec3, Vec3)>,
}

impl Edit {
    /// The rooms of `rooms` (the level as baked) whose free voxels come within two voxels of
    /// one of the edit's boxes, sorted (module doc): a walk that passed through what the edit
    /// changed passed through the free space of one of them.
    pub fn rooms(&self, rooms: &Rooms) -> Vec<u32> {
        let mut out: Vec<u32> =
            self.boxes.iter().flat_map(|&(lo, hi)| rooms.rooms_in_box(lo, hi, 2)).collect();
        out.sort_unstable();
        out.dedup();
        out
    }
}

/// Whether a tile's walks lay in one of the `touched` rooms (both sorted; a tile's
/// [`ANY_ROOM`] meets every room).
pub fn meets(tile: &[u32], touched: &[u32]) -> bool {
    tile.last() == Some(&ANY_ROOM) || tile.iter().any(|r| touched.binary_search(r).is_ok())
}

/// A tile's rooms in the labels of the level after an edit (`map`: per room as baked, its
/// space's rooms now: [`Rooms::rooms_in`]); a room whose space is gone, or one the map does
/// not know, becomes [`ANY_ROOM`].
pub fn relabel(rooms: &[u32], map: &[Vec<u32>]) -> Vec<u32> {
    let mut out = Vec::new();
    for &r in rooms {
        match map.get(r as usize) {
            Some(now) if !now.is_empty() => out.extend_from_slice(now),
            _ => out.push(ANY_ROOM),
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// The voxels an edit changed, grown by one (module doc): triangles whose digest differs,
/// where they were and where they are, the cells and triangles of entries that differ, and
/// the cells whose row of the walks' next-bounce table differs (`rows`, this bake's row
/// digests: a walk through such a cell reads its row, wherever the edit that changed it).
pub fn edited_voxels(
    cache: &UpdateCache,
    now: &[TriangleDigest],
    scene: &Scene,
    old: (&[Entry], &Cells),
    new: (&[Entry], &Cells),
    rows: &[u64],
) -> Edit {
    let grid = &cache.grid;
    let mut bits = vec![0u64; grid.words()];
    let mut boxes = Vec::new();
    let mut mark = |pts: &[Vec3]| {
        let lo = pts.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
        let hi = pts.iter().fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
        if lo.is_finite() && hi.is_finite() {
            grid.mark_box(lo, hi, &mut bits);
            boxes.push((lo, hi));
        }
    };
    for ((was, a), (is, b)) in cache.triangles.iter().zip(now) {
        if a != b {
            mark(was);
            mark(is);
        }
    }
    for j in 0..old.0.len().min(new.0.len()) {
        if same_entry(&old.0[j], &new.0[j]) && same_cell(old.1.of(j), new.1.of(j)) {
            continue;
        }
        for cell in [old.1.of(j), new.1.of(j)] {
            cell.iter().for_each(|t| mark(t));
        }
        // The entry's site on its triangle (old and new): the owner of every point of that
        // triangle may change.
        let (a, b) = (&old.0[j], &new.0[j]);
        if let Some((corners, _)) = cache.triangles.get(a.triangle as usize) {
            mark(corners);
        }
        if (b.triangle as usize) < scene.triangles.len() {
            mark(&scene.corners(b.triangle as usize));
        }
        mark(&[a.position]);
        mark(&[b.position]);
    }
    if cache.rows != rows {
        for j in 0..old.0.len().min(new.0.len()) {
            if cache.rows.get(j) != rows.get(j) {
                for cell in [old.1.of(j), new.1.of(j)] {
                    cell.iter().for_each(|t| mark(t));
                }
            }
        }
    }
    Edit { voxels: grid.grow(&bits), boxes }
}

/// What of the preamble an update takes from the old bake: the rooms of the edited level
/// whose space lay in no room the edit touched, and the entries that are as the old bake had
/// them and lie in one of those (*settled*). The edit here is the triangles' and the entries'
/// ([`edited_voxels`] without the table's rows, which are made from the far field), the same
/// boxes the plan starts from.
pub struct Untouched {
    /// Rooms (of the edited level) whose space lay in a room the edit touched.
    pub touched: std::collections::BTreeSet<u32>,
    /// Per entry: settled.
    pub entry: Vec<bool>,
    /// Per triangle: as the old bake had it (its digest, [`triangle_digests`]).
    pub triangle: Vec<bool>,
    /// The rooms of the level as baked (which the cache's tiles name), and per room of it the
    /// edited level's rooms its space lies in ([`Rooms::rooms_in`]): the plan uses both.
    pub baked: Rooms,
    pub map: Vec<Vec<u32>>,
    /// Per entry: as the old bake had it, whatever its room (`settled` asks more).
    pub same: Vec<bool>,
    /// The old bake's entries' rooms, in the labels of the level as baked
    /// (`crate::cells::filled_rooms`, as that bake found them).
    pub old_room: Vec<u32>,
    /// The edit's boxes ([`Edit::boxes`], without the table's rows): every triangle changed,
    /// where it was and where it is, and every entry changed, its cells and sites. A ray
    /// between points of a box that meets none of them meets what it met before.
    pub boxes: EditBoxes,
    /// The entries changed (themselves or their cells): a texel near one may have it among its
    /// near links' cells.
    pub changed: ChangedCells,
}

impl Untouched {
    /// `rooms` and `room` (per entry) are the edited level's.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        cache: &UpdateCache,
        old: (&[Entry], &Cells),
        now: &[TriangleDigest],
        scene: &Scene,
        entries: &[Entry],
        cells: &Cells,
        rooms: &Rooms,
        room: &[u32],
    ) -> Untouched {
        let edit = edited_voxels(cache, now, scene, old, (entries, cells), &cache.rows);
        let corners: Vec<[Vec3; 3]> = cache.triangles.iter().map(|t| t.0).collect();
        let baked = Rooms::new(&corners);
        let map = baked.rooms_in(rooms);
        let touched: std::collections::BTreeSet<u32> = edit
            .rooms(&baked)
            .iter()
            .flat_map(|&r| map.get(r as usize).into_iter().flatten().copied())
            .collect();
        let same: Vec<bool> =
            (0..entries.len()).map(|j| old.0.get(j).is_some_and(|o| same_entry(o, &entries[j]))).collect();
        let entry = (0..entries.len())
            .map(|j| same[j] && room.get(j).is_some_and(|r| !touched.contains(r)))
            .collect();
        let triangle = cache.triangles.iter().zip(now).map(|(a, b)| a.1 == b.1).collect();
        let old_room = crate::cells::filled_rooms(&crate::cells::entry_rooms(&baked, old.0));
        let mut changed = Vec::new();
        for (j, e) in entries.iter().enumerate() {
            let kept = same[j] && same_cell(old.1.of(j), cells.of(j));
            if !kept {
                if let Some(o) = old.0.get(j) {
                    changed.push((old.1.centroid(j).unwrap_or(o.position), old.1.area(j).max(0.0).sqrt()));
                }
                changed.push((cells.centroid(j).unwrap_or(e.position), cells.area(j).max(0.0).sqrt()));
            }
        }
        let (boxes, changed) = (EditBoxes::new(edit.boxes), ChangedCells::new(changed));
        Untouched { touched, entry, triangle, baked, map, same, old_room, boxes, changed }
    }

    /// Per block of entries ([`prm::prm_file::Far::BLOCK`]): all settled. An update takes
    /// the far-field pairs of two such blocks from the old bake (`crate::far::FarReuse`).
    pub fn blocks(&self) -> Vec<bool> {
        self.entry.chunks(prm::prm_file::Far::BLOCK).map(|c| c.iter().all(|&s| s)).collect()
    }

    /// Per block of entries: every entry as it was, whatever its room.
    pub fn same_blocks(&self) -> Vec<bool> {
        self.same.chunks(prm::prm_file::Far::BLOCK).map(|c| c.iter().all(|&s| s)).collect()
    }

    /// Whether a texel on `triangle` in room `room` is settled: its triangle as it was and its
    /// room untouched, so its near links are the old bake's (`crate::near::near_links`). A
    /// texel of no room is not.
    pub fn texel(&self, triangle: u32, room: Option<u32>) -> bool {
        self.triangle.get(triangle as usize) == Some(&true)
            && room.is_some_and(|r| !self.touched.contains(&r))
    }
}

/// Per covered texel (`texels`, of an atlas `width` wide), whether the old bake had the same texel at its
/// atlas index: the same sample point and normal. A texel's links are kept (settled or by
/// geometry) only then: an edit of lightmap UVs can hand an atlas slot to another, unchanged
/// triangle far away, and geometry that moves can move an unchanged triangle's buried sample
/// point within its square (`prm::texels`), and the old links were made at the old point.
/// The far field keeps each lit texel's point exactly; elsewhere the near points keep it to
/// their 16-bit steps across their box, and a point within 1.5 steps (and a normal within
/// 1e-3) is taken as the same (a moved point moves by a part of a texel, many steps). A
/// texel the old bake kept neither of is not the same (its links are made again).
pub fn same_texels(
    texels: &[prm::Texel],
    width: u32,
    old_far: &[prm::prm_file::FarTexel],
    old_points: &[prm::prm_file::NearPoint],
) -> Vec<bool> {
    let (lo, hi) = prm::prm_file::near_point_box(old_points);
    let step = (hi - lo) / 65535.0;
    let width = width as usize;
    texels
        .iter()
        .map(|t| {
            let texel = (t.j as usize * width + t.i as usize) as u32;
            if let Ok(k) = old_far.binary_search_by_key(&texel, |f| f.texel) {
                let f = &old_far[k];
                return f.position == t.position && f.normal == t.normal;
            }
            match old_points.binary_search_by_key(&texel, |p| p.texel) {
                Ok(k) => {
                    let p = &old_points[k];
                    (p.position - t.position).abs().cmple(1.5 * step + Vec3::splat(1e-6)).all()
                        && p.normal.dot(t.normal) >= 1.0 - 1e-3
                }
                Err(_) => false,
            }
        })
        .collect()
}

/// Most boxes (or changed cells) an edit may have for what it spared to be kept by geometry
/// (`crate::far::FarReuse`, `crate::near::NearReuse`). A wider edit (a wall colour over the
/// whole chamber: thousands of entries changed) spares little, and testing every pair and
/// texel against every box cost more than it saved (the chamber's walls: near links 0.48 ->
/// 0.73 s); past this nothing is kept by geometry.
pub const MAX_GEOMETRY: usize = 4096;

/// The box around `items`' boxes (empty when there are none).
fn hull(items: impl Iterator<Item = (Vec3, Vec3)>) -> (Vec3, Vec3) {
    items.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (a, b)| (lo.min(a), hi.max(b)))
}

/// Whether two boxes overlap.
fn overlap((al, ah): (Vec3, Vec3), (bl, bh): (Vec3, Vec3)) -> bool {
    al.cmple(bh).all() && bl.cmple(ah).all()
}

/// The edit's boxes ([`Edit::boxes`]) as the far field's pairs and the near links kept by
/// geometry ask of them, with the box around them all to settle most questions at once.
#[derive(Clone, Debug)]
pub struct EditBoxes {
    boxes: Vec<(Vec3, Vec3)>,
    hull: (Vec3, Vec3),
    /// More than [`MAX_GEOMETRY`] boxes: nothing is clear.
    wide: bool,
}

impl EditBoxes {
    pub fn new(boxes: Vec<(Vec3, Vec3)>) -> EditBoxes {
        let wide = boxes.len() > MAX_GEOMETRY;
        EditBoxes { hull: hull(boxes.iter().copied()), boxes, wide }
    }

    /// Whether every ray between points of the box `lo..hi` (off their surfaces by `bvh`'s
    /// offsets, which grow the box) stays clear of the edit: such a ray meets the triangles it
    /// met before the edit.
    pub fn clear(&self, bvh: &prm::Bvh, lo: Vec3, hi: Vec3) -> bool {
        if self.wide {
            return false;
        }
        let m = Vec3::splat(2.0 * bvh.eps_at(lo.abs().max(hi.abs())));
        let b = (lo - m, hi + m);
        !overlap(b, self.hull) || !self.boxes.iter().any(|&x| overlap(b, x))
    }
}

/// The entries an edit changed (themselves or their cells), as the near links kept by
/// geometry ask of them: per entry its cell's centroid and the square root of its area, as
/// baked and as now (a texel within the near reach plus that of a centroid may have had, or
/// may have, that cell among its links' cells).
#[derive(Clone, Debug)]
pub struct ChangedCells {
    cells: Vec<(Vec3, f32)>,
    /// The centroids' box grown by the largest square root of an area.
    hull: (Vec3, Vec3),
    /// More than [`MAX_GEOMETRY`] cells: every texel is near one.
    wide: bool,
}

impl ChangedCells {
    pub fn new(cells: Vec<(Vec3, f32)>) -> ChangedCells {
        let s = cells.iter().fold(0.0f32, |m, &(_, s)| m.max(s));
        let (lo, hi) = hull(cells.iter().map(|&(c, _)| (c, c)));
        ChangedCells {
            hull: (lo - Vec3::splat(s), hi + Vec3::splat(s)),
            wide: cells.len() > MAX_GEOMETRY,
            cells,
        }
    }

    /// Whether a changed cell lies within `reach` (plus its own size) of `x`.
    pub fn near(&self, x: Vec3, reach: f32) -> bool {
        if self.wide {
            return true;
        }
        let r = Vec3::splat(reach);
        overlap((x - r, x + r), self.hull) && self.cells.iter().any(|&(c, s)| c.distance(x) <= reach + s)
    }
}

/// What an update does again (module doc).
pub struct Plan {
    /// Per atlas tile: its walks or other inputs changed.
    pub hit: Vec<bool>,
    /// Per atlas tile: encoded again (a hit tile within reach), else taken from the cache.
    pub dirty: Vec<bool>,
    /// Per covered texel (`TexelSet::texels` order): walked again.
    pub walk: Vec<bool>,
}

impl Plan {
    /// The plan for a level whose tiles have digests `digests`, against `cache`, given the
    /// edit's grown voxels `edited` and the rooms it touched (`touched`, labelled as in the
    /// level baked: [`Edit::rooms`]), following the smoothing's taps and the dilation's
    /// sources (module doc): a texel's stored value is its column taps' row-smoothed values,
    /// each of those its row taps' walked values.
    pub fn new(
        cache: &UpdateCache,
        set: &TexelSet,
        tile_size: u32,
        smoothing: Option<&Smoothing>,
        digests: &[u64],
        edited: &[u64],
        touched: &[u32],
    ) -> Plan {
        let tx = set.width.div_ceil(tile_size) as usize;
        let ty = set.height.div_ceil(tile_size) as usize;
        let hit: Vec<bool> = (0..tx * ty)
            .map(|k| {
                let rec = &cache.tiles[k];
                rec.inputs != digests[k]
                    || (rec.footprint.iter().zip(edited).any(|(a, b)| a & b != 0)
                        && meets(&rec.rooms, touched))
            })
            .collect();
        let tile = |k: usize| tile_of(set.texels[k].i, set.texels[k].j, tile_size, tx);
        let texel = |atlas: u32| set.index.get(atlas as usize).copied().filter(|&k| k != TexelSet::EMPTY);
        // Texels whose walks or own inputs may have changed, then those whose smoothed values
        // read them (rows, then columns).
        let walks: Vec<bool> = (0..set.len()).map(|k| hit[tile(k)]).collect();
        let spread = |from: &[bool], pass: usize| -> Vec<bool> {
            match smoothing {
                None => from.to_vec(),
                Some(s) => (0..set.len())
                    .map(|k| {
                        from[k]
                            || s.taps(pass, k)
                                .iter()
                                .any(|&(n, _)| texel(n).is_some_and(|m| from[m as usize]))
                    })
                    .collect(),
            }
        };
        let changed = spread(&spread(&walks, 0), 1);
        let mut dirty = vec![false; tx * ty];
        for k in (0..set.len()).filter(|&k| changed[k]) {
            dirty[tile(k)] = true;
        }
        for d in &set.dilation {
            if d.sources[..d.count as usize].iter().any(|&s| texel(s).is_some_and(|m| changed[m as usize])) {
                dirty[tile_of(d.target % set.width, d.target / set.width, tile_size, tx)] = true;
            }
        }
        for (k, &h) in hit.iter().enumerate() {
            dirty[k] |= h;
        }
        // What the dirty tiles' values are made of: their texels and dilation sources, their
        // column taps, and those texels' row taps.
        let mut need: Vec<bool> = (0..set.len()).map(|k| dirty[tile(k)]).collect();
        for d in &set.dilation {
            if dirty[tile_of(d.target % set.width, d.target / set.width, tile_size, tx)] {
                for &s in &d.sources[..d.count as usize] {
                    if let Some(m) = texel(s) {
                        need[m as usize] = true;
                    }
                }
            }
        }
        let gather = |from: &[bool], pass: usize| -> Vec<bool> {
            let mut out = from.to_vec();
            if let Some(s) = smoothing {
                for k in (0..set.len()).filter(|&k| from[k]) {
                    for &(n, _) in s.taps(pass, k) {
                        if let Some(m) = texel(n) {
                            out[m as usize] = true;
                        }
                    }
                }
            }
            out
        };
        let walk = gather(&gather(&need, 1), 0);
        Plan { hit, dirty, walk }
    }
}

/// Where the parameters, the level or the cache keep an update from reusing OLD's bake.
pub fn refusal(
    cache: &UpdateCache,
    params: &crate::precompute::PrecomputeParams,
    triangles: &[([Vec3; 3], u64)],
    tiles: usize,
) -> Option<Refused> {
    let canonical = params.canonical();
    if cache.params != canonical {
        return Some(Refused(format!(
            "the parameters differ from the old bake's ({} now, {} then)",
            canonical, cache.params
        )));
    }
    if params.estimator != crate::transport::Estimator::Gather {
        return Some(Refused(format!("the {} estimator's walks depend on every cluster", params.estimator)));
    }
    if triangles.len() != cache.triangles.len() {
        return Some(Refused(format!(
            "the level has {} triangles, the old bake had {}",
            triangles.len(),
            cache.triangles.len()
        )));
    }
    if tiles != cache.tiles.len() {
        return Some(Refused(format!("{tiles} atlas tiles now, {} then", cache.tiles.len())));
    }
    None
}

/// Why an update of a level whose bounds are `bounds` now cannot reuse the bake `cache` was
/// made with, if they moved. Every ray's offsets follow the level's diagonal
/// (`prm::Bvh::build`, from `prm::Scene::bounds`: every vertex, not only triangles'
/// corners), so no ray kept from the old bake would be the one a full precompute traces. (A
/// full precompute given OLD's clusters, the update's twin, does not ask.)
pub fn moved_bounds(cache: &UpdateCache, bounds: (Vec3, Vec3)) -> Option<Refused> {
    (bounds != cache.bounds).then(|| {
        Refused(format!(
            "the edit moved the level's bounds ({}..{} now, {}..{} then), and every ray's offsets with them",
            bounds.0, bounds.1, cache.bounds.0, cache.bounds.1
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use prm::prm_file::{FarTexel, NearPoint};

    /// A texel is the old bake's where its far-field record has the very same point and
    /// normal, or (lit by no far field) its near point is within the points' rounding; not
    /// where the point moved by a part of a texel, the normal turned, or the old bake kept
    /// neither.
    #[test]
    fn a_texel_is_the_old_bakes_only_at_the_same_point() {
        let texel = |i: u32, x: f32, n: Vec3| prm::Texel {
            i,
            j: 0,
            position: Vec3::new(x, 0.0, 0.0),
            normal: n,
            triangle: 0,
            bary: Vec3::ONE / 3.0,
        };
        let far = |t: u32, x: f32| FarTexel {
            texel: t,
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Y,
            ..Default::default()
        };
        // The near points span 10 m: steps of 0.15 mm.
        let point =
            |t: u32, x: f32| NearPoint { texel: t, position: Vec3::new(x, 0.0, 0.0), normal: Vec3::Y };
        let old_far = [far(0, 1.0), far(1, 2.0)];
        let old_points = [point(2, 3.0001), point(3, 4.0), point(9, 10.0), point(10, 0.0)];
        let now = [
            texel(0, 1.0, Vec3::Y),        // the far field's own point
            texel(1, 2.0 + 1e-6, Vec3::Y), // moved by an ulp or so: not the same bits
            texel(2, 3.0, Vec3::Y),        // within the near points' rounding
            texel(3, 4.02, Vec3::Y),       // moved 2 cm (a buried point placed again)
            texel(4, 5.0, Vec3::Y),        // the old bake kept neither
            texel(9, 10.0, Vec3::X),       // turned
        ];
        assert_eq!(
            same_texels(&now, 64, &old_far, &old_points),
            vec![true, false, true, false, false, false]
        );
    }
}
