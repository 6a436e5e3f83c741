//! The `.prm` file, format v14 (DESIGN.md §8): one level's precomputed radiance map.
//!
//! Layout, little-endian:
//!
//! ```text
//! 0   magic  b"PRMAP\0\r\n"     (the CR LF catches text-mode mangling)
//! 8   u32    version = 14 (10 to 13 are read too)
//! 12  u32    JSON header length H
//! 16  H      JSON header: fingerprint, atlas, pages, tile size, counts, parameters, statistics
//!     then sections, each  [u8; 4] tag, u64 byte length, payload:
//!     ENTR  N x 48 B: position, normal, albedo (3 x f32 each), area f32, triangle u32, stay
//!           share f32 (v12; v10 and v11 wrote 0 there and are read as every share 1)
//!     GAIN  (v14) N x 12 B: each entry's bounce gain (3 x f32), or empty (every gain its
//!           stay share, as in a file before v14)
//!     CELL  u32 T, then (N + 1) x u32: entry j's cell is triangles first[j] .. first[j + 1];
//!           then T x 36 B: three corners (3 x f32 each), counter-clockwise seen from the front
//!     NEAR  u32 R runs, u32 L links, u32 entry width W (2, 3 or 4); the box of the runs'
//!           points (min, max: 6 x f32); R x 16 B: texel u32 (row-major atlas index), link
//!           count u16, the texel's sample point (3 x u16 across the box), its normal
//!           (octahedral, 2 x i16 snorm); W = 3 (v11): R x u32, each run's smallest entry;
//!           L x 2 or 4 B: entry (u16; u16 above its run's smallest at W = 3; u32 at W = 4);
//!           L x f16: factor. Links sorted by texel then entry
//!     CLUS  C x 32 B: first member u32, member count u32, centroid (3 x f32), energy f32,
//!                     first tile u32, tile count u32
//!     MEMB  u32 entry indices, grouped by cluster
//!     GRUP  G x 16 B: energy f32, first tile u32, tile count u32, pad u32; then (when G > 0)
//!           C x u32: the group of each cluster
//!     MASK  ceil(W x H / 8) B: bit (j W + i) set where a texel is stored (covered or dilated)
//!     TILE  K x 20 B: pane u32 (cluster c < C, or group C + g), tile index u32, colour scale
//!           (3 x f32)
//!     DATA  u8 per-texel intensity code (`intensity`: 0, or 1e-4 .. 1 logarithmically, 3.7 %
//!           a step): for each tile in TILE order, its masked texels
//!           in row-major order (empty atlas texels are not stored)
//!     DIPO  (v6 to v12 only) u32 D, u32 K, u32 b, then the dipole panes: read only when
//!           D = 0, skipped (below)
//!     FARF  u32 T texels, u32 F block offsets (0, or B + 1 for B blocks of 32 entries), u32 P
//!           pairs of blocks, f32 reach, f32 radius; F x u32: each block's first pair, then P;
//!           P x u32: each pair's other block (ascending within a block); P x 32 x u32: each
//!           pair's visibility bits ([`Far`]); T x 60 B: texel u32, point (3 x f32), normal
//!           (3 x f32), 4 entries u32, 4 weights f32; then (when T > 0) N x f32: each entry's
//!           far-field energy per unit deviation (`Far::energy`). T = F = P = 0: no far field
//!     TXAR  (v17) T x f32: each far texel's area (`Far::areas`), or none
//! end u64    FNV-1a 64 checksum of every byte before it
//! ```
//!
//! A pane is the indirect irradiance (W/m², RGB) at every texel when its cluster's entry points
//! receive 1 W/m². Its texels are stored in tile_size x tile_size tiles of the atlas; tiles
//! holding a negligible share of the pane's energy are left out (the header says how much was
//! dropped). A texel's value is `scale x intensity`: one RGB scale per tile (the tile's mean
//! chromaticity times its peak luminance) and one 8-bit logarithmic intensity per texel
//! ([`intensity`]), so luminance is kept to within 1.9 % (half a step) down to 1e-4 of the
//! tile's peak, and colour to the tile's mean. A pane's colour is mostly its cluster's albedo,
//! the same over the tile; the saving is 6x over RGB half floats. (v4; v3 stored half floats.
//! Measured on the chamber's torch placements, the 8-bit codes change the PRM's error against
//! the ground truth by under 0.02 points: 256 panes' rounding averages out.)
//!
//! **Cells** (v3): the surface each entry stands for, as triangles that together tile the lit
//! surfaces (each entry's Voronoi cell among the entries of its triangle, plus the triangles too
//! small to hold an entry). The runtime's entry weight is the power its cell receives over the
//! entry's area, so a light close to a surface delivers its power however small its hot spot
//! (DESIGN.md §4). A v2 file has no cells and is refused: bake it again.
//!
//! **Near-field links** (v3): per texel, the entries whose cells lie within a few entry
//! spacings, with the first bounce each cell sends to the texel per unit weight. The runtime
//! adds `albedo_j (E_j - w_c(j) t_j) factor` over them: what the cluster mean leaves out next
//! to a hot spot (`prm_precompute::near`). Since v4 each linked texel also carries its sample
//! point and normal, so the runtime can weigh a cell's light by how the texel sees it (a hot
//! spot at the near edge of a cell counts for more than one at its far edge).
//!
//! **What a texel sees of each cell** (v15): per near link, a bit for each of the cell's
//! triangles (the first 64) the texel does not see ([`NearLink::hidden`]; a `SEEN` section
//! lists the few links that hide any, 2 % on the chamber). The link's factor counts the
//! triangles seen, and where a cell is lit unevenly the runtime weighs its light as the texel
//! sees it over those alone: a beam on a pillar's upper shaft lit the floor row before the
//! plinth at the cell's light as if that row saw the lower shaft too, half of it
//! (`docs/near-lights.md`, *What a texel sees of a hot cell*). A v14 file reads as every texel
//! seeing every triangle.
//!
//! **Crease points** (v16): near points past the texels' (their texel numbers past the
//! atlas's), each on a texel's square where a receiver of the echo sees that square (a floor
//! texel 6 mm from a wall sees the wall's lowest cm), with near links of their own; the echo
//! reads the source there (`CRSE` names each one's texel, [`Echo::creases`]). A v15 file has
//! none (`docs/near-lights.md`, *The echo read at the creases*).
//!
//! **Far field** (v7): what the near links leave out of the deviations' first bounce. A hot spot's
//! light reaches the whole room, and a pane spreads it over its cluster: the pillar faces 3 m
//! from a lamp beside a wall see the lamp's end of the wall, not the cluster's middle. Each
//! frame the runtime takes the entries whose deviation carries a share of the light and sends
//! it to every texel as from a point (its cell's flux, the two cosines over pi r²), the
//! visibility read from the entries' mutual visibility bits at the texel's nearest entries.
//! The near links fade out over `reach .. reach + cell size` from a cell as the far field fades
//! in, so the two add up to the whole first bounce (`prm_precompute::far`). Since v8 each
//! entry also carries the far field's energy per unit of its deviation, which the runtime's
//! cluster balance counts with the links' (v7's far field added its light on top of panes that
//! already held all of it: 6 % too much indirect light under a lamp 1 cm over a floor).
//!
//! **Pages** (v9): a level whose generated UVs need more than one lightmap page has them all in
//! the one atlas, stacked: `atlas_width`^2 pages down an atlas `pages` x `atlas_width` tall
//! (`crate::density::Atlas`). Texel, tile and mask indices run over the stack; the header says
//! how many pages there are and the texel size the UVs were packed at, so the level loads again
//! with the same UVs. The runtime's lightmap is a texture array of the pages.
//!
//! **Stay shares** (v12): per entry, the share of the light its cell reflects that lands on the
//! level (its cosine rays that hit a surface; the rest leaves through an opening, and since
//! v14 a ray from a point buried inside a solid is not counted and the back of a one-sided
//! surface seen from the open absorbs: `prm_precompute::cells::reflections`, 256 rays a cell
//! where v12 and v13 bakes drew 64). A pane answers even light over its cluster, so a cluster's
//! weight is a mean of its entries' light; v12 and v13 weighed each entry's light in that mean
//! by its stay share (since v14, by its bounce gain, whose first term it is), so a sunlit
//! window jamb (half of whose light leaves) in a cluster with the wall inside does not light
//! the room as the wall would. The far field's bar counts each entry's light by its stay
//! share. A closed level's shares are all 1.
//!
//! **Bounce gains** (v14): per entry, `g_j`, the light that lands on the level over every
//! bounce per unit its cell reflects (channel by channel): the stay share, plus what the cells
//! its light lands in send on (`prm_precompute::cells::reflections`). Under even light a pane's
//! total is the sum over its cluster's cells of `rho_j g_j t_j` (`t_j`: the cell's area over
//! an entry's share), so the runtime weighs each entry's light in its cluster's mean by
//! `rho_j g_j` (the stay share alone before v14): the mean then carries the total the lit
//! cells give, not the cluster's average cell's. Weighted
//! by the stay share alone, a flashlight on a pillar's shaft lit the whole chamber 3-4 % too
//! bright at every seed (`docs/near-lights.md`, *Bounce gains*). A file before v14 reads each
//! gain as its stay share. A bake since session 84 also scales each pane (its tiles' scales
//! and its energy) so that it delivers that total, its texels counted at the area of surface
//! they stand for (`prm_precompute::precompute::match_power`; the header's provenance
//! `power_scale` states the least and most scale, `match_power` whether it was done): the
//! format is the same.
//!
//! **Dipoles** (v6 to v12, gone in v13): up to three more panes per cluster answered light
//! growing linearly across it, weighted by the light's first moment over the cluster. Off by
//! default from the start, they were last measured worth having before the far field; with it
//! (session 82, the chamber's torch rig and the flashlight rig) every placement came out 2 to 6
//! times the error without them, so they were removed. A v12 file without them reads as before;
//! one with them is refused, to be baked again.
//!
//! **Groups** (v2) are a coarse level over the clusters: each group's pane is the sum of its
//! clusters' panes. A runtime composing only the K strongest clusters adds each group's pane
//! weighted by the light of its clusters left out (the runtime's residual weights), so the light
//! of the many weak clusters is kept in total and placed at the group's scale instead of lost.
//!
//! Loading checks, before using anything: magic, version, the checksum, every section length
//! against the file (`sections`), then the invariants every [`Prm`] holds, however made
//! ([`Prm::new`]: every index against its table, tile ranges, finite values), and (when a
//! scene is given) the [`crate::fingerprint`] of the scene geometry, lightmap UVs, albedos and
//! atlas layout. Any mismatch is a [`PrmError`] naming the file and the problem. Writing is
//! atomic.
//!
//! This module is the format only: weighting, selecting and composing panes is the runtime's
//! (its CPU twin in `prm_runtime::cpu`).

mod check;
mod reduce;
mod sections;

use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::fingerprint::{fingerprint_hex, fnv1a, FNV_START};
use crate::luminance;
use crate::scene::Scene;
pub use reduce::Reduced;
use sections::{Reader, SectionError, Writer};

/// File magic.
pub const MAGIC: [u8; 8] = *b"PRMAP\0\r\n";
/// The format version this code writes.
pub const VERSION: u32 = 17;
/// The oldest version this code reads: a v10 file is a v11 file whose near links never take
/// the per-run bases (`NEAR` width 3, added in v11 for levels of more than 65,536 entries), and
/// a v11 file a v12 one without stay shares (every entry's light taken to stay), and a v12
/// file a v13 one with a `DIPO` section, read when it holds no dipole panes, and a v13 file a
/// v14 one without bounce gains (each gain its stay share), and a v14 file a v15 one whose
/// texels see every triangle of their links' cells (no `SEEN` section), and a v15 file a v16
/// one without crease points (no `CRSE` section), and a v16 file a v17 one without the far
/// texels' areas (no `TXAR` section: the runtime's lift then keeps the panes' energy as the
/// balance set it).
pub const OLDEST_READ: u32 = 10;

/// An entry point (DESIGN.md §4).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Entry {
    pub position: Vec3,
    /// Unit front-face normal.
    pub normal: Vec3,
    /// Linear albedo at the entry.
    pub albedo: Vec3,
    /// Surface area the entry stands for (A / N), square scene units.
    pub area: f32,
    /// Scene triangle it lies on.
    pub triangle: u32,
}

/// The most times [`Cells::split_long`] halves one triangle of a cell (4,096 pieces at most).
pub const SPLIT_DEPTH: u32 = 12;

/// The surface each entry point stands for (its *cell*), as triangles counter-clockwise seen
/// from the front: entry j owns `triangles[first[j]..first[j + 1]]`. Together the cells tile
/// the surfaces light can reach (module doc).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cells {
    /// N + 1 offsets into `triangles`, from 0 to its length, non-decreasing.
    pub first: Vec<u32>,
    pub triangles: Vec<[Vec3; 3]>,
}

impl Cells {
    /// Cells from each entry's list of triangles.
    pub fn from_lists(lists: Vec<Vec<[Vec3; 3]>>) -> Cells {
        let mut first = Vec::with_capacity(lists.len() + 1);
        first.push(0);
        let mut triangles = Vec::new();
        for l in lists {
            triangles.extend(l);
            first.push(triangles.len() as u32);
        }
        Cells { first, triangles }
    }

    /// The same cells with every triangle whose longest edge exceeds `max_edge` cut in two at
    /// that edge's midpoint, again until none does (at most [`SPLIT_DEPTH`] times; a
    /// non-finite or non-positive `max_edge` cuts nothing). Each cell covers what it covered,
    /// wound as it was.
    ///
    /// The runtime reads a cell's light at a fixed number of points per triangle (its fine
    /// points, `prm::cell_light::FINE_SUB`² of them): a cell fanned from its entry into long
    /// slivers places them a fifth of a metre apart along a sliver, and a texel beside the
    /// cell's edge sees the few centimetres nearest to it. A window's jamb one cell of 0.25 x
    /// 1.4 m, sunlit but for a strip shaded by the head above it: the head saw the jamb 0.55-0.77
    /// of its mean light, by how the fan fell, against 0.51-0.52 over a fine grid of rays.
    pub fn split_long(&self, max_edge: f32) -> Cells {
        self.split_long_from(max_edge).0
    }

    /// [`Self::split_long`], and per triangle of the cut cells (in their order) the index of
    /// the triangle of `self` it was cut from: a triangle's pieces follow one another, in the
    /// order of the triangles they come from.
    pub fn split_long_from(&self, max_edge: f32) -> (Cells, Vec<u32>) {
        if !(max_edge > 0.0 && max_edge.is_finite()) {
            return (self.clone(), (0..self.triangles.len() as u32).collect());
        }
        let mut from = Vec::with_capacity(self.triangles.len());
        let lists = (0..self.first.len().saturating_sub(1))
            .map(|j| {
                let mut out = Vec::with_capacity(self.of(j).len());
                for (k, &whole) in self.of(j).iter().enumerate() {
                    let before = out.len();
                    let mut stack: Vec<([Vec3; 3], u32)> = vec![(whole, 0)];
                    while let Some((t, depth)) = stack.pop() {
                        let edge = |k: usize| t[k].distance(t[(k + 1) % 3]);
                        let k = (0..3).fold(0, |best, k| if edge(k) > edge(best) { k } else { best });
                        if !(edge(k) > max_edge) || depth >= SPLIT_DEPTH {
                            out.push(t);
                            continue;
                        }
                        let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                        let m = (a + b) * 0.5;
                        // Both halves keep the triangle's winding; the one at `a` comes first.
                        stack.push(([m, b, c], depth + 1));
                        stack.push(([a, m, c], depth + 1));
                    }
                    from.extend(std::iter::repeat_n(self.first[j] + k as u32, out.len() - before));
                }
                out
            })
            .collect();
        (Cells::from_lists(lists), from)
    }

    /// The triangles of entry `j`'s cell.
    pub fn of(&self, j: usize) -> &[[Vec3; 3]] {
        &self.triangles[self.first[j] as usize..self.first[j + 1] as usize]
    }

    /// Total area of entry `j`'s cell.
    pub fn area(&self, j: usize) -> f32 {
        self.of(j).iter().map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()).sum()
    }

    /// Entry `j`'s cell as a set to draw points from, evenly by area.
    pub fn spread(&self, j: usize) -> CellSpread<'_> {
        let triangles = self.of(j);
        let areas: Vec<f32> =
            triangles.iter().map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()).collect();
        CellSpread { total: areas.iter().sum(), triangles, areas }
    }

    /// The area-weighted centroid of entry `j`'s cell (None for a cell of no area).
    pub fn centroid(&self, j: usize) -> Option<Vec3> {
        let (mut c, mut a) = (Vec3::ZERO, 0.0f32);
        for t in self.of(j) {
            let at = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
            c += (t[0] + t[1] + t[2]) / 3.0 * at;
            a += at;
        }
        (a > 0.0).then(|| c / a)
    }
}

/// One cell's triangles with their areas ([`Cells::spread`]): points drawn from it are even
/// over the cell's area.
pub struct CellSpread<'a> {
    triangles: &'a [[Vec3; 3]],
    areas: Vec<f32>,
    /// The cell's area.
    pub total: f32,
}

impl CellSpread<'_> {
    /// The point that three numbers uniform in [0, 1) pick, and the normal of the triangle it
    /// lies on: `r` picks the triangle by area, `(u, v)` the point in it (folded into the
    /// triangle where `u + v > 1`). Call only on a cell of positive area.
    pub fn point(&self, r: f32, u: f32, v: f32) -> (Vec3, Vec3) {
        let mut pick = r * self.total;
        let mut t = 0;
        while t + 1 < self.triangles.len() && pick > self.areas[t] {
            pick -= self.areas[t];
            t += 1;
        }
        let [a, b, c] = self.triangles[t];
        let (u, v) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
        (a + (b - a) * u + (c - a) * v, (b - a).cross(c - a).normalize())
    }
}

/// A near-field link: texel `texel` (row-major atlas index) receives `albedo x factor` W/m² of
/// first bounce per W/m² of weight on entry `entry` (module doc). Stored as a half float: a
/// bake rounds the factor to one before it makes the map, so a map and its file agree.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NearLink {
    pub texel: u32,
    pub entry: u32,
    pub factor: f32,
    /// Bit t (t below [`HIDDEN_TRIANGLES`]): the texel does not see triangle t of its entry's
    /// cell (in [`Cells::of`] order; most of its points hidden). The factor counts only the
    /// triangles seen, and the runtime's concentration weighs a hot cell's light as the texel
    /// sees it over the same ones (`prm_runtime::cpu::concentrate`): a floor texel before a
    /// plinth does not see a pillar's lower shaft, where a beam on the upper shaft puts no
    /// light. 0 where the texel sees every triangle (most links). Since v15; 0 in older files.
    pub hidden: u64,
}

/// The cell triangles past this many have no [`NearLink::hidden`] bit: taken as seen.
pub const HIDDEN_TRIANGLES: usize = 64;

/// Whether a link's texel sees triangle `t` of its cell, by its [`NearLink::hidden`] bits.
pub fn sees_triangle(hidden: u64, t: usize) -> bool {
    t >= HIDDEN_TRIANGLES || (hidden >> t) & 1 == 0
}

/// The sample point and unit normal of a texel with near-field links (one per run of links,
/// in the same order). Stored as 16-bit positions across the box of all of them and an
/// octahedral 16-bit normal; [`round_near_points`] rounds them as the file stores them.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NearPoint {
    pub texel: u32,
    pub position: Vec3,
    pub normal: Vec3,
}

/// The near field's second and third bounce (`prm_precompute::near`, the echo): point
/// `receiver` gets `factor` (the form factor from its point to the source texel's square) times
/// the source's albedo times the source's near-field irradiance. Both are indices into
/// [`Prm::near_points`]. Stored as a half float, rounded by the bake as for [`NearLink`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EchoLink {
    pub receiver: u32,
    pub source: u32,
    pub factor: f32,
}

/// The echo of the near field: each near point's albedo (8-bit linear, [`round_albedo`]) and
/// the links, sorted by receiver then source. Empty when the map has none.
///
/// `creases` (v16): the near points past the texels' are *crease points*, one per entry here,
/// each naming the near point (a texel's) on whose square it lies. A receiver a few mm from a
/// wall sees the wall's strip next to it far more than the rest of the wall texel's square, and
/// where a hot spot lights the receiver's side of the crease, that strip takes several times
/// the first bounce the texel's own point does: the echo reads the source's light at a point
/// of the square where the receiver sees it ([`Echo::creases`]'s points have near links of their
/// own, their texel `texel_count + k`), and the source's own echo, for the third bounce, at its
/// texel. Crease points are sources only, never composed.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Echo {
    pub albedo: Vec<Vec3>,
    pub links: Vec<EchoLink>,
    /// Per crease point (the last `creases.len()` near points), its texel's near point.
    #[serde(default)]
    pub creases: Vec<u32>,
}

/// An albedo as the file stores it: each channel in 1/255 steps of [0, 1].
pub fn round_albedo(a: Vec3) -> Vec3 {
    (a.clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round() / 255.0
}

/// The box of `points` (min, max); zero-size for none.
pub fn near_point_box(points: &[NearPoint]) -> (Vec3, Vec3) {
    if points.is_empty() {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    points
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p.position), hi.max(p.position)))
}

/// Position `p` as 16-bit steps across the box `(lo, hi)`.
pub(crate) fn quantize_position(p: Vec3, (lo, hi): (Vec3, Vec3)) -> [u16; 3] {
    let span = hi - lo;
    let q = |x: f32, l: f32, s: f32| {
        if s > 0.0 {
            ((x - l) / s * 65535.0).round().clamp(0.0, 65535.0) as u16
        } else {
            0
        }
    };
    [q(p.x, lo.x, span.x), q(p.y, lo.y, span.y), q(p.z, lo.z, span.z)]
}

/// The position 16-bit steps `q` stand for across the box `(lo, hi)`.
pub(crate) fn dequantize_position(q: [u16; 3], (lo, hi): (Vec3, Vec3)) -> Vec3 {
    lo + (hi - lo) * Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32) / 65535.0
}

/// Unit vector `n` in octahedral coordinates, snorm16.
pub(crate) fn encode_octahedral(n: Vec3) -> [i16; 2] {
    let p = n / (n.x.abs() + n.y.abs() + n.z.abs()).max(1e-30);
    let (x, y) = if p.z >= 0.0 {
        (p.x, p.y)
    } else {
        ((1.0 - p.y.abs()) * p.x.signum(), (1.0 - p.x.abs()) * p.y.signum())
    };
    let s = |v: f32| (v.clamp(-1.0, 1.0) * 32767.0).round() as i16;
    [s(x), s(y)]
}

/// The unit vector of octahedral snorm16 coordinates `q`.
pub(crate) fn decode_octahedral(q: [i16; 2]) -> Vec3 {
    let (x, y) = (q[0] as f32 / 32767.0, q[1] as f32 / 32767.0);
    let z = 1.0 - x.abs() - y.abs();
    let v = if z >= 0.0 {
        Vec3::new(x, y, z)
    } else {
        Vec3::new((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum(), z)
    };
    v.normalize_or_zero()
}

/// Round `points` as the file stores them (a bake keeps what its file will say).
pub fn round_near_points(points: &mut [NearPoint]) {
    let bounds = near_point_box(points);
    round_near_points_within(points, bounds);
}

/// Round `points` as a file whose near points span the box `bounds` stores them (the crease
/// points, which lie within the texels' box).
pub fn round_near_points_within(points: &mut [NearPoint], bounds: (Vec3, Vec3)) {
    for p in points {
        p.position = dequantize_position(quantize_position(p.position, bounds), bounds);
        p.normal = decode_octahedral(encode_octahedral(p.normal));
    }
}

/// A texel the far field lights (`Far`): its sample point and unit normal, and the entries
/// (up to four; weight 0 for an unused one) whose visibility it borrows, weights summing to 1.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FarTexel {
    /// Row-major atlas index.
    pub texel: u32,
    pub position: Vec3,
    pub normal: Vec3,
    pub entries: [u32; 4],
    pub weights: [f32; 4],
}

/// The far field (`prm_precompute::far`; module doc): the distance where it starts to take over
/// from the near links, the entries' mutual visibility within `radius` and the texels it lights,
/// sorted by texel. Empty when the map has none.
///
/// The visibility is kept by blocks of [`Far::BLOCK`] consecutive entries (v10): for each block,
/// the blocks within `radius` of it that it sees anything of, ascending, each with a 32 x 32 bit
/// matrix. Both orders of a pair of blocks are stored, so a block's row answers for all its
/// entries and a run over ascending sources walks it once. Entries farther apart than `radius`
/// exchange no far-field light; the visibility grows with the level, not with its square (v9
/// kept a bit for every pair of entries: 41.5 MB on the 4 x 4 halls, and none past 65,536
/// entries).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Far {
    /// The far field has no share of a cell's light closer than this (scene units) and all of
    /// it beyond `reach` plus the cell's size ([`far_share`]).
    pub reach: f32,
    /// Entries farther apart than this (scene units) see nothing of each other's far field.
    pub radius: f32,
    /// Per block of entries, where its pairs start in `pair_block`; then the pair count (blocks
    /// + 1 offsets, or none without a far field).
    pub block_first: Vec<u32>,
    /// Per pair of blocks, the other block, ascending within each block's run.
    pub pair_block: Vec<u32>,
    /// Per pair of blocks (a, b), [`Far::BLOCK`] words: bit c of word r is set when entry
    /// `BLOCK a + r` sees entry `BLOCK b + c`.
    pub visible: Vec<u32>,
    pub texels: Vec<FarTexel>,
    /// Per entry (v8): the energy (luminance summed over texels, a pane's unit) the far field
    /// delivers per W/m² of the entry's deviation, for the runtime's cluster balance, which
    /// counts it with the near links' so that panes, links and far field together keep a
    /// cluster's light (`prm_precompute::far`). A map with atlas tiles left out
    /// ([`Prm::without_atlas_tiles`]) adds here the energy of the near links it cut.
    pub energy: Vec<f32>,
    /// Per far texel (v17; empty in an older map): the area of surface it stands for (scene
    /// units², `prm::TexelSet::visible_areas`), so the runtime can sum the near and far fields'
    /// power and keep each room's light at the power its cells send (`prm_runtime::cpu::
    /// lift_weights`).
    pub areas: Vec<f32>,
}

impl Echo {
    /// Per near point x, the energy (summed over texels, luminance) that one unit of near-field
    /// irradiance at x delivers with its echo: `1 + a_x S_x + a_x sum_y F_yx a_y S_y`, where `a`
    /// is the point's albedo luminance and `S_x` the sum of the echo factors with source x (what
    /// the echo's first bounce from x puts on all receivers per unit of radiosity). `points`:
    /// the near points' count.
    pub fn gain(&self, points: usize) -> Vec<f32> {
        let mut spread = vec![0.0f32; points];
        for l in &self.links {
            spread[l.source as usize] += l.factor;
        }
        // A receiver's own echo goes on from its texel's point and from each of its crease
        // points (theirs is their texel's, [`Echo::creases`]).
        let first_crease = points.saturating_sub(self.creases.len());
        let mut onward = spread.clone();
        for (k, &parent) in self.creases.iter().enumerate() {
            if let (Some(&s), Some(o)) = (spread.get(first_crease + k), onward.get_mut(parent as usize)) {
                *o += s;
            }
        }
        let a: Vec<f32> = (0..points).map(|k| self.albedo.get(k).map_or(0.0, |&v| luminance(v))).collect();
        let mut second = vec![0.0f32; points];
        for l in &self.links {
            let (x, y) = (l.source as usize, l.receiver as usize);
            second[x] += l.factor * a[y] * onward[y];
        }
        // A crease point is never composed: only its echo counts.
        (0..points).map(|x| (x < first_crease) as u8 as f32 + a[x] * (spread[x] + second[x])).collect()
    }

    /// The index of the first crease point among `points` near points ([`Echo::creases`]).
    pub fn first_crease(&self, points: usize) -> usize {
        points.saturating_sub(self.creases.len())
    }

    /// The near point whose echo point `x` passes on: its texel's for a crease point, else
    /// itself (`points` near points).
    pub fn echo_of(&self, x: usize, points: usize) -> usize {
        let first = self.first_crease(points);
        match x.checked_sub(first).and_then(|k| self.creases.get(k)) {
            Some(&parent) => parent as usize,
            None => x,
        }
    }
}

/// Per entry, the energy (luminance summed over texels, a pane's unit) its near links deliver
/// with their echo per W/m² of its deviation: `sum over its links of luminance(albedo) x
/// factor x` the link's texel's [`Echo::gain`]. The runtime's cluster balance counts it with
/// [`Far::energy`].
pub fn link_energy(entries: &[Entry], near: &[NearLink], echo: &Echo, points: usize) -> Vec<f32> {
    let mut energy = vec![0.0f32; entries.len()];
    for (links, g) in near.chunk_by(|a, b| a.texel == b.texel).zip(echo.gain(points)) {
        for l in links {
            let j = l.entry as usize;
            energy[j] += luminance(entries[j].albedo) * l.factor * g;
        }
    }
    energy
}

impl Far {
    /// Entries per block of the visibility (the bits of one u32).
    pub const BLOCK: usize = 32;

    /// Blocks of `n` entries.
    pub fn blocks(n: usize) -> usize {
        n.div_ceil(Far::BLOCK)
    }

    /// The pair of blocks (a, b): its index in `pair_block` (its bits start at `BLOCK` times
    /// it), if the far field keeps it.
    pub fn pair(&self, a: usize, b: usize) -> Option<usize> {
        let (start, end) = (*self.block_first.get(a)? as usize, *self.block_first.get(a + 1)? as usize);
        let run = self.pair_block.get(start..end)?;
        run.binary_search(&(b as u32)).ok().map(|k| start + k)
    }

    /// Whether entries i and j see each other within the radius (an entry sees itself).
    pub fn sees(&self, i: usize, j: usize) -> bool {
        if i == j {
            return true;
        }
        let bs = Far::BLOCK;
        self.pair(i / bs, j / bs)
            .and_then(|p| self.visible.get(p * bs + i % bs))
            .is_some_and(|w| w >> (j % bs) & 1 == 1)
    }
}

/// The far field's share of a cell's light at distance `d` from its centroid: 0 up to
/// `reach`, 1 from `reach + size` (size: the cell's square root of area), smooth between; the
/// near links keep `1 - far_share`.
#[inline]
pub fn far_share(d: f32, reach: f32, size: f32) -> f32 {
    let t = ((d - reach) / size.max(1e-6)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A far texel's visibility of a far-field source: the vote of its four neighbour entries
/// (`weights`), each for the source where its pair bit is set (`sees(k)`), counted over the
/// neighbours that face the source (`faces(k)`); with none facing it, all of them vote. The
/// runtime's far field and the precompute's first bounce (`prm_precompute::far::FirstBounce`)
/// both take it from here.
#[inline]
pub fn far_vote(weights: &[f32; 4], sees: impl Fn(usize) -> bool, faces: impl Fn(usize) -> bool) -> f32 {
    let (mut seen, mut total, mut every) = (0.0f32, 0.0f32, 0.0f32);
    for (k, &w) in weights.iter().enumerate() {
        let s = if sees(k) { w } else { 0.0 };
        every += s;
        if faces(k) {
            seen += s;
            total += w;
        }
    }
    if total > 0.0 {
        seen / total
    } else {
        every
    }
}

/// [`far_share`] in WGSL, for the runtime's shader prelude: the same operations in the same
/// order; a GPU test holds the two together.
pub const FAR_SHARE_WGSL: &str = "fn far_share(d: f32, reach: f32, size: f32) -> f32 {
    let t = clamp((d - reach) / max(size, 1e-6), 0.0, 1.0);
    return t * t * (3.0 - 2.0 * t);
}
";

/// A cluster of entry points sharing one pane and one runtime weight.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    /// Member entries (indices into [`Prm::entries`]).
    pub members: Vec<u32>,
    /// Mean position of the members.
    pub centroid: Vec3,
    /// Sum of the pane's luminance over all texels (texel count weighted, per unit weight):
    /// the runtime ranks clusters by weight x energy.
    pub energy: f32,
    /// Range of this cluster's tiles in [`Prm::tiles`].
    pub first_tile: u32,
    pub tile_count: u32,
}

/// A group of clusters whose summed pane stands in for those of its clusters a frame leaves out.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    /// Energy of the group's pane (the sum of its clusters' energies, less dropped tiles).
    pub energy: f32,
    /// Range of this group's tiles in [`Prm::tiles`] (their `cluster` is C + group index).
    pub first_tile: u32,
    pub tile_count: u32,
}

/// One stored tile of a pane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tile {
    /// The pane: cluster c < C, or group C + g.
    pub cluster: u32,
    /// Tile index in the atlas tile grid, row-major.
    pub index: u32,
    /// RGB multiplier of the stored half-float intensities.
    pub scale: Vec3,
}

/// Header facts, stored as JSON.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Hex FNV-1a 64 of the scene (see [`crate::fingerprint::scene_fingerprint`]).
    pub fingerprint: String,
    pub atlas_width: u32,
    pub atlas_height: u32,
    pub tile_size: u32,
    pub entries: u32,
    pub clusters: u32,
    pub tiles: u32,
    /// Tiles left out because their energy was negligible.
    pub tiles_dropped: u32,
    /// Fraction of the panes' total energy in the dropped tiles.
    pub dropped_energy: f64,
    /// The relative threshold tiles were dropped by.
    pub drop_threshold: f64,
    /// Free-form provenance: the parameters and statistics of the precompute.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// Groups (coarse panes) after the clusters; 0 = none.
    #[serde(default)]
    pub groups: u32,
    /// Lightmap pages (v9): 1, or the pages of generated UVs stacked down the atlas, which is
    /// then `pages` pages of `atlas_width`^2 (see [`crate::density::Atlas`]).
    pub pages: u32,
    /// With generated UVs packed in pages (always with several), the texel size in metres they
    /// were packed at (how the level is loaded again to match the map); else 0.
    #[serde(default)]
    pub page_texel_size: f32,
}

impl Header {
    /// The atlas the map was baked for.
    pub fn atlas(&self) -> crate::density::Atlas {
        crate::density::Atlas { side: self.atlas_width, pages: self.pages.max(1) }
    }
}

/// The pieces of a radiance map, unchecked: what a bake assembles and [`Prm::new`] validates.
/// Writing parts as bytes does not check them (tests write broken files with it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PrmParts {
    pub header: Header,
    pub entries: Vec<Entry>,
    /// Per entry, the share of its cell's reflected light that lands on the level, in [0, 1]
    /// (module doc); empty: every share 1 (a v10 or v11 file).
    pub stays: Vec<f32>,
    /// Per entry, its bounce gain, finite and non-negative (module doc, *Bounce gains*);
    /// empty: each gain its stay share (a file before v14).
    pub gains: Vec<Vec3>,
    /// The surface each entry stands for.
    pub cells: Cells,
    /// Near-field links, sorted by texel then entry (may be empty).
    pub near: Vec<NearLink>,
    /// The sample point of each texel with links, in texel order (one per run of `near`).
    pub near_points: Vec<NearPoint>,
    /// The near field's echo between those points (may be empty).
    pub echo: Echo,
    pub clusters: Vec<Cluster>,
    /// Coarse panes over the clusters (may be empty).
    pub groups: Vec<Group>,
    /// The group of each cluster (empty when there are no groups).
    pub group_of: Vec<u32>,
    pub tiles: Vec<Tile>,
    /// Stored-texel mask of the atlas, one bit per texel, row-major (covered or dilated).
    pub mask: Vec<u8>,
    /// Half-float intensities of all tiles' masked texels, in tile order.
    pub data: Vec<u8>,
    /// The far field of the deviations (may be empty).
    pub far: Far,
}

/// A radiance map that holds every invariant of the format (see [`Prm::new`]).
#[derive(Clone, Debug)]
pub struct Prm {
    parts: PrmParts,
    /// Its file's checksum once known: read with the file, or made by [`Prm::checksum`] or
    /// [`Prm::write`] (an update compares the old map's with its cache's, and its new cache
    /// holds the new map's: each was a pass over the whole file, 382 MB on the 16 chambers).
    /// Not part of the map's value.
    checksum: std::sync::OnceLock<u64>,
    /// The format version of the file it was read from ([`VERSION`] for a map made here). Not
    /// part of the map's value.
    read_version: u32,
}

impl PartialEq for Prm {
    fn eq(&self, other: &Prm) -> bool {
        self.parts == other.parts
    }
}

/// Where each stored tile's texels are: per atlas tile index, the row-major atlas texels stored
/// there (in storage order), and per stored tile, the start of its data.
#[derive(Clone, Debug)]
pub struct TileLayout {
    pub texels: Vec<Vec<u32>>,
    pub offsets: Vec<usize>,
    /// Total stored texels over all tiles.
    pub len: usize,
}

/// One stored tile of a pane with its texels: irradiance per unit weight at `texels[i]` is
/// `tile.scale x intensity(data[i])`.
pub struct PaneTile<'a> {
    pub tile: &'a Tile,
    /// Row-major atlas texel indices.
    pub texels: &'a [u32],
    /// Intensity codes ([`intensity`]).
    pub data: &'a [u8],
}

/// The smallest intensity a code holds (code 1), relative to its tile's peak (code 255).
pub const INTENSITY_FLOOR: f32 = 1e-4;

/// The intensity in [0, 1] a stored code stands for: 0 for code 0, else logarithmic from
/// [`INTENSITY_FLOOR`] (code 1) to 1 (code 255), a step of 3.7 % (the GPU's `intensity` in
/// the compose shader is the same formula).
#[inline]
pub fn intensity(code: u8) -> f32 {
    if code == 0 {
        0.0
    } else {
        (INTENSITY_FLOOR.log2() * (255 - code) as f32 / 254.0).exp2()
    }
}

/// The code of intensity `v` (relative to its tile's peak, in [0, 1]): the nearest in log
/// space; below half the floor, 0.
pub fn intensity_code(v: f32) -> u8 {
    if !(v >= 0.5 * INTENSITY_FLOOR) {
        return 0;
    }
    let steps = 254.0 * v.clamp(INTENSITY_FLOOR, 1.0).log2() / INTENSITY_FLOOR.log2();
    (255.0 - steps).round().clamp(1.0, 255.0) as u8
}

/// Pack a per-texel boolean mask into bits.
pub fn pack_mask(mask: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; mask.len().div_ceil(8)];
    for (k, &m) in mask.iter().enumerate() {
        if m {
            out[k / 8] |= 1 << (k % 8);
        }
    }
    out
}

/// What can be wrong with a `.prm` file.
#[derive(Debug, thiserror::Error)]
pub enum PrmError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a .prm file (bad magic)")]
    Magic { path: PathBuf },
    #[error(
        "{path}: .prm version {found}, this build reads versions {OLDEST_READ} to {VERSION} (version 9 keeps the far \
         field's visibility for every pair of entries, 8 lacks lightmap pages, 7 the far field's energy, \
         6 and older the far field); run prm precompute again"
    )]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: truncated ({size} bytes; {what})")]
    Truncated { path: PathBuf, size: u64, what: String },
    #[error("{path}: {what}; run prm precompute again")]
    Retired { path: PathBuf, what: String },
    #[error("{path}: checksum mismatch: the file is corrupt")]
    Checksum { path: PathBuf },
    #[error("{path}: corrupt: {what}")]
    Corrupt { path: PathBuf, what: String },
    #[error(
        "{path}: baked for another scene or atlas (file fingerprint {file}, scene {scene}, atlas {file_atlas} vs \
         {scene_atlas}); run prm precompute again"
    )]
    WrongScene { path: PathBuf, file: String, scene: String, file_atlas: String, scene_atlas: String },
}

/// Parts that break an invariant of the format (see [`Prm::new`]).
#[derive(Debug, thiserror::Error)]
#[error("invalid radiance map: {0}")]
pub struct InvalidPrm(pub String);

/// The stored-texel layout of `tiles` over an atlas with this header and mask (the mask must
/// have the atlas's size).
fn tile_layout(header: &Header, mask: &[u8], tiles: &[Tile]) -> TileLayout {
    let ts = header.tile_size as usize;
    let (w, h) = (header.atlas_width as usize, header.atlas_height as usize);
    let (tx, ty) = (w.div_ceil(ts), h.div_ceil(ts));
    let stored = |k: usize| mask[k / 8] & (1 << (k % 8)) != 0;
    let texels: Vec<Vec<u32>> = (0..tx * ty)
        .map(|index| {
            let (ti, tj) = (index % tx, index / tx);
            let mut out = Vec::new();
            for j in tj * ts..((tj + 1) * ts).min(h) {
                for i in ti * ts..((ti + 1) * ts).min(w) {
                    if stored(j * w + i) {
                        out.push((j * w + i) as u32);
                    }
                }
            }
            out
        })
        .collect();
    let mut offsets = Vec::with_capacity(tiles.len());
    let mut len = 0;
    for t in tiles {
        offsets.push(len);
        len += texels.get(t.index as usize).map_or(0, Vec::len);
    }
    TileLayout { texels, offsets, len }
}

impl PrmParts {
    /// The file bytes (magic, version, JSON header, sections, checksum), checked or not.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        // Writing to a Vec cannot fail.
        let _ = self.write_to(&mut out);
        out
    }

    /// Write the file's bytes to `out` as [`PrmParts::to_bytes`] gives them, a section at a
    /// time (no copy of the whole file is made); returns the count written.
    pub fn write_to(&self, out: &mut dyn std::io::Write) -> std::io::Result<u64> {
        let mut w = Writer::new(out);
        w.put(&MAGIC);
        w.put(&VERSION.to_le_bytes());
        let header = serde_json::to_vec(&self.header).unwrap_or_default();
        w.put(&(header.len() as u32).to_le_bytes());
        w.put(&header);
        w.entries(&self.entries, &self.stays);
        w.gains(&self.gains);
        w.cells(&self.cells);
        w.near(&self.near, &self.near_points);
        w.seen(&self.near);
        w.echo(&self.echo);
        w.creases(&self.echo.creases);
        w.clusters(&self.clusters);
        w.groups(&self.groups, &self.group_of);
        w.mask(&self.mask);
        w.tiles(&self.tiles);
        w.data(&self.data);
        w.far(&self.far);
        w.texel_areas(&self.far.areas);
        let sum = w.sum;
        w.put(&sum.to_le_bytes());
        match w.error {
            Some(e) => Err(e),
            None => Ok(w.len),
        }
    }
}

impl Prm {
    /// A map from its parts, if they hold every invariant of the format: the header's counts
    /// are the parts' lengths; a plausible atlas and tile size; finite entries with a
    /// non-negative area; members that are entries; tiles naming an existing pane and an atlas
    /// tile inside the grid, with a finite non-negative scale; each pane's tile range holding
    /// only its tiles, the ranges covering every tile, no atlas tile twice in a pane; groups of
    /// clusters that exist; a mask of the atlas's size; exactly the stored texels' data, finite
    /// and non-negative; finite non-negative energies.
    pub fn new(parts: PrmParts) -> Result<Prm, InvalidPrm> {
        check::invariants(&parts).map_err(InvalidPrm)?;
        Ok(Prm { parts, checksum: std::sync::OnceLock::new(), read_version: VERSION })
    }

    /// The parts back, to change and validate again.
    pub fn into_parts(self) -> PrmParts {
        self.parts
    }

    pub fn header(&self) -> &Header {
        &self.parts.header
    }

    pub fn entries(&self) -> &[Entry] {
        &self.parts.entries
    }

    /// Entry `j`'s stay share: the share of its cell's reflected light that lands on the
    /// level (1 in a file without them).
    pub fn stay(&self, j: usize) -> f32 {
        self.parts.stays.get(j).copied().unwrap_or(1.0)
    }

    /// Entry `j`'s bounce gain: the light that lands on the level over every bounce per unit
    /// its cell reflects (module doc, *Bounce gains*; its stay share in a file without them).
    pub fn gain(&self, j: usize) -> Vec3 {
        self.parts.gains.get(j).copied().unwrap_or_else(|| Vec3::splat(self.stay(j)))
    }

    /// The surface each entry stands for.
    pub fn cells(&self) -> &Cells {
        &self.parts.cells
    }

    /// Near-field links, sorted by texel then entry.
    pub fn near(&self) -> &[NearLink] {
        &self.parts.near
    }

    /// The sample point of each texel with links, in the order of their runs in [`Prm::near`].
    pub fn near_points(&self) -> &[NearPoint] {
        &self.parts.near_points
    }

    /// The near field's echo between the near points.
    pub fn echo(&self) -> &Echo {
        &self.parts.echo
    }

    /// Per entry, the energy its near links deliver per W/m² of deviation ([`link_energy`]).
    pub fn link_energy(&self) -> Vec<f32> {
        let p = &self.parts;
        link_energy(&p.entries, &p.near, &p.echo, p.near_points.len())
    }

    /// The far field of the deviations (empty when the map has none).
    pub fn far(&self) -> &Far {
        &self.parts.far
    }

    pub fn clusters(&self) -> &[Cluster] {
        &self.parts.clusters
    }

    /// Coarse panes over the clusters (may be empty).
    pub fn groups(&self) -> &[Group] {
        &self.parts.groups
    }

    /// The group of each cluster (empty when there are no groups).
    pub fn group_of(&self) -> &[u32] {
        &self.parts.group_of
    }

    pub fn tiles(&self) -> &[Tile] {
        &self.parts.tiles
    }

    /// Stored-texel mask of the atlas, one bit per texel, row-major (see [`Prm::stored`]).
    pub fn mask(&self) -> &[u8] {
        &self.parts.mask
    }

    /// Half-float intensities of all tiles' masked texels, in tile order.
    pub fn data(&self) -> &[u8] {
        &self.parts.data
    }

    /// Atlas width and height in texels.
    pub fn atlas(&self) -> (u32, u32) {
        (self.parts.header.atlas_width, self.parts.header.atlas_height)
    }

    /// Atlas texels (width x height).
    pub fn texel_count(&self) -> usize {
        self.parts.header.atlas_width as usize * self.parts.header.atlas_height as usize
    }

    /// Panes: clusters, then groups.
    pub fn pane_count(&self) -> usize {
        self.parts.clusters.len() + self.parts.groups.len()
    }

    /// True when atlas texel `k` (row-major) is stored.
    #[inline]
    pub fn stored(&self, k: usize) -> bool {
        self.parts.mask[k / 8] & (1 << (k % 8)) != 0
    }

    /// Tiles across the atlas.
    pub fn tiles_x(&self) -> u32 {
        self.parts.header.atlas_width.div_ceil(self.parts.header.tile_size)
    }

    /// Tiles down the atlas.
    pub fn tiles_y(&self) -> u32 {
        self.parts.header.atlas_height.div_ceil(self.parts.header.tile_size)
    }

    /// The atlas tile (row-major over the tile grid) that holds atlas texel `texel`
    /// (row-major).
    pub fn atlas_tile_of(&self, texel: u32) -> usize {
        let (w, ts) = (self.parts.header.atlas_width, self.parts.header.tile_size);
        ((texel / w) / ts) as usize * self.tiles_x() as usize + ((texel % w) / ts) as usize
    }

    /// Where every stored tile's texels live: build it once per map, then read panes with it.
    pub fn layout(&self) -> TileLayout {
        tile_layout(&self.parts.header, &self.parts.mask, &self.parts.tiles)
    }

    /// The range of pane `pane`'s tiles in [`Prm::tiles`] (cluster c < C, group C + g).
    pub fn tile_range(&self, pane: usize) -> Range<usize> {
        let c = self.parts.clusters.len();
        let (first, count) = match self.parts.clusters.get(pane) {
            Some(cl) => (cl.first_tile, cl.tile_count),
            None => {
                let g = &self.parts.groups[pane - c];
                (g.first_tile, g.tile_count)
            }
        };
        first as usize..(first + count) as usize
    }

    /// The stored tiles of pane `pane` (cluster c < C, group C + g) with their texels.
    pub fn pane_tiles<'a>(
        &'a self,
        pane: usize,
        layout: &'a TileLayout,
    ) -> impl Iterator<Item = PaneTile<'a>> + 'a {
        self.tile_range(pane).map(move |k| {
            let tile = &self.parts.tiles[k];
            let texels = &layout.texels[tile.index as usize];
            let start = layout.offsets[k];
            PaneTile { tile, texels, data: &self.parts.data[start..start + texels.len()] }
        })
    }

    /// Error unless this map was baked for `scene` at its atlas size.
    pub fn check_scene(&self, path: &Path, scene: &Scene) -> Result<(), PrmError> {
        let h = &self.parts.header;
        let fp = fingerprint_hex(scene, h.atlas_width, h.atlas_height);
        if fp != h.fingerprint {
            let atlas = format!("{}x{}", h.atlas_width, h.atlas_height);
            return Err(PrmError::WrongScene {
                path: path.into(),
                file: h.fingerprint.clone(),
                scene: fp,
                file_atlas: atlas.clone(),
                scene_atlas: atlas,
            });
        }
        Ok(())
    }

    /// The format version of the file the map was read from: [`VERSION`] for one made by this
    /// build, older for a file an older build wrote (read in this version's form: its checksum
    /// is not the file's).
    pub fn read_version(&self) -> u32 {
        self.read_version
    }

    /// The file bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.parts.to_bytes()
    }

    /// The file's checksum, its last 8 bytes, made as [`Prm::write`] makes it but holding no
    /// copy of the file (an update's old map and new cache each asked for one: twice the
    /// file in memory on the 16 chambers, 382 MB each).
    pub fn checksum(&self) -> u64 {
        *self.checksum.get_or_init(|| self.make_checksum())
    }

    /// [`Prm::checksum`], made.
    fn make_checksum(&self) -> u64 {
        /// Keeps the last 8 bytes written.
        struct Tail([u8; 8]);
        impl std::io::Write for Tail {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                let n = b.len().min(8);
                self.0.rotate_left(n);
                self.0[8 - n..].copy_from_slice(&b[b.len() - n..]);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let mut tail = Tail([0; 8]);
        // Writing to it cannot fail.
        let _ = self.parts.write_to(&mut tail);
        u64::from_le_bytes(tail.0)
    }

    /// Write atomically, a section at a time; returns the file's size.
    pub fn write(&self, path: &Path) -> Result<u64, PrmError> {
        let mut len = 0;
        crate::fsutil::write_atomic(path, |w| {
            len = self.parts.write_to(w)?;
            Ok::<(), std::io::Error>(())
        })
        .map_err(|source| PrmError::Io { path: path.into(), source })?;
        Ok(len)
    }

    /// Read and validate a file; with `scene`, also check it was baked for that scene.
    pub fn read(path: &Path, scene: Option<&Scene>) -> Result<Prm, PrmError> {
        let bytes = std::fs::read(path).map_err(|source| PrmError::Io { path: path.into(), source })?;
        let prm = Self::from_bytes(path, &bytes)?;
        if let Some(s) = scene {
            prm.check_scene(path, s)?;
        }
        Ok(prm)
    }

    /// Parse and validate file bytes (`path` is only for messages).
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Prm, PrmError> {
        let size = bytes.len() as u64;
        let truncated = |what: &str| PrmError::Truncated { path: path.into(), size, what: what.into() };
        let corrupt = |what: String| PrmError::Corrupt { path: path.into(), what };
        let (header, body, at) = Self::frame(path, bytes)?;
        // `frame` has checked the version and that the file holds it.
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
        let mut r = Reader::new(body, at);
        let parts = (|| -> Result<PrmParts, SectionError> {
            let (entries, stays) = r.entries(&header, version)?;
            let gains = if version >= 14 { r.gains(entries.len())? } else { Vec::new() };
            let cells = r.cells(entries.len())?;
            let (mut near, near_points) = r.near()?;
            if version >= 15 {
                r.seen(&mut near)?;
            }
            let mut echo = r.echo(near_points.len())?;
            if version >= 16 {
                echo.creases = r.creases()?;
            }
            let clusters = r.clusters(&header, entries.len())?;
            let (groups, group_of) = r.groups(&header)?;
            let mask = r.mask()?;
            let tiles = r.tiles(&header)?;
            let data = r.data()?;
            if version < 13 {
                r.retired_dipoles()?;
            }
            let mut far = r.far()?;
            if version >= 17 {
                far.areas = r.texel_areas(far.texels.len())?;
            }
            r.finish()?;
            Ok(PrmParts {
                header,
                entries,
                stays,
                gains,
                cells,
                near,
                near_points,
                echo,
                clusters,
                groups,
                group_of,
                tiles,
                mask,
                data,
                far,
            })
        })()
        .map_err(|e| match e {
            SectionError::Truncated(what) => truncated(&what),
            SectionError::Corrupt(what) => corrupt(what),
            SectionError::Retired(what) => PrmError::Retired { path: path.into(), what },
        })?;
        let mut prm = Prm::new(parts).map_err(|InvalidPrm(what)| corrupt(what))?;
        prm.read_version = version;
        // A file of this version is what writing the map gives (an older one is written anew
        // in this version, with another checksum): its checksum, checked above, is the map's.
        if bytes[8..12] == VERSION.to_le_bytes() {
            let tail = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().unwrap_or_default());
            let _ = prm.checksum.set(tail);
        }
        Ok(prm)
    }

    /// Magic, version, checksum and JSON header: the header, the body (the bytes the checksum
    /// covers) and where its sections start.
    fn frame<'a>(path: &Path, bytes: &'a [u8]) -> Result<(Header, &'a [u8], usize), PrmError> {
        let size = bytes.len() as u64;
        let truncated = |what: &str| PrmError::Truncated { path: path.into(), size, what: what.into() };
        let u32_at = |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
        if bytes.len() < 8 || bytes[..8] != MAGIC {
            if bytes.len() < 8 && MAGIC.starts_with(bytes) && !bytes.is_empty() {
                return Err(truncated("shorter than the magic"));
            }
            return Err(PrmError::Magic { path: path.into() });
        }
        if bytes.len() < 16 {
            return Err(truncated("no header"));
        }
        let version = u32_at(8);
        if !(OLDEST_READ..=VERSION).contains(&version) {
            return Err(PrmError::Version { path: path.into(), found: version });
        }
        if bytes.len() < 24 {
            return Err(truncated("no checksum"));
        }
        let body = &bytes[..bytes.len() - 8];
        let stored = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().unwrap_or_default());
        let header_len = u32_at(12) as usize;
        if 16 + header_len > body.len() {
            return Err(truncated("header runs past the end"));
        }
        if fnv1a(FNV_START, body) != stored {
            return Err(PrmError::Checksum { path: path.into() });
        }
        let corrupt = |what: String| PrmError::Corrupt { path: path.into(), what };
        let header: Header = serde_json::from_slice(&body[16..16 + header_len])
            .map_err(|e| corrupt(format!("header: {e}")))?;
        check::atlas(&header).map_err(corrupt)?;
        Ok((header, body, 16 + header_len))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 x 4 atlas in one 4 x 4 tile, two entries in one cluster, one stored tile.
    fn parts() -> PrmParts {
        let entry = |x: f32| Entry {
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Y,
            albedo: Vec3::splat(0.5),
            area: 0.25,
            triangle: 0,
        };
        PrmParts {
            header: Header {
                atlas_width: 4,
                atlas_height: 4,
                pages: 1,
                tile_size: 4,
                entries: 2,
                clusters: 1,
                tiles: 1,
                ..Default::default()
            },
            entries: vec![entry(0.0), entry(1.0)],
            stays: vec![1.0, 0.5],
            gains: vec![Vec3::new(2.5, 2.4, 2.3), Vec3::new(0.5, 0.6, 0.7)],
            cells: Cells::from_lists(vec![
                vec![[Vec3::ZERO, Vec3::Z, Vec3::X]],
                vec![[Vec3::X, Vec3::Z, Vec3::X + Vec3::Z], [Vec3::X, Vec3::X + Vec3::Z, Vec3::X * 2.0]],
            ]),
            near: vec![
                NearLink { texel: 3, entry: 0, factor: 0.5, hidden: 0 },
                NearLink { texel: 3, entry: 1, factor: 0.25, hidden: 0b10 },
                NearLink { texel: 5, entry: 1, factor: 0.125, hidden: 0 },
            ],
            // The box's corners and axis normals: what the file stores exactly.
            near_points: vec![
                NearPoint { texel: 3, position: Vec3::ZERO, normal: Vec3::Y },
                NearPoint { texel: 5, position: Vec3::new(1.0, 2.0, 3.0), normal: Vec3::NEG_Z },
            ],
            // Albedos in 1/255 steps and half-float factors: stored exactly.
            echo: Echo {
                albedo: vec![Vec3::new(0.2, 0.4, 1.0), Vec3::ZERO],
                links: vec![
                    EchoLink { receiver: 0, source: 1, factor: 0.25 },
                    EchoLink { receiver: 1, source: 0, factor: 0.5 },
                ],
                creases: Vec::new(),
            },
            clusters: vec![Cluster {
                members: vec![0, 1],
                centroid: Vec3::new(0.5, 0.0, 0.0),
                energy: 1.0,
                first_tile: 0,
                tile_count: 1,
            }],
            tiles: vec![Tile { cluster: 0, index: 0, scale: Vec3::ONE }],
            mask: pack_mask(&[true; 16]),
            data: (0..16).map(|k| k * 16).collect(),
            far: Far {
                reach: 0.5,
                radius: 10.0,
                block_first: vec![0, 1],
                pair_block: vec![0],
                visible: [vec![2, 1], vec![0; Far::BLOCK - 2]].concat(),
                texels: vec![
                    FarTexel {
                        texel: 2,
                        position: Vec3::new(0.5, 1.0, 0.0),
                        normal: Vec3::NEG_Y,
                        entries: [0, 1, 0, 0],
                        weights: [0.75, 0.25, 0.0, 0.0],
                    },
                    FarTexel {
                        texel: 9,
                        normal: Vec3::X,
                        entries: [1, 0, 0, 0],
                        weights: [1.0, 0.0, 0.0, 0.0],
                        ..Default::default()
                    },
                ],
                energy: vec![0.5, 2.0],
                areas: Vec::new(),
            },
            ..Default::default()
        }
    }

    /// A pair of blocks is found in its first block's run; a bit answers for one pair of
    /// entries; an entry sees itself; a pair of blocks not kept sees nothing.
    /// `split_long` keeps each cell's area, centroid and winding, cuts every triangle to the
    /// edge asked for, leaves short ones as they were, and cuts nothing for a bad length.
    #[test]
    fn long_cell_triangles_are_cut_without_moving_the_cell() {
        // A jamb-like sliver (0.25 x 1.4) as two triangles, and a small triangle.
        let (a, b, c, d) =
            (Vec3::ZERO, Vec3::new(0.0, 0.0, 0.25), Vec3::new(0.0, 1.4, 0.25), Vec3::new(0.0, 1.4, 0.0));
        let small = [Vec3::X, Vec3::X + Vec3::Z * 0.1, Vec3::X + Vec3::Y * 0.1];
        let cells = Cells::from_lists(vec![vec![[a, b, c], [a, c, d]], vec![small]]);
        let split = cells.split_long(0.3);
        assert_eq!(split.of(1), cells.of(1), "a short triangle is kept as it is");
        assert!(split.of(0).len() >= 8, "{} pieces", split.of(0).len());
        let normal = |t: &[Vec3; 3]| (t[1] - t[0]).cross(t[2] - t[0]);
        for t in split.of(0) {
            for k in 0..3 {
                assert!(t[k].distance(t[(k + 1) % 3]) <= 0.3 + 1e-6, "{t:?}");
            }
            assert!(normal(t).normalize().dot(normal(&cells.of(0)[0]).normalize()) > 0.999, "winding kept");
        }
        for j in 0..2 {
            assert!((split.area(j) - cells.area(j)).abs() <= 1e-5 * cells.area(j), "area of cell {j}");
            let (p, q) = (split.centroid(j).unwrap(), cells.centroid(j).unwrap());
            assert!(p.distance(q) <= 1e-5, "centroid of cell {j}: {p} against {q}");
        }
        // Each piece names the triangle it was cut from: the pieces of one cover its area.
        let (again, from) = cells.split_long_from(0.3);
        assert_eq!((&again, from.len()), (&split, split.triangles.len()));
        assert!(from.windows(2).all(|w| w[0] <= w[1]), "pieces follow their triangles' order");
        let area = |t: &[Vec3; 3]| 0.5 * normal(t).length();
        for (k, whole) in cells.triangles.iter().enumerate() {
            let pieces: f32 = split
                .triangles
                .iter()
                .zip(&from)
                .filter(|(_, &f)| f as usize == k)
                .map(|(t, _)| area(t))
                .sum();
            assert!(
                (pieces - area(whole)).abs() <= 1e-5,
                "triangle {k}: pieces {pieces}, whole {}",
                area(whole)
            );
        }
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(cells.split_long_from(bad).1, vec![0, 1, 2], "max edge {bad}");
            assert_eq!(cells.split_long(bad), cells, "max edge {bad}");
        }
        // The depth bound: a triangle 1 m long cut to 1e-9 m stops at 2^SPLIT_DEPTH pieces.
        let one = Cells::from_lists(vec![vec![[a, Vec3::X, Vec3::Y]]]);
        assert_eq!(one.split_long(1e-9).of(0).len(), 1 << SPLIT_DEPTH);
    }

    #[test]
    fn far_visibility_is_looked_up_by_blocks() {
        // 70 entries: blocks 0, 1, 2. Kept pairs: (0, 0), (0, 2), (2, 0), (1, 1).
        let mut visible = vec![0u32; 4 * Far::BLOCK];
        visible[Far::BLOCK + 3] = 1 << 5; // entry 3 sees entry 64 + 5
        visible[3 * Far::BLOCK + 5] = 1 << 3; // and back (pair 3 is (2, 0))
        visible[7] = 1 << 9; // entry 7 sees entry 9
        let far = Far {
            radius: 1.0,
            block_first: vec![0, 2, 3, 4],
            pair_block: vec![0, 2, 1, 0],
            visible,
            ..Far::default()
        };
        assert_eq!(
            (far.pair(0, 2), far.pair(2, 0), far.pair(0, 1), far.pair(5, 0)),
            (Some(1), Some(3), None, None)
        );
        assert!(far.sees(3, 69) && far.sees(69, 3) && !far.sees(3, 68) && !far.sees(4, 69));
        assert!(far.sees(7, 9) && !far.sees(9, 7), "the bits are as stored");
        assert!(far.sees(40, 40) && !far.sees(40, 41) && !far.sees(1, 33));
        assert_eq!((Far::blocks(64), Far::blocks(65)), (2, 3));
        assert_eq!((far_share(0.4, 0.5, 0.2), far_share(0.7, 0.5, 0.2)), (0.0, 1.0));
        assert!((far_share(0.6, 0.5, 0.2) - 0.5).abs() < 1e-5);
    }

    #[test]
    fn valid_parts_make_a_map_that_round_trips() {
        let prm = Prm::new(parts()).unwrap();
        let bytes = prm.to_bytes();
        let back = Prm::from_bytes(Path::new("t.prm"), &bytes).unwrap();
        assert_eq!(back, prm);
        assert_eq!(prm.pane_tiles(0, &prm.layout()).map(|t| t.texels.len()).sum::<usize>(), 16);
        // The checksum made without the bytes is the file's last 8; the one a map read keeps
        // from its file is the one made from it; neither is part of the map's value.
        assert_eq!(prm.checksum().to_le_bytes(), bytes[bytes.len() - 8..]);
        assert_eq!((back.checksum(), back.make_checksum()), (prm.checksum(), prm.checksum()));
        assert_eq!(prm, Prm::new(parts()).unwrap());
    }

    /// Stay shares round-trip, and a share outside [0, 1] or a count other than the entries'
    /// is refused, naming it.
    #[test]
    fn stay_shares_round_trip_and_bad_ones_are_refused() {
        let prm = Prm::new(parts()).unwrap();
        let back = Prm::from_bytes(Path::new("t.prm"), &prm.to_bytes()).unwrap();
        assert_eq!((back.stay(0), back.stay(1)), (1.0, 0.5));
        for bad in [vec![1.0, 1.5], vec![-0.1, 1.0], vec![f32::NAN, 1.0], vec![1.0]] {
            let err = Prm::new(PrmParts { stays: bad.clone(), ..parts() }).unwrap_err().0;
            assert!(err.contains("stay share"), "{bad:?}: {err}");
        }
    }

    /// A v3 file (no texel points for the near field) is refused, saying what to do.
    #[test]
    fn an_older_version_is_refused_with_a_rebake_message() {
        let mut bytes = Prm::new(parts()).unwrap().to_bytes();
        bytes[8..12].copy_from_slice(&3u32.to_le_bytes());
        let err = Prm::from_bytes(Path::new("old.prm"), &bytes).unwrap_err().to_string();
        assert!(err.contains("version 3") && err.contains("run prm precompute again"), "{err}");
        // A v8 file has no pages: it is refused as old, not read as one page.
        bytes[8..12].copy_from_slice(&8u32.to_le_bytes());
        let err = Prm::from_bytes(Path::new("old.prm"), &bytes).unwrap_err().to_string();
        assert!(err.contains("8 lacks lightmap pages"), "{err}");
        // A v9 file's far field has a bit for every pair of entries: refused, not misread.
        bytes[8..12].copy_from_slice(&9u32.to_le_bytes());
        let err = Prm::from_bytes(Path::new("old.prm"), &bytes).unwrap_err().to_string();
        assert!(err.contains("version 9 keeps the far field's visibility for every pair"), "{err}");
        // A v10 or v11 file is read: it differs only in what v11 added (the near links' run
        // bases), v12 (the stay shares, whose slot was padding: every share is then 1), v13
        // (no `DIPO` section; an empty one before `FARF` here) and v14 (no `GAIN` section).
        let no_stays =
            Prm::new(PrmParts { stays: Vec::new(), gains: Vec::new(), ..seeing_all(parts()) }).unwrap();
        for old in [10u32, 11] {
            let new = without_seen(&without_gains(&without_creases(&before_areas(&no_stays.to_bytes()))));
            let Some(far) = (16..new.len()).find(|&k| &new[k..k + 4] == b"FARF") else {
                panic!("no FARF section");
            };
            let mut bytes = new[..far].to_vec();
            bytes[8..12].copy_from_slice(&old.to_le_bytes());
            bytes.extend_from_slice(b"DIPO");
            bytes.extend_from_slice(&12u64.to_le_bytes());
            bytes.extend_from_slice(&[0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]);
            bytes.extend_from_slice(&new[far..new.len() - 8]);
            let sum = crate::fingerprint::fnv1a(crate::fingerprint::FNV_START, &bytes);
            bytes.extend_from_slice(&sum.to_le_bytes());
            let read = Prm::from_bytes(Path::new("v11.prm"), &bytes).unwrap();
            assert_eq!(read, no_stays, "v{old}");
            assert_eq!((read.stay(0), read.stay(1)), (1.0, 1.0));
        }
        // A version from a later build is refused, not misread.
        bytes[8..12].copy_from_slice(&18u32.to_le_bytes());
        let err = Prm::from_bytes(Path::new("new.prm"), &bytes).unwrap_err().to_string();
        assert!(err.contains("version 18") && err.contains("versions 10 to 17"), "{err}");
    }

    /// `parts` with every near link seeing its whole cell: what a file before v15 reads as.
    fn seeing_all(mut parts: PrmParts) -> PrmParts {
        for l in &mut parts.near {
            l.hidden = 0;
        }
        parts
    }

    /// `bytes` (a file of this version, without crease points) without its `CRSE` section, its
    /// checksum made again: a v15 file of the same map but for the version.
    fn without_creases(bytes: &[u8]) -> Vec<u8> {
        let out = without_section(bytes, b"CRSE");
        assert_eq!(out.len() + 16, bytes.len(), "the CRSE section lists crease points");
        out
    }

    /// `parts()` with a crease point on texel 5's square (near point 1), linked to entry 0,
    /// which receiver 0's echo reads in place of texel 5.
    fn with_crease(mut p: PrmParts) -> PrmParts {
        p.near.push(NearLink { texel: 16, entry: 0, factor: 0.375, hidden: 0 });
        p.near_points.push(NearPoint { texel: 16, ..p.near_points[1] });
        p.echo.albedo.push(p.echo.albedo[1]);
        p.echo.links[0].source = 2;
        p.echo.creases = vec![1];
        p
    }

    /// Crease points round-trip; a map without them, stamped v15 without its `CRSE` section,
    /// reads as it was; each one counts its echo but is never composed (`Echo::gain`), its
    /// texel's onward echo counts what it passes on; and it goes where its texel goes when
    /// atlas tiles are left out.
    #[test]
    fn crease_points_round_trip_count_their_echo_and_follow_their_texel() {
        let (Ok(prm), Ok(plain)) = (Prm::new(with_crease(parts())), Prm::new(parts())) else {
            panic!("valid parts refused");
        };
        let Ok(back) = Prm::from_bytes(Path::new("t.prm"), &prm.to_bytes()) else {
            panic!("a map's bytes refused")
        };
        assert_eq!(back, prm);
        assert_eq!(back.echo().creases, vec![1]);
        let v15 = as_version(&without_creases(&before_areas(&plain.to_bytes())), 15);
        match Prm::from_bytes(Path::new("v15.prm"), &v15) {
            Ok(read) => assert_eq!((read.read_version(), read.echo()), (15, plain.echo())),
            Err(e) => panic!("a v15 file refused: {e}"),
        }
        // Echo factors 0.25 (0 <- crease) and 0.5 (1 <- 0); albedo luminances.
        let echo = prm.echo();
        let a: Vec<f32> = echo.albedo.iter().map(|&v| luminance(v)).collect();
        let g = echo.gain(3);
        let close = |x: f32, y: f32| (x - y).abs() < 1e-6;
        // The crease point: its own spread 0.25, its receiver 0 passing on 0.5 x a_1 from there.
        assert!(close(g[2], a[2] * (0.25 + 0.25 * a[0] * 0.0)), "{g:?}");
        // Point 0 sends 0.5 to point 1, whose onward spread is its own (none) and its crease's.
        assert!(close(g[0], 1.0 + a[0] * (0.5 + 0.5 * a[1] * 0.25)), "{g:?}");
        assert!(close(g[1], 1.0), "{g:?}");
        assert_eq!((echo.first_crease(3), echo.echo_of(2, 3), echo.echo_of(1, 3)), (2, 1, 1));
        // Texel 5 lies in the atlas's one tile: leaving it out leaves out the crease point too.
        let Ok(cut) = prm.without_atlas_tiles(&[true]) else { panic!("the cut map is refused") };
        assert!(cut.prm.near_points().is_empty() && cut.prm.echo().creases.is_empty());
    }

    /// `bytes` (a file of this version) without its `TXAR` section (a map without the far
    /// texels' areas), its checksum made again: what the file was before v17.
    fn before_areas(bytes: &[u8]) -> Vec<u8> {
        without_empty_section(bytes, b"TXAR")
    }

    /// `bytes` without its section `tag`, which must be empty, its checksum made again.
    fn without_empty_section(bytes: &[u8], tag: &[u8; 4]) -> Vec<u8> {
        let out = without_section(bytes, tag);
        assert_eq!(out.len() + 12, bytes.len(), "the {} section is not empty", String::from_utf8_lossy(tag));
        out
    }

    /// The far texels' areas round-trip; a map without them, stamped v16 without its `TXAR`
    /// section, reads as it was (no areas: the runtime's lift keeps the energy); a section for
    /// another count of texels is refused; leaving out every texel leaves out every area (one
    /// texel at a time: `reduce`'s test).
    #[test]
    fn far_texel_areas_round_trip_and_a_v16_file_has_none() {
        let mut p = parts();
        p.far.areas = vec![0.04, 0.01];
        let (Ok(prm), Ok(plain)) = (Prm::new(p), Prm::new(parts())) else { panic!("valid parts refused") };
        let Ok(back) = Prm::from_bytes(Path::new("t.prm"), &prm.to_bytes()) else {
            panic!("a map's bytes refused")
        };
        assert_eq!(back.far().areas, vec![0.04, 0.01]);
        assert_eq!(back, prm);
        let v16 = as_version(&before_areas(&plain.to_bytes()), 16);
        match Prm::from_bytes(Path::new("v16.prm"), &v16) {
            Ok(read) => {
                assert_eq!((read.read_version(), read.far().areas.is_empty(), &read), (16, true, &plain))
            }
            Err(e) => panic!("a v16 file refused: {e}"),
        }
        // Bytes of areas for another count of texels are refused.
        let mut bad = prm.to_bytes();
        let Some(at) = (16..bad.len()).find(|&k| &bad[k..k + 4] == b"TXAR") else {
            panic!("no TXAR section")
        };
        bad[at + 4..at + 12].copy_from_slice(&4u64.to_le_bytes());
        bad.drain(at + 16..at + 20);
        let len = bad.len();
        let sum = crate::fingerprint::fnv1a(crate::fingerprint::FNV_START, &bad[..len - 8]);
        bad[len - 8..].copy_from_slice(&sum.to_le_bytes());
        let err = Prm::from_bytes(Path::new("bad.prm"), &bad).unwrap_err().to_string();
        assert!(err.contains("2 far-field texels, 4 bytes of their areas"), "{err}");
        // Leaving out the atlas's one tile leaves out every far texel, and their areas with them.
        let Ok(cut) = prm.without_atlas_tiles(&[true]) else { panic!("the cut map is refused") };
        assert!(cut.prm.far().texels.is_empty() && cut.prm.far().areas.is_empty());
    }

    /// `bytes` (a file of this version) without its `SEEN` section, its checksum made again.
    fn without_seen(bytes: &[u8]) -> Vec<u8> {
        without_section(bytes, b"SEEN")
    }

    /// `bytes` without its section `tag` (which it must have), its checksum made again.
    fn without_section(bytes: &[u8], tag: &[u8; 4]) -> Vec<u8> {
        let Some(at) = (16..bytes.len()).find(|&k| &bytes[k..k + 4] == tag) else {
            panic!("no {} section", String::from_utf8_lossy(tag));
        };
        let len = u64::from_le_bytes(bytes[at + 4..at + 12].try_into().unwrap_or_default()) as usize;
        let mut out = [&bytes[..at], &bytes[at + 12 + len..bytes.len() - 8]].concat();
        let sum = crate::fingerprint::fnv1a(crate::fingerprint::FNV_START, &out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// `bytes` stamped as format `version`, its checksum made again.
    fn as_version(bytes: &[u8], version: u32) -> Vec<u8> {
        let mut out = bytes[..bytes.len() - 8].to_vec();
        out[8..12].copy_from_slice(&version.to_le_bytes());
        let sum = crate::fingerprint::fnv1a(crate::fingerprint::FNV_START, &out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// The links' hidden triangles round-trip; a v14 file (no `SEEN` section) reads with every
    /// texel seeing the whole of each linked cell.
    #[test]
    fn hidden_triangles_round_trip_and_a_v14_file_sees_every_triangle() {
        let (Ok(prm), Ok(blind)) = (Prm::new(parts()), Prm::new(seeing_all(parts()))) else {
            panic!("valid parts refused");
        };
        assert!(prm.near().iter().any(|l| l.hidden != 0));
        let Ok(back) = Prm::from_bytes(Path::new("t.prm"), &prm.to_bytes()) else {
            panic!("a map's bytes refused")
        };
        assert_eq!(back.near(), prm.near());
        let v14 = as_version(&without_seen(&without_creases(&before_areas(&prm.to_bytes()))), 14);
        let read = match Prm::from_bytes(Path::new("v14.prm"), &v14) {
            Ok(read) => read,
            Err(e) => panic!("a v14 file refused: {e}"),
        };
        assert_eq!(read, blind);
        assert_eq!(read.read_version(), 14);
    }

    /// `bytes` (a file of this version, its `GAIN` section empty) without that section, its
    /// checksum made again: the bytes a v13 file of the same map has but for the version.
    fn without_gains(bytes: &[u8]) -> Vec<u8> {
        without_empty_section(bytes, b"GAIN")
    }

    /// Bounce gains round-trip; a map without them (a v13 file, read) gives each entry its
    /// stay share as its gain; a gain not finite or negative, or a count other than the
    /// entries', is refused, naming it.
    #[test]
    fn bounce_gains_round_trip_a_v13_file_reads_its_stay_shares_and_bad_ones_are_refused() {
        let (Ok(prm), Ok(v14)) =
            (Prm::new(parts()), Prm::new(PrmParts { gains: Vec::new(), ..seeing_all(parts()) }))
        else {
            panic!("valid parts refused");
        };
        let Ok(back) = Prm::from_bytes(Path::new("t.prm"), &prm.to_bytes()) else {
            panic!("a map's bytes refused")
        };
        assert_eq!((back.gain(0), back.gain(1)), (Vec3::new(2.5, 2.4, 2.3), Vec3::new(0.5, 0.6, 0.7)));
        let v13 =
            as_version(&without_seen(&without_gains(&without_creases(&before_areas(&v14.to_bytes())))), 13);
        let read = match Prm::from_bytes(Path::new("v13.prm"), &v13) {
            Ok(read) => read,
            Err(e) => panic!("a v13 file refused: {e}"),
        };
        assert_eq!(read, v14);
        assert_eq!((read.gain(0), read.gain(1)), (Vec3::ONE, Vec3::splat(0.5)));
        assert_eq!((read.read_version(), back.read_version(), prm.read_version()), (13, VERSION, VERSION));

        let g = Vec3::ONE;
        for bad in [
            vec![g, Vec3::new(1.0, -0.1, 1.0)],
            vec![g, Vec3::new(f32::NAN, 1.0, 1.0)],
            vec![g, Vec3::INFINITY],
            vec![g],
        ] {
            let err = Prm::new(PrmParts { gains: bad.clone(), ..parts() }).unwrap_err().0;
            assert!(err.contains("bounce gain"), "{bad:?}: {err}");
        }
        // A GAIN section of the wrong length is corrupt.
        let mut bytes = prm.to_bytes();
        let Some(at) = (16..bytes.len()).find(|&k| &bytes[k..k + 4] == b"GAIN") else {
            panic!("no GAIN section");
        };
        bytes[at + 4..at + 12].copy_from_slice(&12u64.to_le_bytes());
        let n = bytes.len();
        let sum = crate::fingerprint::fnv1a(crate::fingerprint::FNV_START, &bytes[..n - 8]);
        bytes[n - 8..].copy_from_slice(&sum.to_le_bytes());
        let err = Prm::from_bytes(Path::new("g.prm"), &bytes).unwrap_err().to_string();
        assert!(err.contains("2 entries, 12 bytes of bounce gains"), "{err}");
    }

    /// Every code decodes to what it encodes; any intensity from the floor to 1 comes back
    /// within half a logarithmic step (1.9 %); below half the floor, 0.
    #[test]
    fn intensity_codes_round_trip_within_half_a_step() {
        for c in 0..=255u8 {
            assert_eq!(intensity_code(intensity(c)), c, "code {c}");
        }
        assert_eq!((intensity(255), intensity(0)), (1.0, 0.0));
        assert!((intensity(1) / INTENSITY_FLOOR - 1.0).abs() < 1e-5);
        let half_step = INTENSITY_FLOOR.powf(-1.0 / 254.0).sqrt() - 1.0;
        for k in 0..10_000 {
            let v = INTENSITY_FLOOR.powf(k as f32 / 9999.0);
            let back = intensity(intensity_code(v));
            assert!((back / v - 1.0).abs() <= half_step + 1e-5, "{v} -> {back}");
        }
        assert_eq!(intensity_code(0.49 * INTENSITY_FLOOR), 0);
        assert_eq!(intensity_code(f32::NAN), 0);
        assert_eq!(intensity_code(2.0), 255);
    }

    /// Points anywhere in the box come back within half a 16-bit step, normals within 1e-4,
    /// and rounding twice changes nothing.
    #[test]
    fn near_points_round_as_stored() {
        let mut pts: Vec<NearPoint> = (0..50)
            .map(|k| {
                let t = k as f32 * 0.37;
                NearPoint {
                    texel: k,
                    position: Vec3::new(t.sin() * 9.0, t.cos() * 3.0 - 10.0, t * 0.1),
                    normal: Vec3::new(t.cos(), (2.0 * t).sin(), (3.0 * t).cos() - 0.5).normalize(),
                }
            })
            .collect();
        let exact = pts.clone();
        round_near_points(&mut pts);
        let (lo, hi) = near_point_box(&exact);
        for (a, b) in pts.iter().zip(&exact) {
            assert!(
                ((a.position - b.position).abs() - (hi - lo) / 65535.0 * 0.5).max_element() <= 1e-5,
                "{a:?} {b:?}"
            );
            assert!(
                a.normal.distance(b.normal) < 1e-4 && (a.normal.length() - 1.0).abs() < 1e-6,
                "{a:?} {b:?}"
            );
        }
        let once = pts.clone();
        round_near_points(&mut pts);
        assert_eq!(pts, once);
    }

    #[test]
    fn every_broken_invariant_is_refused_with_its_reason() {
        type Break = fn(&mut PrmParts);
        let cases: Vec<(&str, Break)> = vec![
            ("entries declared", |p| p.header.entries = 3),
            ("groups declared", |p| p.header.groups = 1),
            ("cluster groups declared", |p| p.group_of = vec![0]),
            ("implausible atlas", |p| p.header.tile_size = 0),
            ("implausible atlas", |p| p.header.pages = 0),
            // Two pages must stack two squares of the width, and say their texel size.
            ("implausible atlas", |p| {
                p.header.pages = 2;
                p.header.page_texel_size = 0.1;
            }),
            ("implausible atlas", |p| p.header.page_texel_size = -0.1),
            ("implausible atlas", |p| {
                p.header.pages = 2;
                p.header.atlas_width = 2;
                p.header.atlas_height = 4;
                p.header.page_texel_size = f32::NAN;
            }),
            ("non-finite", |p| p.entries[1].area = f32::NAN),
            ("not an entry", |p| p.clusters[0].members[1] = 2),
            ("cell offsets", |p| p.cells.first = vec![0, 1]),
            ("cell offsets", |p| p.cells.first[1] = 4),
            ("non-finite corners", |p| p.cells.triangles[2][1].y = f32::NAN),
            ("near-field link 1 is out of range", |p| p.near[1].entry = 2),
            ("near-field link 0 is out of range", |p| p.near[0].texel = 16),
            ("near-field link 1 is out of range", |p| p.near[1].factor = f32::NAN),
            ("near-field link 1 is out of order", |p| p.near.swap(0, 1)),
            // Entry 0's cell has one triangle, entry 1's two.
            ("near-field link 0 hides triangles past its cell's 1", |p| p.near[0].hidden = 0b10),
            ("near-field link 1 hides triangles past its cell's 2", |p| p.near[1].hidden = 0b101),
            ("2 texels have near-field links but 1 points", |p| {
                p.near_points.pop();
            }),
            ("near-field point 0 is for texel 4", |p| p.near_points[0].texel = 4),
            ("near-field point 1 is not a point with a unit normal", |p| {
                p.near_points[1].normal = Vec3::ZERO
            }),
            ("near-field point 0 is not a point", |p| p.near_points[0].position.x = f32::NAN),
            ("the echo has 1 albedos for 2", |p| {
                p.echo.albedo.pop();
            }),
            ("echo albedo 0 is not in [0, 1]", |p| p.echo.albedo[0].x = 1.5),
            ("echo link 1 is out of range", |p| p.echo.links[1].source = 2),
            ("echo link 0 is out of range", |p| p.echo.links[0].source = 0),
            ("echo link 1 is out of range", |p| p.echo.links[1].factor = f32::NAN),
            ("echo link 1 is out of order", |p| p.echo.links.swap(0, 1)),
            ("crease point 0 lies on near-field point 2", |p| {
                *p = with_crease(std::mem::take(p));
                p.echo.creases[0] = 2;
            }),
            ("echo link 1 lights crease point 2", |p| {
                *p = with_crease(std::mem::take(p));
                p.echo.links[1] = EchoLink { receiver: 2, source: 0, factor: 0.5 };
            }),
            ("near-field point 1 has texel 5 where 1 texels' points and 2 crease points", |p| {
                *p = with_crease(std::mem::take(p));
                p.echo.creases.push(1);
            }),
            ("33 far-field visibility words for 1 pairs of blocks", |p| p.far.visible.push(0)),
            ("a far field without texels", |p| p.far.texels.clear()),
            ("far-field block offsets", |p| p.far.block_first.push(1)),
            ("far-field block offsets", |p| p.far.block_first[1] = 2),
            ("far-field block offsets", |p| p.far.block_first = vec![1, 1]),
            ("far-field pair 1 names block 0", |p| {
                p.far.block_first = vec![0, 2];
                p.far.pair_block = vec![0, 0];
                p.far.visible.extend([0; Far::BLOCK]);
            }),
            ("far-field pair 0 names block 1", |p| p.far.pair_block[0] = 1),
            ("far-field radius", |p| p.far.radius = -1.0),
            ("far-field texel 0 is out of range", |p| p.far.texels[0].weights[0] = 0.5),
            ("far-field reach", |p| p.far.reach = f32::NAN),
            ("1 far-field energies and 0 texel areas without a far field", |p| {
                p.far = Far { energy: vec![1.0], ..Far::default() }
            }),
            ("1 far-field energies for 2 entries", |p| {
                p.far.energy.pop();
            }),
            ("far-field energy of entry 1", |p| p.far.energy[1] = f32::INFINITY),
            ("far-field energy of entry 0", |p| p.far.energy[0] = -1.0),
            ("far-field texel 1 is out of range", |p| p.far.texels[1].entries[2] = 2),
            ("far-field texel 1 is out of range", |p| p.far.texels.swap(0, 1)),
            ("far-field texel 0 is out of range", |p| p.far.texels[0].weights[3] = -1.0),
            ("far-field texel 1 is out of range", |p| p.far.texels[1].texel = 16),
            ("1 far-field texel areas for 2 texels", |p| p.far.areas = vec![0.04]),
            ("far-field texel 1's area is NaN", |p| p.far.areas = vec![0.04, f32::NAN]),
            ("far-field texel 0's area is -1", |p| p.far.areas = vec![-1.0, 0.01]),
            ("0 far-field energies and 2 texel areas without a far field", |p| {
                p.far = Far { areas: vec![1.0, 1.0], ..Far::default() }
            }),
            ("out of range", |p| p.tiles[0].index = 1),
            ("out of range", |p| p.tiles[0].scale.x = -1.0),
            ("tile range is wrong", |p| p.clusters[0].tile_count = 2),
            ("mask is", |p| p.mask.push(0)),
            ("masked texels need", |p| {
                p.data.pop();
            }),
            ("non-finite energy", |p| p.clusters[0].energy = f32::INFINITY),
            ("entry 1 is a member of cluster 0 and of cluster 0", |p| p.clusters[0].members = vec![0, 1, 1]),
        ];
        for (reason, break_it) in cases {
            let mut p = parts();
            break_it(&mut p);
            let err = Prm::new(p).expect_err(reason);
            assert!(err.0.contains(reason), "expected '{reason}', got '{}'", err.0);
        }
    }
}
