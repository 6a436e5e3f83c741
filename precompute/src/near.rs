//! Near-field links (DESIGN.md §4, `prm::prm_file::NearLink`): the first bounce from the entry
//! cells close to each texel, for the part of it a cluster's pane cannot say.
//!
//! A pane answers unit irradiance spread over its whole cluster. A light close to a surface
//! puts its power into one or two cells, and texels a few cm from them (the other walls of a
//! corner) see that hot spot from close by: the cluster mean spreads it over metres. The
//! runtime adds, per texel x, `sum_j albedo_j (E_j - w_c(j) t_j) factor_xj` over the entries j
//! linked to x: the deviation of each entry's weight from what even light over its cluster
//! would give it (`t_j`: its cell's area over A/N; `prm_runtime::cpu::NearTables`), times the first bounce its cell sends to x per unit weight. Deviations sum to
//! about zero over a cluster, so their far field is small and links are kept only within a few
//! entry spacings (`PrecomputeParams::near_radius`); the runtime lowers each cluster's weight
//! by the energy its links deliver, so what the truncation leaves unbalanced is not gained or
//! lost (`prm_runtime::cpu::cluster_weights`).
//!
//! `factor_xj = (A / N) / A_cell F(x -> cell) V`: entry j's weight E carries `E A/N` W, which
//! leaves its cell (area A_cell) as uniform exitance `albedo E (A/N) / A_cell`; a Lambertian
//! polygon of exitance M gives irradiance `M F` at x, with F the point-to-polygon form factor
//! (Lambert's contour integral, the cell clipped to x's hemisphere), each cell triangle's
//! share times the part of it x sees (shadow rays to a few points of it, [`seen_form_factor`]).
//! Coplanar cells have F = 0 and get no link: flat interiors of walls have none.
//!
//! Each link also says which of the map's cell triangles (the cells as cut for the runtime,
//! [`Cells::split_long`]) its texel does not see (`NearLink::hidden`): a triangle seen in part
//! is looked at piece by piece, and the factor counts the pieces seen (`seen_cell`). The
//! runtime weighs a hot cell's uneven light as the texel sees it over those alone.

use std::collections::HashMap;

use glam::{IVec3, Vec3};
use prm::form_factor::closest_point;
use prm::prm_file::{
    far_share, near_point_box, round_albedo, round_near_points, round_near_points_within, Cells, Echo,
    EchoLink, Entry, Far, NearLink, NearPoint, HIDDEN_TRIANGLES,
};
use prm::{Bvh, TexelSet};
use rayon::prelude::*;

use crate::reference::form_factor::{clip_above_plane, point_to_polygon};

/// Links below this factor are dropped (a deviation of 1 W/m² then adds under 1e-4 W/m²).
pub const MIN_FACTOR: f32 = 1e-4;

/// The links of every covered texel of `set` to the entries whose cell centroid lies within
/// `radius` entry spacings (sqrt(A / N)) plus the cell's own size, sorted by texel (atlas
/// row-major index) then entry; and the sample point of each texel with links, rounded as the
/// file stores it. Where the far field (`crate::far`) lights the texel, each link keeps `1 -
/// far_share` of its factor (`prm::prm_file::far_share`, from the far field's reach to that
/// plus the cell's size) and the far field has the rest; elsewhere (no far field, or a texel it
/// leaves out) the link keeps it all. With `reuse` (an update: the old bake's links, and per
/// covered texel whether it is settled, `crate::update::Untouched::texel`) a settled texel
/// takes its links from the old bake: its texel, the entries it reaches and the rays between
/// them lie in rooms the edit did not touch.
pub fn near_links(
    bvh: &Bvh,
    set: &TexelSet,
    entries: &[Entry],
    cells: (&Cells, &Cells, &[u32]),
    radius: f32,
    far: &Far,
    reuse: Option<&NearReuse>,
) -> (Vec<NearLink>, Vec<NearPoint>) {
    let Some(search) = LinkSearch::new(bvh, entries, cells, radius, far) else {
        return (Vec::new(), Vec::new());
    };
    let width = set.width as usize;
    let per_texel: Vec<Vec<NearLink>> = set
        .texels
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            let texel = (t.j as usize * width + t.i as usize) as u32;
            let fades = far.texels.binary_search_by_key(&texel, |f| f.texel).is_ok();
            if let Some(r) = reuse.filter(|r| {
                r.settled.get(k) == Some(&true)
                    || (r.same_texel.get(k) == Some(&true)
                        && r.kept_by_geometry(
                            bvh,
                            t,
                            texel,
                            fades,
                            cells.0,
                            &search.cell,
                            search.reach,
                            &search.reaches,
                        ))
            }) {
                let from = r.old.partition_point(|l| l.texel < texel);
                let to = from + r.old[from..].partition_point(|l| l.texel == texel);
                return r.old[from..to].to_vec();
            }
            search.links((t.position, t.normal), texel, fades)
        })
        .collect();
    let mut links: Vec<NearLink> = per_texel.into_iter().flatten().collect();
    links.sort_by_key(|l| (l.texel, l.entry));
    let width = set.width;
    let mut points: Vec<NearPoint> = links
        .chunk_by(|a, b| a.texel == b.texel)
        .map(|r| {
            let t = &set.texels[set.index[r[0].texel as usize] as usize];
            debug_assert_eq!(t.j * width + t.i, r[0].texel);
            NearPoint { texel: r[0].texel, position: t.position, normal: t.normal }
        })
        .collect();
    round_near_points(&mut points);
    (links, points)
}

/// What the links of one point are found with ([`near_links`], [`crease_points`]): the cells'
/// centroids and areas, and a grid of the cells that reach each place.
struct LinkSearch<'a> {
    bvh: &'a Bvh,
    entries: &'a [Entry],
    cells: (&'a Cells, &'a Cells, &'a [u32]),
    far: &'a Far,
    cell: Vec<(Vec3, f32)>,
    reach: f32,
    reaches: ReachGrid,
}

impl<'a> LinkSearch<'a> {
    /// None without entries.
    fn new(
        bvh: &'a Bvh,
        entries: &'a [Entry],
        cells: (&'a Cells, &'a Cells, &'a [u32]),
        radius: f32,
        far: &'a Far,
    ) -> Option<LinkSearch<'a>> {
        let reach = radius * entries.first()?.area.sqrt();
        let cell: Vec<(Vec3, f32)> = (0..entries.len())
            .map(|j| (cells.0.centroid(j).unwrap_or(entries[j].position), cells.0.area(j)))
            .collect();
        let reaches = ReachGrid::new(&cell, reach);
        Some(LinkSearch { bvh, entries, cells, far, cell, reach, reaches })
    }

    /// The links of the point `x` (unit normal `n`), numbered `texel`, in entry order; `fades`:
    /// the far field lights it (each link keeps `1 - far_share` of its factor).
    fn links(&self, (x, n): (Vec3, Vec3), texel: u32, fades: bool) -> Vec<NearLink> {
        let mut out = Vec::new();
        for j in self.reaches.around(x) {
            let (e, (centroid, area)) = (&self.entries[j], self.cell[j]);
            if !(area > 0.0) || centroid.distance(x) > self.reach + area.sqrt() {
                continue;
            }
            let (mut f, hidden) = seen_cell(self.bvh, (x, n), e, area, self.cells, j);
            if fades {
                f *= 1.0 - far_share(centroid.distance(x), self.far.reach, area.sqrt());
            }
            // Rounded as the file stores it (a half float), so a bake and its file agree.
            let factor = half::f16::from_f32(e.area / area * f).to_f32();
            if !(factor >= MIN_FACTOR) {
                continue;
            }
            out.push(NearLink { texel, entry: j as u32, factor, hidden });
        }
        out
    }
}

/// The form factor from the texel at `x` (unit normal `n`) to the part of entry `j`'s cell it sees ([`seen_part`] over
/// the triangles of `cells`), and the [`NearLink::hidden`] bits of the map's pieces of them
/// (`pieces`, each cut from triangle `from[k]` of `cells`, [`Cells::split_long_from`]). A triangle the texel sees whole, or not
/// at all, gives its pieces its bit; one it sees in part is looked at piece by piece
/// ([`seen_part`] again), each seen or not by most of its points, and the factor counts the
/// pieces seen, so that the factor and the bits agree. (A piece past the bits' 64 counts at
/// the share of it seen.)
fn seen_cell(
    bvh: &Bvh,
    (x, n): (Vec3, Vec3),
    e: &Entry,
    area: f32,
    (cells, pieces, from): (&Cells, &Cells, &[u32]),
    j: usize,
) -> (f32, u64) {
    let scale = e.area / area;
    let parts: Vec<(f32, f32)> =
        cells.of(j).iter().map(|tri| seen_part(bvh, x, n, tri, e.normal, scale)).collect();
    let in_part = |(part, seen): (f32, f32)| part > 0.0 && seen > 0.0 && seen < 1.0;
    let mut f: f32 = parts.iter().filter(|&&p| !in_part(p)).map(|(part, seen)| part * seen).sum();
    let mut hidden = 0u64;
    let range = pieces.first[j] as usize..pieces.first[j + 1] as usize;
    for (k, (piece, &whole)) in pieces.triangles[range.clone()].iter().zip(&from[range]).enumerate() {
        let (part, seen) = parts[(whole - cells.first[j]) as usize];
        let sees = if in_part((part, seen)) {
            let (part, seen) = seen_part(bvh, x, n, piece, e.normal, scale);
            if k >= HIDDEN_TRIANGLES {
                f += part * seen;
                continue;
            }
            if seen >= 0.5 {
                f += part;
            }
            seen >= 0.5 || !(part > 0.0)
        } else {
            seen >= 0.5 || !(part > 0.0)
        };
        if !sees && k < HIDDEN_TRIANGLES {
            hidden |= 1 << k;
        }
    }
    (f, hidden)
}

/// What an update takes from the old bake's near links (`crate::update::Untouched`): the
/// links of every `settled` texel (its triangle as it was, in a room the edit did not touch),
/// and of a texel the edit cannot have reached by geometry. That is a texel whose triangle is
/// as it was (`triangle`), which the far field lights now as it did then (`old_far`), none of
/// whose candidate cells changed (no changed entry's cell, old or new, reaches it: `changed`,
/// its centroid and the square root of its area), and whose rays to its cells stay clear of
/// the edit (the box of the texel and those cells' triangles misses every box of `boxes`).
/// On a level whose rooms are joined by doors an edit touches the one room, and without the
/// geometry every texel's links were made again.
pub struct NearReuse<'a> {
    pub old: &'a [NearLink],
    pub settled: &'a [bool],
    /// Per covered texel (set order), whether the old bake had the same texel at its atlas
    /// index (`crate::update::same_texels`); only such a texel is kept by geometry.
    pub same_texel: &'a [bool],
    pub triangle: &'a [bool],
    pub old_far: &'a Far,
    pub changed: &'a crate::update::ChangedCells,
    pub boxes: &'a crate::update::EditBoxes,
    /// How many texels not settled were taken by geometry (counted as it goes).
    pub by_geometry: std::sync::atomic::AtomicUsize,
}

impl NearReuse<'_> {
    /// Whether texel `t` (atlas index `texel`) has the old bake's links by geometry (`fades`:
    /// the far field lights it now; `cell`, `reach` and `reaches` as [`near_links`] finds its
    /// candidate cells).
    #[allow(clippy::too_many_arguments)]
    fn kept_by_geometry(
        &self,
        bvh: &Bvh,
        t: &prm::Texel,
        texel: u32,
        fades: bool,
        cells: &Cells,
        cell: &[(Vec3, f32)],
        reach: f32,
        reaches: &ReachGrid,
    ) -> bool {
        if self.triangle.get(t.triangle as usize) != Some(&true)
            || self.old_far.texels.binary_search_by_key(&texel, |f| f.texel).is_ok() != fades
        {
            return false;
        }
        let x = t.position;
        if self.changed.near(x, reach + 2.0 * bvh.eps_at(x)) {
            return false;
        }
        let (mut lo, mut hi) = (x, x);
        for j in reaches.around(x) {
            let (centroid, area) = cell[j];
            if !(area > 0.0) || centroid.distance(x) > reach + area.sqrt() {
                continue;
            }
            for p in cells.of(j).iter().flatten() {
                (lo, hi) = (lo.min(*p), hi.max(*p));
            }
        }
        if !self.boxes.clear(bvh, lo, hi) {
            return false;
        }
        self.by_geometry.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        true
    }
}

/// The form factor from the texel `(x, n)` to the part of cell triangle `tri` it sees (`front`:
/// its entry's normal, `scale`: the link factor per unit form factor): the triangle clipped to
/// the texel's hemisphere, times the share of points spread over that part that `x` sees (its
/// vertex mean, and where the triangle's share of the link factor is [`SPLIT_FACTOR`] or more,
/// one point halfway to each corner: for a clipped part of three corners these are the
/// centroids of its four equal sub-triangles). A triangle whose front faces away from `x`
/// sends it nothing.
///
/// One ray to the entry point decided a whole cell before: a plinth top cut by its pillar has
/// its entry behind the pillar, so the texels at the pillar's foot lost the link to the lit
/// strip in front of it (the chamber's torch by a pillar: 0.0-0.8 W/m² there against the
/// ground truth's 2.5-3.1), and a cell half hidden was counted whole.
pub fn seen_form_factor(bvh: &Bvh, x: Vec3, n: Vec3, tri: &[Vec3; 3], front: Vec3, scale: f32) -> f32 {
    let (f, seen) = seen_part(bvh, x, n, tri, front, scale);
    f * seen
}

/// [`seen_form_factor`] in its two parts: the form factor of the part of `tri` in the texel's
/// hemisphere, and the share of its points the texel sees (1 where the form factor is 0).
pub fn seen_part(bvh: &Bvh, x: Vec3, n: Vec3, tri: &[Vec3; 3], front: Vec3, scale: f32) -> (f32, f32) {
    let Some(normal) = (tri[1] - tri[0]).cross(tri[2] - tri[0]).try_normalize() else { return (0.0, 1.0) };
    let normal = if normal.dot(front) < 0.0 { -normal } else { normal };
    if normal.dot(x - tri[0]) <= 0.0 {
        return (0.0, 1.0);
    }
    let part = clip_above_plane(tri, x, n);
    if part.len() < 3 {
        return (0.0, 1.0);
    }
    let f = point_to_polygon(x, n, &part);
    if !(f > 0.0) {
        return (0.0, 1.0);
    }
    let centre = part.iter().copied().sum::<Vec3>() / part.len() as f32;
    // The centre, and where the part matters one point halfway to each of its corners (three
    // or four: one plane cuts a triangle).
    let more = if f * scale >= SPLIT_FACTOR { part.len() } else { 0 };
    let seen = std::iter::once(centre)
        .chain(part.iter().take(more).map(|&v| 0.5 * (centre + v)))
        .filter(|&y| bvh.visible(x, n, y, normal))
        .count();
    (f, seen as f32 / (1 + more) as f32)
}

/// A cell triangle whose share of a link factor is this or more gets a shadow ray to each of
/// several points of it in [`seen_form_factor`], one elsewhere: most links are weak, and four
/// rays for every triangle made the near phase 2.8x slower.
pub const SPLIT_FACTOR: f32 = 0.01;

/// The cells that may reach a point: each cell `(centroid, area)` is listed in every grid box
/// its sphere of radius `reach + sqrt(area)` overlaps (a cell too large for that is checked
/// everywhere), so a point looks in its own box only. This keeps the near links linear in the
/// level's size: each texel tests the cells around it, not every cell of the level.
struct ReachGrid {
    side: f32,
    boxes: HashMap<IVec3, Vec<u32>>,
    everywhere: Vec<u32>,
}

impl ReachGrid {
    /// Grid boxes a cell may be listed in before it is checked everywhere instead.
    const MAX_BOXES: i64 = 4096;

    fn new(cell: &[(Vec3, f32)], reach: f32) -> ReachGrid {
        let side = (2.0 * reach).max(1e-6);
        let mut grid = ReachGrid { side, boxes: HashMap::new(), everywhere: Vec::new() };
        for (j, &(centroid, area)) in cell.iter().enumerate() {
            if !(area > 0.0) {
                continue;
            }
            let r = reach + area.sqrt();
            let (lo, hi) = (grid.key(centroid - Vec3::splat(r)), grid.key(centroid + Vec3::splat(r)));
            let span = (hi - lo + IVec3::ONE).as_i64vec3();
            if span.x * span.y * span.z > Self::MAX_BOXES {
                grid.everywhere.push(j as u32);
                continue;
            }
            for z in lo.z..=hi.z {
                for y in lo.y..=hi.y {
                    for x in lo.x..=hi.x {
                        grid.boxes.entry(IVec3::new(x, y, z)).or_default().push(j as u32);
                    }
                }
            }
        }
        grid
    }

    fn key(&self, p: Vec3) -> IVec3 {
        (p / self.side).floor().as_ivec3()
    }

    /// The cells that may reach `p`, in increasing order.
    fn around(&self, p: Vec3) -> Vec<usize> {
        let mut out: Vec<usize> =
            self.boxes.get(&self.key(p)).into_iter().flatten().map(|&j| j as usize).collect();
        out.extend(self.everywhere.iter().map(|&j| j as usize));
        out.sort_unstable();
        out
    }
}

/// The near field's echo (`prm::prm_file::Echo`): between the texels with links, the light the
/// near field puts on one texel bounces to the others close by. A hot spot in a corner lights
/// the walls next to it from a few cm away (the links' first bounce), and those walls light
/// each other and the floor as strongly again; a pane spreads that second bounce over its whole
/// cluster. Each link is the form factor from the receiver's point to the source texel's square
/// (its footprint on the source triangle), for sources within `radius` entry spacings that the
/// receiver sees in front of it and that see it in front of them (coplanar texels have none).
/// The runtime applies it twice (second and third bounce) to the near field's own irradiance.
/// With `reuse` (an update) a settled receiver takes its links from the old bake, as
/// [`near_links`] does.
///
/// Also the links whose receiver sees the source's square unevenly, each with the point of the
/// square where it sees it ([`Crease`]; [`crease_points`] makes them points of their own).
pub fn echo_links(
    scene: &prm::Scene,
    bvh: &Bvh,
    set: &TexelSet,
    entries: &[Entry],
    points: &[NearPoint],
    radius: f32,
    reuse: Option<EchoReuse<'_>>,
) -> (Echo, Vec<Crease>) {
    let Some(first) = entries.first() else { return Default::default() };
    if points.is_empty() || !(radius > 0.0) {
        return Default::default();
    }
    let texels: Vec<&prm::Texel> =
        points.iter().map(|p| &set.texels[set.index[p.texel as usize] as usize]).collect();
    let albedo: Vec<Vec3> =
        texels.iter().map(|t| round_albedo(scene.albedo(t.triangle as usize, t.bary))).collect();
    let squares: Vec<Option<[Vec3; 4]>> = texels.iter().map(|t| texel_square(scene, set, t)).collect();
    let positions: Vec<Vec3> = texels.iter().map(|t| t.position).collect();
    let (reach, grid) = echo_grid(&positions, radius * first.area.sqrt());
    let key = |p: Vec3| (p / reach).floor().as_ivec3();
    // Per receiver, its links, each with where it sees its source when that is a crease.
    type Seen = (EchoLink, Option<(Vec3, f32)>);
    let per_receiver: Vec<Vec<Seen>> = texels
        .par_iter()
        .enumerate()
        .map(|(y, ty)| {
            if let Some(links) = reuse.as_ref().and_then(|r| r.links_of(set, points, y)) {
                return links.into_iter().map(|l| (l, None)).collect();
            }
            let mut out = Vec::new();
            let c = key(ty.position);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let Some(cands) = grid.get(&(c + glam::IVec3::new(dx, dy, dz))) else { continue };
                        for &x in cands {
                            let tx = texels[x as usize];
                            let v = ty.position - tx.position;
                            if x as usize == y || v.length() > reach || !(tx.normal.dot(v) > 0.0) {
                                continue;
                            }
                            let Some(square) = &squares[x as usize] else { continue };
                            let f = half::f16::from_f32(point_to_polygon(ty.position, ty.normal, square))
                                .to_f32();
                            if !(f >= MIN_FACTOR)
                                || !bvh.visible(ty.position, ty.normal, tx.position, tx.normal)
                            {
                                continue;
                            }
                            let crease = seen_centre((ty.position, ty.normal), square, tx.normal)
                                .filter(|&(centre, side)| centre.distance(tx.position) > CREASE_SHIFT * side);
                            out.push((EchoLink { receiver: y as u32, source: x, factor: f }, crease));
                        }
                    }
                }
            }
            out.sort_by_key(|(l, _)| l.source);
            out
        })
        .collect();
    let mut links = Vec::new();
    let mut creases = Vec::new();
    for (l, crease) in per_receiver.into_iter().flatten() {
        if let Some((position, side)) = crease {
            creases.push(Crease { link: links.len(), position, side });
        }
        links.push(l);
    }
    (Echo { albedo, links, creases: Vec::new() }, creases)
}

/// An echo link whose receiver sees the source texel's square unevenly (a floor texel a few mm
/// from a wall sees the wall's lowest cm most): the mean point of the square weighted by how
/// the receiver sees it ([`seen_centre`]), more than [`CREASE_SHIFT`] of the square's side from
/// the source's point.
pub struct Crease {
    /// Index of the link in the echo's links.
    pub link: usize,
    pub position: Vec3,
    /// The side of the source's square (the square root of its area).
    pub side: f32,
}

/// How far (in sides of the source's square) the point a receiver sees a source's square at
/// may lie from the source's point before the echo reads the source there ([`crease_points`]).
pub const CREASE_SHIFT: f32 = 0.2;

/// Crease points of one source within this share of its side of each other are one.
pub const CREASE_MERGE: f32 = 0.25;

/// Quadrature points per side of a square in [`seen_centre`].
const SEEN_CENTRE_SIDE: usize = 16;

/// The mean point of the parallelogram `q` (corners in order; unit normal `nq`) weighted by the
/// form-factor kernel `cos_x cos_y / r²` from the point `x` (unit normal `n`), and the
/// parallelogram's side (the square root of its area); None where `x` sees none of it. Each
/// quadrature point counts as a disk of its area seen from `x`, so that a receiver a few mm
/// from the square weighs its nearest points by what their area can give it.
pub fn seen_centre((x, n): (Vec3, Vec3), q: &[Vec3; 4], nq: Vec3) -> Option<(Vec3, f32)> {
    let (u, v) = (q[1] - q[0], q[3] - q[0]);
    let area = u.cross(v).length();
    let m = SEEN_CENTRE_SIDE;
    let disk = area / (m * m) as f32 / std::f32::consts::PI;
    let (mut weight, mut sum) = (0.0f32, Vec3::ZERO);
    for i in 0..m {
        for j in 0..m {
            let y = q[0] + u * ((i as f32 + 0.5) / m as f32) + v * ((j as f32 + 0.5) / m as f32);
            let d = y - x;
            let r2 = d.length_squared();
            let g = n.dot(d).max(0.0) * (-nq.dot(d)).max(0.0) / (r2 * (r2 + disk)).max(1e-30);
            weight += g;
            sum += y * g;
        }
    }
    (weight > 0.0 && area > 0.0).then(|| (sum / weight, area.sqrt()))
}

/// The crease points of the echo (`prm::prm_file::Echo::creases`): for each [`Crease`], a point
/// on its source's triangle where its receiver sees the source's square (those of one source
/// within [`CREASE_MERGE`] of its side are one, at their mean), with near links of its own
/// (found as [`near_links`] finds a texel's, the far field's share as at its texel), numbered
/// past the atlas's texels. Their echo links read the source there; `echo` gains their albedos
/// and texels' points. A crease point without links is left out (its links read the texel).
/// The points lie within the box of the texels' (`points`), so the file stores them all alike.
#[allow(clippy::too_many_arguments)]
pub fn crease_points(
    scene: &prm::Scene,
    bvh: &Bvh,
    set: &TexelSet,
    entries: &[Entry],
    cells: (&Cells, &Cells, &[u32]),
    radius: f32,
    far: &Far,
    points: &[NearPoint],
    (echo, creases): (&mut Echo, &[Crease]),
) -> (Vec<NearLink>, Vec<NearPoint>) {
    let Some(search) = LinkSearch::new(bvh, entries, cells, radius, far) else { return Default::default() };
    let mut groups: std::collections::BTreeMap<(u32, [i32; 3]), Vec<usize>> = Default::default();
    for (k, c) in creases.iter().enumerate() {
        let Some(l) = echo.links.get(c.link) else { continue };
        let cell = (c.position / (CREASE_MERGE * c.side).max(1e-6)).floor().as_ivec3().to_array();
        groups.entry((l.source, cell)).or_default().push(k);
    }
    let groups: Vec<(u32, Vec<usize>)> = groups.into_iter().map(|((source, _), m)| (source, m)).collect();
    let bounds = near_point_box(points);
    let made: Vec<Option<(Vec3, Vec<NearLink>)>> = groups
        .par_iter()
        .map(|(source, members)| {
            let parent = points.get(*source as usize)?;
            let t = &set.texels[*set.index.get(parent.texel as usize)? as usize];
            let mean = members.iter().map(|&k| creases[k].position).sum::<Vec3>() / members.len() as f32;
            let on = closest_point(&scene.corners(t.triangle as usize), mean).clamp(bounds.0, bounds.1);
            let fades = far.texels.binary_search_by_key(&parent.texel, |f| f.texel).is_ok();
            let links = search.links((on, parent.normal), 0, fades);
            (!links.is_empty()).then_some((on, links))
        })
        .collect();
    let first = points.len() as u32;
    let texels = set.width * set.height;
    let (mut links, mut out) = (Vec::new(), Vec::new());
    let mut source_of: Vec<Option<u32>> = vec![None; echo.links.len()];
    for ((source, members), made) in groups.iter().zip(made) {
        let Some((position, found)) = made else { continue };
        let k = out.len() as u32;
        let texel = texels + k;
        links.extend(found.into_iter().map(|l| NearLink { texel, ..l }));
        out.push(NearPoint { texel, position, normal: points[*source as usize].normal });
        echo.albedo.push(echo.albedo.get(*source as usize).copied().unwrap_or(Vec3::ZERO));
        echo.creases.push(*source);
        for &m in members {
            source_of[creases[m].link] = Some(first + k);
        }
    }
    for (l, s) in echo.links.iter_mut().zip(source_of) {
        if let Some(s) = s {
            l.source = s;
        }
    }
    echo.links.sort_by_key(|l| (l.receiver, l.source));
    round_near_points_within(&mut out, bounds);
    (links, out)
}

/// Most points a receiver of the echo looks at, on average ([`echo_grid`]).
const ECHO_CANDIDATES: usize = 2048;

/// The echo's reach and its grid of `reach`-sized cells over `points` (each receiver looks at
/// its own cell and the 26 around it). The reach is `wanted` (the echo radius in entry
/// spacings) unless a receiver would then look at more than [`ECHO_CANDIDATES`] points on
/// average: a map of very few entries has a spacing as large as the level, and every point
/// would echo every other (the Cornell box with 2 entries: 32 M links, 321 MB and 112 s). Then
/// the reach shrinks by the square root of the excess (the points lie on surfaces) until it
/// holds. The bundled levels and the 16 sunrooms keep the reach they had (the same bytes).
fn echo_grid(points: &[Vec3], wanted: f32) -> (f32, std::collections::HashMap<glam::IVec3, Vec<u32>>) {
    let grid_of = |reach: f32| {
        let mut grid: std::collections::HashMap<glam::IVec3, Vec<u32>> = std::collections::HashMap::new();
        for (k, &p) in points.iter().enumerate() {
            grid.entry((p / reach).floor().as_ivec3()).or_default().push(k as u32);
        }
        grid
    };
    let (mut reach, mut grid) = (wanted, grid_of(wanted));
    // Each pass shrinks the reach by the square root of the excess; points piled on one spot
    // cannot be spread by any reach, and the last pass's grid is kept.
    for _ in 0..ECHO_SHRINKS {
        let looked: usize = grid
            .iter()
            .map(|(c, here)| {
                let around: usize = (-1..=1)
                    .flat_map(|z| {
                        (-1..=1).flat_map(move |y| (-1..=1).map(move |x| glam::IVec3::new(x, y, z)))
                    })
                    .map(|d| grid.get(&(*c + d)).map_or(0, Vec::len))
                    .sum();
                around * here.len()
            })
            .sum();
        let mean = looked as f32 / points.len().max(1) as f32;
        if mean <= ECHO_CANDIDATES as f32 || !(reach > 0.0) {
            break;
        }
        reach *= (ECHO_CANDIDATES as f32 / mean).sqrt();
        grid = grid_of(reach);
    }
    (reach, grid)
}

/// Passes [`echo_grid`] may shrink the reach in.
const ECHO_SHRINKS: usize = 16;

/// What an update's echo takes from the old bake ([`echo_links`]): its echo and near points,
/// and per covered texel (set order) whether it is settled (`crate::update::Untouched::texel`:
/// its triangle as it was, in a room the edit did not touch, so are every source it sees
/// within reach and the rays between them).
pub struct EchoReuse<'a> {
    pub old: &'a Echo,
    pub old_points: &'a [NearPoint],
    pub settled: &'a [bool],
    /// Per covered texel (set order), whether the old bake had the same texel at its atlas
    /// index (`crate::update::same_texels`): a kept link's source must be, too.
    pub same: &'a [bool],
}

impl EchoReuse<'_> {
    /// Receiver `y`'s links (of `points`, this bake's near points) from the old bake, when it
    /// is settled and the old bake had it and every source it linked to as near points, each
    /// source the same texel as then. Both
    /// bakes' points are in texel order, so the sources stay in order.
    fn links_of(&self, set: &TexelSet, points: &[NearPoint], y: usize) -> Option<Vec<EchoLink>> {
        let texel = points.get(y)?.texel;
        let k = *set.index.get(texel as usize)?;
        if !self.settled.get(k as usize).copied().unwrap_or(false) {
            return None;
        }
        let was = self.old_points.binary_search_by_key(&texel, |p| p.texel).ok()? as u32;
        let links = &self.old.links;
        let from = links.partition_point(|l| l.receiver < was);
        let to = from + links[from..].partition_point(|l| l.receiver == was);
        links[from..to]
            .iter()
            .map(|l| {
                let source = self.old_points.get(l.source as usize)?.texel;
                let k = *set.index.get(source as usize)?;
                if !self.same.get(k as usize).copied().unwrap_or(false) {
                    return None;
                }
                let x = points.binary_search_by_key(&source, |p| p.texel).ok()?;
                Some(EchoLink { receiver: y as u32, source: x as u32, factor: l.factor })
            })
            .collect()
    }
}

/// The world-space square of texel `t`: its square in the lightmap mapped through its owning
/// triangle's UV-to-surface map (None for a triangle degenerate in UV).
fn texel_square(scene: &prm::Scene, set: &TexelSet, t: &prm::Texel) -> Option<[Vec3; 4]> {
    let tri = t.triangle as usize;
    let uv = scene.uv1_corners(tri);
    let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = e1.perp_dot(e2);
    if !(det.abs() > 1e-20) {
        return None;
    }
    // Barycentrics of a lightmap point, unclamped: the square may reach past the triangle.
    let to_world = |u: glam::Vec2| {
        let d = u - uv[0];
        let (a, b) = (d.perp_dot(e2) / det, e1.perp_dot(d) / det);
        scene.point(tri, Vec3::new(1.0 - a - b, a, b))
    };
    let (w, h) = (set.width as f32, set.height as f32);
    let (u0, v0, u1, v1) = (t.i as f32 / w, t.j as f32 / h, (t.i + 1) as f32 / w, (t.j + 1) as f32 / h);
    let q = [
        to_world(glam::Vec2::new(u0, v0)),
        to_world(glam::Vec2::new(u1, v0)),
        to_world(glam::Vec2::new(u1, v1)),
        to_world(glam::Vec2::new(u0, v1)),
    ];
    q.iter().all(|v| v.is_finite()).then_some(q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use prm::Scene;
    use rand::{Rng, SeedableRng};

    /// A settled receiver keeps its old echo links only while every source is the same texel
    /// as then (after a UV edit an atlas slot can hold another triangle's texel).
    #[test]
    fn an_echo_link_is_kept_only_from_the_same_source() {
        let texel = |i: u32| prm::Texel {
            i,
            j: 0,
            position: Vec3::new(i as f32, 0.0, 0.0),
            normal: Vec3::Y,
            triangle: 0,
            bary: Vec3::ONE / 3.0,
        };
        let set = TexelSet {
            width: 4,
            height: 1,
            texels: vec![texel(0), texel(2)],
            index: vec![0, TexelSet::EMPTY, 1, TexelSet::EMPTY],
            dilation: Vec::new(),
            zero_uv_area_triangles: 0,
            shared_gutter_texels: 0,
            buried: Default::default(),
            buried_centres: Vec::new(),
        };
        let point = |t: u32| NearPoint { texel: t, position: Vec3::new(t as f32, 0.0, 0.0), normal: Vec3::Y };
        let points = [point(0), point(2)];
        let old = Echo {
            albedo: vec![Vec3::ONE; 2],
            links: vec![EchoLink { receiver: 0, source: 1, factor: 0.25 }],
            creases: Vec::new(),
        };
        let reuse = |same: &[bool]| {
            EchoReuse { old: &old, old_points: &points, settled: &[true, true], same }
                .links_of(&set, &points, 0)
        };
        assert_eq!(reuse(&[true, true]), Some(vec![EchoLink { receiver: 0, source: 1, factor: 0.25 }]));
        assert_eq!(reuse(&[true, false]), None, "its source's slot holds another texel now");
    }

    /// A 20 cm wall square standing on a floor: a floor point 6 mm in front of its foot sees it
    /// at its lowest 3 cm, straight above itself (the kernel's mean height over a wall that
    /// high, seen from 6 mm, is 6 mm x (ln(2 x 20 / 0.6) - 1), 1.9 cm); a point 2 m in front, facing it, at its middle;
    /// a point behind it not at all.
    #[test]
    fn a_receiver_at_a_walls_foot_sees_its_square_at_the_crease() {
        let q = [Vec3::ZERO, Vec3::new(0.2, 0.0, 0.0), Vec3::new(0.2, 0.2, 0.0), Vec3::new(0.0, 0.2, 0.0)];
        let Some((foot, side)) = seen_centre((Vec3::new(0.1, 0.0, 0.006), Vec3::Y), &q, Vec3::Z) else {
            panic!("the foot of the wall sees nothing of it")
        };
        assert!((side - 0.2).abs() < 1e-6, "side {side}");
        assert!(foot.y < 0.03 && (foot.x - 0.1).abs() < 0.005 && foot.z.abs() < 1e-6, "{foot}");
        assert!(foot.distance(Vec3::new(0.1, 0.1, 0.0)) > CREASE_SHIFT * side, "not a crease: {foot}");
        let Some((front, _)) = seen_centre((Vec3::new(0.1, 0.1, 2.0), Vec3::NEG_Z), &q, Vec3::Z) else {
            panic!("a point in front sees nothing")
        };
        assert!(front.distance(Vec3::new(0.1, 0.1, 0.0)) < 1e-3, "{front}");
        assert!(seen_centre((Vec3::new(0.1, 0.1, -1.0), Vec3::Z), &q, Vec3::Z).is_none());
    }

    /// A texel at the origin facing up under a square cell 1 m above it (facing down, cut into
    /// four triangles along x = 0), a blocker over the x > 0 half at half height, and a cell
    /// triangle standing on the texel's own plane half below it (a plinth top under its
    /// pillar): the hidden half counts for nothing, the half below the plane is clipped and
    /// the rest is seen, and a cell facing away sends nothing.
    #[test]
    fn a_link_counts_the_part_of_its_cell_the_texel_sees() {
        let (x, n) = (Vec3::ZERO, Vec3::Y);
        let c = |a: f32, b: f32| Vec3::new(a, 1.0, b);
        let left = [[c(-1.0, -1.0), c(0.0, -1.0), c(0.0, 1.0)], [c(-1.0, -1.0), c(0.0, 1.0), c(-1.0, 1.0)]];
        let right = [[c(0.0, -1.0), c(1.0, -1.0), c(1.0, 1.0)], [c(0.0, -1.0), c(1.0, 1.0), c(0.0, 1.0)]];
        let square = [c(-1.0, -1.0), c(1.0, -1.0), c(1.0, 1.0), c(-1.0, 1.0)];
        let whole = point_to_polygon(x, n, &square);
        let seen = |bvh: &Bvh, tris: &[[Vec3; 3]]| -> f32 {
            tris.iter().map(|t| seen_form_factor(bvh, x, n, t, Vec3::NEG_Y, 1.0)).sum()
        };
        let all: Vec<[Vec3; 3]> = left.iter().chain(&right).copied().collect();
        // A far-away speck, so the BVH is not empty.
        let far = |k: f32| Vec3::new(50.0 + k, 50.0, 50.0);
        let open =
            Scene::from_mesh(vec![far(0.0), far(0.1), far(0.2)], vec![glam::Vec2::ZERO; 3], &[0, 1, 2]);
        let open = Bvh::build(&open);
        assert!((seen(&open, &all) - whole).abs() < 1e-4 * whole, "{} against {whole}", seen(&open, &all));
        let blocker = vec![
            Vec3::new(0.0, 0.5, -5.0),
            Vec3::new(5.0, 0.5, -5.0),
            Vec3::new(5.0, 0.5, 5.0),
            Vec3::new(0.0, 0.5, 5.0),
        ];
        let half = Scene::from_mesh(blocker, vec![glam::Vec2::ZERO; 4], &[0, 1, 2, 0, 2, 3]);
        let half = Bvh::build(&half);
        let got = seen(&half, &all);
        assert!((got - 0.5 * whole).abs() < 1e-4 * whole, "{got} against half of {whole}");
        assert!(seen(&half, &right) == 0.0, "the hidden half is hidden");
        // Weak links (one ray a triangle) see the same halves.
        let weak: f32 = all.iter().map(|t| seen_form_factor(&half, x, n, t, Vec3::NEG_Y, 1e-3)).sum();
        assert!((weak - 0.5 * whole).abs() < 1e-4 * whole, "{weak} with one ray each");
        // Standing on the texel's floor, half below it (a plinth top under its pillar): the part
        // above is seen whole, since the rays go to points of the clipped part; a ray to the
        // triangle's own centroid, under the floor, would say nothing was.
        let floor = vec![
            Vec3::new(-5.0, 0.0, -5.0),
            Vec3::new(5.0, 0.0, -5.0),
            Vec3::new(5.0, 0.0, 5.0),
            Vec3::new(-5.0, 0.0, 5.0),
        ];
        let floor = Bvh::build(&Scene::from_mesh(floor, vec![glam::Vec2::ZERO; 4], &[0, 1, 2, 0, 2, 3]));
        let upright = [Vec3::new(-0.5, -1.0, 1.0), Vec3::new(0.5, -1.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let centroid = (upright[0] + upright[1] + upright[2]) / 3.0;
        assert!(!floor.visible(x, n, centroid, Vec3::NEG_Z), "the centroid is under the floor");
        let above = point_to_polygon(x, n, &upright);
        assert!(above > 0.01);
        for scale in [1.0, 1e-3] {
            let got = seen_form_factor(&floor, x, n, &upright, Vec3::NEG_Z, scale);
            assert!((got - above).abs() < 1e-6, "{got} against {above} at scale {scale}");
        }
        assert_eq!(seen_form_factor(&floor, x, n, &upright, Vec3::Z, 1.0), 0.0, "facing away");
    }

    /// The square cell 1 m over a texel (as [`a_link_counts_the_part_of_its_cell_the_texel_sees`],
    /// two triangles cut into pieces no longer than 0.6 m), a blocker over x > 0.3 at half
    /// height, which hides the cell's x > 0.6 from the texel: the pieces wholly beyond that are
    /// hidden, those wholly before it seen, the factor is the seen pieces' form factor (the
    /// bits and the factor agree) and within 3 % of the exact form factor of the cell's part
    /// x < 0.6; with nothing in the way, nothing is hidden and the factor is the whole cell's.
    #[test]
    fn a_link_hides_the_pieces_of_its_cell_the_texel_does_not_see() {
        let c = |a: f32, b: f32| Vec3::new(a, 1.0, b);
        let square = [c(-1.0, -1.0), c(1.0, -1.0), c(1.0, 1.0), c(-1.0, 1.0)];
        let cut = Cells::from_lists(vec![vec![
            [square[0], square[2], square[1]],
            [square[0], square[3], square[2]],
        ]]);
        let (pieces, from) = cut.split_long_from(0.6);
        let n = pieces.triangles.len();
        assert!(n > 16 && n <= HIDDEN_TRIANGLES, "{n} pieces");
        // The texel's point and normal.
        let texel = (Vec3::ZERO, Vec3::Y);
        let entry =
            Entry { position: c(0.0, 0.0), normal: Vec3::NEG_Y, albedo: Vec3::ONE, area: 4.0, triangle: 0 };
        let quad = |pts: Vec<Vec3>| {
            let idx = [0, 1, 2, 0, 2, 3];
            Bvh::build(&Scene::from_mesh(pts, vec![glam::Vec2::ZERO; 4], &idx))
        };
        let far = |k: f32| Vec3::new(50.0 + k, 50.0, 50.0);
        let open = quad(vec![far(0.0), far(0.1), far(0.2), far(0.3)]);
        let whole = point_to_polygon(Vec3::ZERO, Vec3::Y, &square);
        let (f, hidden) = seen_cell(&open, texel, &entry, 4.0, (&cut, &pieces, &from), 0);
        assert_eq!(hidden, 0);
        assert!((f - whole).abs() < 1e-4 * whole, "{f} against {whole}");
        let blocker = quad(vec![
            Vec3::new(0.3, 0.5, -5.0),
            Vec3::new(0.3, 0.5, 5.0),
            Vec3::new(5.0, 0.5, 5.0),
            Vec3::new(5.0, 0.5, -5.0),
        ]);
        let (f, hidden) = seen_cell(&blocker, texel, &entry, 4.0, (&cut, &pieces, &from), 0);
        let mut seen_pieces = 0.0;
        for (k, t) in pieces.of(0).iter().enumerate() {
            let is_hidden = (hidden >> k) & 1 == 1;
            let xs = t.map(|p| p.x);
            if xs.iter().all(|&x| x > 0.62) {
                assert!(is_hidden, "piece {k} {t:?} is behind the blocker");
            }
            if xs.iter().all(|&x| x < 0.58) {
                assert!(!is_hidden, "piece {k} {t:?} is in the open");
            }
            if !is_hidden {
                seen_pieces += point_to_polygon(Vec3::ZERO, Vec3::Y, t);
            }
        }
        assert!((f - seen_pieces).abs() < 1e-4 * whole, "factor {f}, seen pieces {seen_pieces}");
        let part =
            point_to_polygon(Vec3::ZERO, Vec3::Y, &[c(-1.0, -1.0), c(0.6, -1.0), c(0.6, 1.0), c(-1.0, 1.0)]);
        assert!((f / part - 1.0).abs() < 0.03, "factor {f} against the seen part's {part}");
    }

    /// An update keeps a texel's near links by geometry (`NearReuse`) only where nothing it
    /// reads can have changed: three 1 m cells on a floor at x = 0, 5 and 10 (reach 1 m), a
    /// texel by each. The cell at 5 changed and an edit's box stands on the cell at 10: only
    /// the texel by the cell at 0 keeps its links, and not if its triangle changed or the far
    /// field lights it now and did not then.
    #[test]
    fn near_links_are_kept_only_clear_of_the_edit() {
        let square = |x: f32| {
            let c = |a: f32, b: f32| Vec3::new(x + a, 0.0, b);
            vec![[c(-0.5, -0.5), c(-0.5, 0.5), c(0.5, 0.5)], [c(-0.5, -0.5), c(0.5, 0.5), c(0.5, -0.5)]]
        };
        let cells = Cells::from_lists(vec![square(0.0), square(5.0), square(10.0)]);
        let cell: Vec<(Vec3, f32)> =
            (0..3).map(|j| (cells.centroid(j).unwrap_or(Vec3::NAN), cells.area(j))).collect();
        let reach = 1.0;
        let reaches = ReachGrid::new(&cell, reach);
        let speck = |k: f32| Vec3::new(50.0 + k, 50.0, 50.0);
        let bvh = Bvh::build(&Scene::from_mesh(
            vec![speck(0.0), speck(0.1), speck(0.2)],
            vec![glam::Vec2::ZERO; 3],
            &[0, 1, 2],
        ));
        let texel = |x: f32| prm::Texel {
            i: x as u32,
            j: 0,
            position: Vec3::new(x + 0.2, 0.0, 0.0),
            normal: Vec3::Y,
            triangle: 0,
            bary: Vec3::splat(1.0 / 3.0),
        };
        let old_far = Far::default();
        let changed = crate::update::ChangedCells::new(vec![(cell[1].0, cell[1].1.sqrt())]);
        let boxes =
            crate::update::EditBoxes::new(vec![(Vec3::new(10.0, 0.0, -0.1), Vec3::new(10.1, 0.5, 0.1))]);
        let (same, moved) = ([true], [false]);
        let reuse = |triangle| NearReuse {
            old: &[],
            settled: &[],
            same_texel: &[],
            triangle,
            old_far: &old_far,
            changed: &changed,
            boxes: &boxes,
            by_geometry: Default::default(),
        };
        let r = reuse(&same);
        let kept = |r: &NearReuse, x: f32, fades: bool| {
            let t = texel(x);
            r.kept_by_geometry(&bvh, &t, t.i, fades, &cells, &cell, reach, &reaches)
        };
        assert!(kept(&r, 0.0, false), "clear of every change");
        assert!(!kept(&r, 5.0, false), "by a changed cell");
        assert!(!kept(&r, 10.0, false), "its cell under the edit's box");
        assert!(!kept(&r, 0.0, true), "the far field lights it now, not then");
        assert!(!kept(&reuse(&moved), 0.0, false), "its triangle changed");
        assert_eq!(r.by_geometry.into_inner(), 1);
        // More changed cells than `MAX_GEOMETRY`, all far away: every texel is made again.
        let far_away =
            crate::update::ChangedCells::new(vec![(Vec3::splat(1e3), 1.0); crate::update::MAX_GEOMETRY + 1]);
        let wide = NearReuse { changed: &far_away, ..reuse(&same) };
        assert!(!kept(&wide, 0.0, false), "a wide edit keeps nothing by geometry");
    }

    /// The echo's reach is the one asked for where a receiver looks at few points, and shrinks
    /// until it looks at no more than [`ECHO_CANDIDATES`] on average where it would look at
    /// all of them (a reach as large as the level: a map of two entries). The 27 cells around
    /// a receiver hold every point within one reach of it (in each axis) and none past two.
    #[test]
    fn the_echo_reach_shrinks_only_where_it_would_look_at_too_many_points() {
        let points: Vec<Vec3> =
            (0..10_000).map(|k| Vec3::new((k % 100) as f32 * 0.01, 0.0, (k / 100) as f32 * 0.01)).collect();
        // The mean number of points within `h` of a point in each axis.
        let within = |h: f32| {
            let n: usize = points
                .iter()
                .map(|p| points.iter().filter(|q| (**q - *p).abs().max_element() < h).count())
                .sum();
            n as f32 / points.len() as f32
        };
        let (kept, grid) = echo_grid(&points, 0.03);
        assert_eq!(kept, 0.03);
        assert_eq!(grid.values().map(Vec::len).sum::<usize>(), points.len());
        let (cut, grid) = echo_grid(&points, 10.0);
        assert_eq!(grid.values().map(Vec::len).sum::<usize>(), points.len());
        let (near, far) = (within(cut), within(2.0 * cut));
        assert!(near <= ECHO_CANDIDATES as f32, "reach {cut}: {near} points within it");
        assert!(far >= ECHO_CANDIDATES as f32 / 2.0, "reach {cut} cut too far: {far} points within twice it");
        let (piled, _) = echo_grid(&vec![Vec3::ONE; 5000], 1.0);
        assert!(piled.is_finite() && piled > 0.0, "points on one spot: reach {piled}");
    }

    #[test]
    fn the_reach_grid_lists_every_cell_that_reaches_a_point() {
        // Cells of varied sizes (one too large for the grid) against brute force.
        let mut rng = rand_pcg::Pcg32::seed_from_u64(7);
        let mut cells: Vec<(Vec3, f32)> = (0..400)
            .map(|_| {
                let c = Vec3::new(
                    rng.random_range(-20.0..20.0),
                    rng.random_range(0.0..5.0),
                    rng.random_range(-20.0..20.0),
                );
                (c, rng.random_range(0.0..2.0f32).powi(2))
            })
            .collect();
        cells.push((Vec3::ZERO, 1e4));
        cells.push((Vec3::ONE, 0.0));
        let reach = 0.8;
        let grid = ReachGrid::new(&cells, reach);
        assert_eq!(grid.everywhere, vec![400], "the huge cell is checked everywhere");
        for _ in 0..500 {
            let p = Vec3::new(
                rng.random_range(-22.0..22.0),
                rng.random_range(-1.0..6.0),
                rng.random_range(-22.0..22.0),
            );
            let listed = grid.around(p);
            assert!(listed.windows(2).all(|w| w[0] < w[1]), "in order, once each");
            for (j, &(c, area)) in cells.iter().enumerate() {
                if area > 0.0 && c.distance(p) <= reach + area.sqrt() {
                    assert!(listed.contains(&j), "cell {j} reaches {p} but is not listed");
                }
            }
        }
    }
}
