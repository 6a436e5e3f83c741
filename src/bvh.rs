//! Ray queries over the scene: closest hit and occlusion, on an `obvhs` compressed wide BVH.
//!
//! **Offsets.** A ray leaving a surface starts at the point moved along the normal by
//! `eps(p) = max(1e-5 x scene diagonal, 64 ulp(max |p_k|))`. The first term scales with the
//! level, so the same code works for a 1e-3 and a 1e4 unit scene; the second keeps the offset
//! above float round-off when a small level sits far from the origin. Rays then use tmin = 0.
//! A segment between two surface points ends at the far point's own offset, on its front side,
//! so the far surface itself never occludes a visible pair.
//!
//! **BVH space.** obvhs's wide-BVH node test ignores boxes closer than an absolute 1e-4 along
//! the ray, which at 1e-3 scene scale drops real hits. The BVH is therefore built over the scene
//! scaled by a power of two that brings its diagonal to [1024, 2048): a power-of-two scale is
//! exact in floating point, so hits, distances and offsets are the same as in scene space, and
//! 1e-4 becomes under 1e-7 of the scene, far below the offset.
//!
//! [`Bvh::closest_hit_brute_force`] is the slow twin every traversal is tested against.

use std::sync::OnceLock;
use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle as BvhTriangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use crate::scene::Scene;

/// Offset floor relative to the scene diagonal.
pub const OFFSET_REL_SCENE: f32 = 1e-5;
/// Offset floor relative to the magnitude of the coordinates (64 ulp).
pub const OFFSET_REL_ULP: f32 = 64.0 * f32::EPSILON;

/// Fewest triangles for which [`Bvh::build_with_rooms`] looks for rooms: a smaller level's
/// tree stays in cache whole (the chamber, 3,454 triangles: 6.1 closest-hit Mrays/s a thread;
/// 16 of them, 55,264: 3.4, and 5.1 with room trees).
pub const ROOM_TREES_MIN_TRIANGLES: usize = 16_384;

/// A ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Scene triangle index.
    pub triangle: u32,
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Barycentrics: the point is `(1-u-v) v0 + u v1 + v v2`.
    pub u: f32,
    pub v: f32,
}

impl Hit {
    /// Barycentrics as (w0, w1, w2).
    pub fn bary(&self) -> Vec3 {
        Vec3::new(1.0 - self.u - self.v, self.u, self.v)
    }
}

/// Ray-query acceleration structure over a scene's triangles.
pub struct Bvh {
    /// The whole level (None: no triangles).
    tree: Option<Tree>,
    /// Absolute offset floor: `OFFSET_REL_SCENE x diagonal`.
    scene_eps: f32,
    /// Power-of-two factor from scene space to BVH space.
    to_bvh: f32,
    /// Boxes with a tree of their own ([`Bvh::localise`]; None: it found none); set at most once.
    local: OnceLock<Option<Local>>,
}

/// A wide BVH over some triangles.
struct Tree {
    bvh: CwBvh,
    /// Triangles in BVH order (BVH space).
    tris: Vec<BvhTriangle>,
    /// Scene triangle index for each entry of `tris`.
    ids: Vec<u32>,
}

impl Tree {
    /// Over `tris` (BVH space), the scene triangle of each being `ids`' entry; None if empty.
    fn build(tris: Vec<BvhTriangle>, ids: &[u32]) -> Option<Tree> {
        if tris.is_empty() {
            return None;
        }
        let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
        // Store triangles in BVH leaf order so traversal reads them sequentially. Traversal
        // hands the callback an index into `primitive_indices`, which is then also an index
        // into `tris`.
        let ordered = bvh.primitive_indices.iter().map(|&i| tris[i as usize]).collect();
        let ids = bvh.primitive_indices.iter().map(|&i| ids[i as usize]).collect();
        Some(Tree { bvh, tris: ordered, ids })
    }

    /// Closest hit within the ray's `(tmin, tmax)`: index into `tris`, and `(t, u, v)` in BVH
    /// space.
    #[inline]
    fn closest(&self, ray: Ray) -> Option<(usize, (f32, f32, f32))> {
        let mut hit = RayHit::none();
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| intersect(&self.tris[id], r).map_or(f32::INFINITY, |h| h.0))
        {
            return None;
        }
        let k = hit.primitive_id as usize;
        Some((k, intersect(&self.tris[k], &ray)?))
    }

    /// True when any triangle lies within the ray's `(tmin, tmax)`.
    #[inline]
    fn any(&self, ray: Ray) -> bool {
        !self.bvh.ray_traverse_miss(ray, |r, id| intersect(&self.tris[id], r).map_or(f32::INFINITY, |h| h.0))
    }
}

/// Local trees: on a level of closed rooms most rays start and end in one room, and a tree of
/// that room's few thousand triangles stays in cache where the level's does not (16 chambers:
/// 2.3 closest-hit Mrays/s a thread against the lone chamber's 4.9).
///
/// Exact by construction: a region holds every triangle whose bounding box meets its box
/// (grown by [`REGION_MARGIN`] of its diagonal), so for a ray whose origin lies in the box, a
/// hit the region's tree finds before the ray leaves the box is the level's closest hit (any
/// closer one lies on the same segment inside the box, on a triangle the region holds). A ray
/// that finds nothing before it leaves goes to the level's tree. Equal distances on two
/// triangles (a ray through a shared edge) may name the other triangle.
struct Local {
    regions: Vec<Region>,
    /// A coarse grid over the level: per cell, the region whose box overlaps most of it (of
    /// equal overlaps, the larger box; `u16::MAX`: none).
    lo: Vec3,
    inv_side: f32,
    dims: [usize; 3],
    cell: Vec<u16>,
}

/// A box of the level and its own tree.
struct Region {
    lo: Vec3,
    hi: Vec3,
    tree: Tree,
}

/// A region also holds triangles whose bounds come within this share of its diagonal, so that
/// round-off at its faces never leaves one out.
const REGION_MARGIN: f32 = 1e-4;

/// A region is kept only when its tree holds at most this share of the level's triangles.
const REGION_SHARE: f32 = 0.5;

/// Cells of the region grid along the level's longest side.
const REGION_GRID: f32 = 64.0;

/// How far along a ray leaving a box's inside it is allowed to go: a little short of where it
/// leaves, so that round-off in the exit distance never lets a hit outside count.
const EXIT_SHRINK: f32 = 1.0 - 1e-5;

/// Rays a region's test sends ([`Region::keeps_rays`]).
const REGION_TEST_RAYS: usize = 256;

impl Region {
    /// The distance at which the ray from `o` (inside) along `d` leaves the box, shrunk.
    #[inline]
    fn exit(&self, o: Vec3, d: Vec3) -> f32 {
        // +0 for -0, as in `Bvh::ray`: a -0 component would pick the far face of +0 and give
        // an exit at -infinity (the ray would never use its room's tree).
        let d = d + Vec3::ZERO;
        let far = Vec3::select(d.cmpge(Vec3::ZERO), self.hi, self.lo);
        let t = (far - o) / d;
        // A zero component gives an infinite (or NaN, at a face) distance: `min` drops NaN.
        t.x.min(t.y).min(t.z).max(0.0) * EXIT_SHRINK
    }

    /// True when most rays leaving its triangles' front faces (points inside the box, cosine
    /// directions, a fixed pattern) hit one of its triangles before they leave the box: a room
    /// worth a tree. A pillar's hollow fails: its box's triangles face out of it.
    fn keeps_rays(&self, bvh: &Bvh, scene: &Scene) -> bool {
        let inside: Vec<u32> = self
            .tree
            .ids
            .iter()
            .copied()
            .filter(|&t| self.contains(scene.corners(t as usize).iter().sum::<Vec3>() / 3.0))
            .collect();
        if inside.is_empty() {
            return false;
        }
        let golden = 0.618_034f32;
        let kept = (0..REGION_TEST_RAYS)
            .filter(|&k| {
                let t = inside[k * inside.len() / REGION_TEST_RAYS] as usize;
                let [a, b, c] = scene.corners(t);
                let n = (b - a).cross(c - a).normalize_or_zero();
                let (u, v) =
                    (((k as f32 + 0.5) * golden).fract(), (k as f32 + 0.5) / REGION_TEST_RAYS as f32);
                let (u, v) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
                let o = bvh.offset(a + (b - a) * u + (c - a) * v, n);
                let d = crate::sampling::cosine_direction(n, v, u);
                self.contains(o) && bvh.closest_in(&self.tree, o, d, self.exit(o, d)).is_some()
            })
            .count();
        2 * kept >= REGION_TEST_RAYS
    }

    #[inline]
    fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmple(self.hi).all()
    }
}

impl Local {
    /// The region whose box holds `p`, if the grid names one.
    #[inline]
    fn region_at(&self, p: Vec3) -> Option<&Region> {
        let q = (p - self.lo) * self.inv_side;
        if !(q.min_element() >= 0.0) {
            return None;
        }
        let [x, y, z] = [q.x as usize, q.y as usize, q.z as usize];
        if x >= self.dims[0] || y >= self.dims[1] || z >= self.dims[2] {
            return None;
        }
        let r = self.cell[(z * self.dims[1] + y) * self.dims[0] + x];
        let region = self.regions.get(r as usize)?;
        region.contains(p).then_some(region)
    }
}

/// Scene triangle `t` in BVH space (scaled by `to_bvh`).
fn bvh_triangle(scene: &Scene, t: u32, to_bvh: f32) -> BvhTriangle {
    let [a, b, c] = scene.corners(t as usize).map(|p| Vec3A::from_array((p * to_bvh).to_array()));
    BvhTriangle { v0: a, v1: b, v2: c }
}

/// The power of two that brings a scene diagonal into [1024, 2048).
fn bvh_scale(diagonal: f32) -> f32 {
    if !(diagonal > 0.0 && diagonal.is_finite()) {
        return 1.0;
    }
    let e = 10 - diagonal.log2().floor() as i32;
    2f32.powi(e.clamp(-100, 100))
}

impl Bvh {
    /// Build over all triangles of `scene`.
    pub fn build(scene: &Scene) -> Bvh {
        Bvh::build_with_extent(scene, scene.diagonal())
    }

    /// Build over all triangles of `scene`, and on a level of at least
    /// [`ROOM_TREES_MIN_TRIANGLES`] triangles give its closed rooms trees of their own
    /// ([`Bvh::localise`]; the rooms' flood fill costs 0.2 s on the chamber, 0.5 s on 16).
    pub fn build_with_rooms(scene: &Scene) -> Bvh {
        let bvh = Bvh::build(scene);
        if scene.triangles.len() >= ROOM_TREES_MIN_TRIANGLES {
            bvh.localise(scene, &crate::rooms::Rooms::of_scene(scene));
        }
        bvh
    }

    /// Build with the offsets and the internal scale of a level whose diagonal is `diagonal`
    /// rather than the scene's own: an editor moving objects changes the scene's bounds, and
    /// rays that do not meet what moved must give the same answer before and after.
    pub fn build_with_extent(scene: &Scene, diagonal: f32) -> Bvh {
        let all: Vec<u32> = (0..scene.triangles.len() as u32).collect();
        Bvh::build_subset(scene, &all, diagonal)
    }

    /// Build over the triangles `subset` of `scene` (scene indices), with the offsets and scale
    /// of a level whose diagonal is `diagonal`. Queries decompose exactly: with the same
    /// `diagonal`, a segment is visible in the whole level iff it is visible in each part of
    /// a partition of its triangles (same offsets, same per-triangle tests).
    pub fn build_subset(scene: &Scene, subset: &[u32], diagonal: f32) -> Bvh {
        let to_bvh = bvh_scale(diagonal);
        let tris: Vec<BvhTriangle> = subset.iter().map(|&t| bvh_triangle(scene, t, to_bvh)).collect();
        let scene_eps = OFFSET_REL_SCENE * diagonal.max(f32::MIN_POSITIVE);
        Bvh { tree: Tree::build(tris, subset), scene_eps, to_bvh, local: OnceLock::new() }
    }

    /// Give the level's rooms ([`crate::rooms::Rooms`], made from the same `scene`) trees of
    /// their own, which rays starting in them try first (see `Local`). Answers stay the same,
    /// but for which of two triangles hit at the same distance is named. Left out: a room whose
    /// tree would hold more than half of the level's triangles (the outside, or the one room of
    /// a one-room level), and one whose rays mostly leave it (`Region::keeps_rays`: a
    /// pillar's hollow, whose box a ray from the pillar's faces would try and leave at once).
    /// With no room left, nothing changes. Only the first call on a BVH counts (the answer may
    /// not change while others trace), and only on a BVH built over the whole `scene` (the
    /// caller's to keep: a BVH over another scene of as many triangles is not told apart).
    /// Everything that traces a level and must give the same bytes as another run of it
    /// (a precompute, its shards) localises at the same point, before the rays that count.
    pub fn localise(&self, scene: &Scene, rooms: &crate::rooms::Rooms) {
        let Some(tree) = &self.tree else {
            let _ = self.local.set(None);
            return;
        };
        if tree.tris.len() != scene.triangles.len() || self.is_localised() {
            return;
        }
        let bounds: Vec<(Vec3, Vec3)> = (0..scene.triangles.len())
            .map(|t| {
                let [a, b, c] = scene.corners(t);
                (a.min(b).min(c), a.max(b).max(c))
            })
            .collect();
        let (lo, hi) =
            bounds.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(l, h), b| (l.min(b.0), h.max(b.1)));
        if !(lo.is_finite() && hi.is_finite()) {
            let _ = self.local.set(None);
            return;
        }
        let most = (REGION_SHARE * bounds.len() as f32) as usize;
        let regions: Vec<Region> = rooms
            .boxes()
            .par_iter()
            .filter_map(|&(lo, hi)| {
                let grow = Vec3::splat(REGION_MARGIN * (hi - lo).length());
                let (glo, ghi) = (lo - grow, hi + grow);
                let ids: Vec<u32> = (0..bounds.len() as u32)
                    .filter(|&t| {
                        let (a, b) = bounds[t as usize];
                        b.cmpge(glo).all() && a.cmple(ghi).all()
                    })
                    .collect();
                if ids.len() > most {
                    return None;
                }
                let tris = ids.iter().map(|&t| bvh_triangle(scene, t, self.to_bvh)).collect();
                let region = Region { lo, hi, tree: Tree::build(tris, &ids)? };
                region.keeps_rays(self, scene).then_some(region)
            })
            .collect();
        if regions.is_empty() || regions.len() >= usize::from(u16::MAX) {
            let _ = self.local.set(None);
            return;
        }
        let side = ((hi - lo).max_element() / REGION_GRID).max(f32::MIN_POSITIVE);
        let dims = ((hi - lo) / side).floor().as_uvec3() + glam::UVec3::ONE;
        let dims = [dims.x as usize, dims.y as usize, dims.z as usize];
        // Per cell, the region whose box overlaps most of it; of equal overlaps (a cell wholly
        // inside two boxes: a pocket in a room), the larger box.
        let mut cell = vec![u16::MAX; dims[0] * dims[1] * dims[2]];
        let mut best = vec![(0f32, 0f32); cell.len()];
        for (r, region) in regions.iter().enumerate() {
            let size = region.hi - region.lo;
            let volume = size.x * size.y * size.z;
            let a = ((region.lo - lo) / side).floor().max(Vec3::ZERO).as_uvec3();
            let b = ((region.hi - lo) / side).floor().max(Vec3::ZERO).as_uvec3();
            for z in a.z as usize..=(b.z as usize).min(dims[2] - 1) {
                for y in a.y as usize..=(b.y as usize).min(dims[1] - 1) {
                    for x in a.x as usize..=(b.x as usize).min(dims[0] - 1) {
                        let c0 = lo + Vec3::new(x as f32, y as f32, z as f32) * side;
                        let overlap = (region.hi.min(c0 + side) - region.lo.max(c0)).max(Vec3::ZERO);
                        let v = overlap.x * overlap.y * overlap.z;
                        let i = (z * dims[1] + y) * dims[0] + x;
                        if (v, volume) > best[i] {
                            best[i] = (v, volume);
                            cell[i] = r as u16;
                        }
                    }
                }
            }
        }
        let _ = self.local.set(Some(Local { regions, lo, inv_side: 1.0 / side, dims, cell }));
    }

    /// The room tree (an index below [`Bvh::local_regions`]) a ray starting at `p` tries first.
    pub fn region_at(&self, p: Vec3) -> Option<usize> {
        let local = self.local.get()?.as_ref()?;
        let region = local.region_at(p)?;
        local.regions.iter().position(|r| std::ptr::eq(r, region))
    }

    /// Whether [`Bvh::localise`] has run on this BVH (whatever it found).
    pub fn is_localised(&self) -> bool {
        self.local.get().is_some()
    }

    /// How many boxes have trees of their own ([`Bvh::localise`]).
    pub fn local_regions(&self) -> usize {
        self.local.get().and_then(Option::as_ref).map_or(0, |l| l.regions.len())
    }

    /// The offset distance used at point `p`.
    #[inline]
    pub fn eps_at(&self, p: Vec3) -> f32 {
        self.scene_eps.max(OFFSET_REL_ULP * p.abs().max_element())
    }

    /// `p` moved off its surface along the unit normal `n` (front side).
    #[inline]
    pub fn offset(&self, p: Vec3, n: Vec3) -> Vec3 {
        p + n * self.eps_at(p)
    }

    /// A ray in BVH space.
    #[inline]
    fn ray(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Ray {
        let o = origin * self.to_bvh;
        // Adding +0 turns -0 into +0: obvhs picks the traversal octant from `d < 0` but the
        // inverse direction from the sign bit, and a -0 component makes the two disagree and
        // the ray miss everything (an axis-aligned ray along -n where n has a +0 component).
        let dir = dir + Vec3::ZERO;
        Ray::new(
            glam::Vec3A::from_array(o.to_array()),
            glam::Vec3A::from_array(dir.to_array()),
            0.0,
            tmax * self.to_bvh,
        )
    }

    /// Closest hit along a unit direction within `(0, tmax)`.
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let tree = self.tree.as_ref()?;
        if let Some((region, inside)) = self.room_of_ray(origin, dir, tmax) {
            if let Some(hit) = self.closest_in(&region.tree, origin, dir, tmax.min(inside)) {
                return Some(hit);
            }
            if tmax <= inside {
                return None;
            }
        }
        self.closest_in(tree, origin, dir, tmax)
    }

    /// The room whose tree a ray tries first, and how far along it the ray stays in its box.
    /// A NaN length goes to the level's tree, which finds nothing for it.
    #[inline]
    fn room_of_ray(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(&Region, f32)> {
        let region = self.local.get()?.as_ref().filter(|_| tmax >= 0.0)?.region_at(origin)?;
        Some((region, region.exit(origin, dir)))
    }

    #[inline]
    fn closest_in(&self, tree: &Tree, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let (k, (t, u, v)) = tree.closest(self.ray(origin, dir, tmax))?;
        Some(Hit { triangle: tree.ids[k], t: t / self.to_bvh, u, v })
    }

    /// True when anything lies along the unit direction within `(0, tmax)`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let Some(tree) = self.tree.as_ref() else { return false };
        if let Some((region, inside)) = self.room_of_ray(origin, dir, tmax) {
            if region.tree.any(self.ray(origin, dir, tmax.min(inside))) {
                return true;
            }
            if tmax <= inside {
                return false;
            }
        }
        tree.any(self.ray(origin, dir, tmax))
    }

    /// Closest hit of a ray leaving surface point `p` (unit normal `n`) along unit `dir`.
    pub fn trace_from_surface(&self, p: Vec3, n: Vec3, dir: Vec3) -> Option<Hit> {
        let o = self.offset(p, if n.dot(dir) >= 0.0 { n } else { -n });
        self.closest_hit(o, dir, f32::INFINITY)
    }

    /// Mutual visibility of two surface points, each with the unit normal of the side the
    /// other is seen from.
    pub fn visible(&self, p0: Vec3, n0: Vec3, p1: Vec3, n1: Vec3) -> bool {
        let a = self.offset(p0, n0);
        let b = self.offset(p1, n1);
        let d = b - a;
        let len = d.length();
        if !(len > 0.0) {
            return true;
        }
        !self.occluded(a, d / len, len)
    }

    /// Visibility from surface point `p` (unit normal `n`) to a point `q` in free space, such
    /// as a point light.
    pub fn visible_point(&self, p: Vec3, n: Vec3, q: Vec3) -> bool {
        let a = self.offset(p, n);
        let d = q - a;
        let len = d.length();
        if !(len > 0.0) {
            return true;
        }
        !self.occluded(a, d / len, len * (1.0 - 1e-6))
    }

    /// Visibility from surface point `p` to infinity along unit `dir` (directional lights).
    pub fn visible_dir(&self, p: Vec3, n: Vec3, dir: Vec3) -> bool {
        !self.occluded(self.offset(p, n), dir, f32::INFINITY)
    }

    /// The slow twin of [`Bvh::closest_hit`]: every triangle, in scene order.
    pub fn closest_hit_brute_force(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let ray = self.ray(origin, dir, tmax);
        let tree = self.tree.as_ref()?;
        let mut best: Option<Hit> = None;
        for (k, tri) in tree.tris.iter().enumerate() {
            if let Some((t, u, v)) = intersect(tri, &ray) {
                if best.is_none_or(|b| t < b.t) {
                    best = Some(Hit { triangle: tree.ids[k], t, u, v });
                }
            }
        }
        best.map(|h| Hit { t: h.t / self.to_bvh, ..h })
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tree.as_ref().map_or(0, |t| t.tris.len())
    }

    /// True when there is no geometry.
    pub fn is_empty(&self) -> bool {
        self.tree.is_none()
    }
}

/// Irradiance at surface point `p` (unit normal `n`) from `lights`, with shadow rays (W/m²).
/// The precompute's evaluation, the runtime's CPU twin and the bakers share it; the ground
/// truth keeps its own on purpose (DESIGN.md §7). Each light as [`shadowed_irradiance`] says.
pub fn direct_irradiance(bvh: &Bvh, lights: &[crate::Light], p: Vec3, n: Vec3) -> Vec3 {
    lights.iter().map(|l| shadowed_irradiance(l, p, n, |t| bvh.visible_to(p, n, t) as u8 as f32)).sum()
}

/// Shadow rays per area light and receiver point in [`direct_irradiance`]: one to each of the
/// 2^[`crate::light::APERTURE_LEVELS`] parts of a polygon or of a sphere's silhouette.
pub const AREA_SHADOW_RAYS: u32 = 16;

/// A polygon light's aperture parts ([`crate::light::aperture_parts`] at
/// [`crate::light::APERTURE_LEVELS`]), made once per polygon and thread: a receiver loop asks
/// for the same few lights again and again. The cache holds the corners it was made for (an
/// `Arc` it keeps alive), so a new polygon at a freed one's address is never taken for it.
fn aperture_parts(corners: &std::sync::Arc<[Vec3]>) -> std::sync::Arc<[Vec<Vec3>]> {
    use std::sync::Arc;
    type Cached = (Arc<[Vec3]>, Arc<[Vec<Vec3>]>);
    thread_local! {
        static PARTS: std::cell::RefCell<std::collections::HashMap<usize, Cached>> =
            std::cell::RefCell::new(std::collections::HashMap::new());
    }
    // The address of a polygon the cache holds cannot be reused while it holds it.
    let key = Arc::as_ptr(corners) as *const Vec3 as usize;
    PARTS.with_borrow_mut(|cache| {
        if let Some((c, parts)) = cache.get(&key) {
            if Arc::ptr_eq(c, corners) {
                return parts.clone();
            }
        }
        let parts: Arc<[Vec<Vec3>]> =
            crate::light::aperture_parts(corners, crate::light::APERTURE_LEVELS).into();
        if cache.len() >= APERTURE_CACHE {
            cache.clear();
        }
        cache.insert(key, (corners.clone(), parts.clone()));
        parts
    })
}

/// Polygons whose parts a thread keeps (a level's area lights; about 1 kB each).
const APERTURE_CACHE: usize = 1024;

impl Bvh {
    /// How close the level's geometry comes to a sphere light's centre, when closer than its
    /// radius: the sphere then reaches into a surface, and the bakers give the texels inside it
    /// its surface brightness (`I / R²`), thousands of W/m² for a small, bright bulb, where the
    /// level designer most likely meant it to touch nothing. None for other lights and for a
    /// sphere in free space. 64 rays from its centre (a Fibonacci sphere), each as long as the
    /// radius, so a sliver of geometry between them can go unseen.
    pub fn geometry_inside_sphere(&self, light: &crate::Light) -> Option<f32> {
        let crate::light::Aperture::Sphere { radius } = light.aperture else { return None };
        const RAYS: u32 = 64;
        let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
        (0..RAYS)
            .filter_map(|k| {
                let z = 1.0 - 2.0 * (k as f32 + 0.5) / RAYS as f32;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = golden * k as f32;
                let dir = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                self.closest_hit(light.position, dir, radius).map(|h| h.t)
            })
            .reduce(f32::min)
    }
}

/// Where a light's shadow ray from a receiver ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShadowTarget {
    /// A point in free space (point, spot and sphere lights).
    Point(Vec3),
    /// A point of a polygon light with the polygon's normal: it may lie on a surface (an
    /// emissive face), so the ray ends at its offset.
    Surface(Vec3, Vec3),
    /// Infinity along a unit direction (directional lights).
    Toward(Vec3),
}

impl ShadowTarget {
    /// The ray from `p` as a unit direction and a length (infinite for [`ShadowTarget::Toward`]).
    pub fn segment(&self, p: Vec3) -> (Vec3, f32) {
        match *self {
            ShadowTarget::Point(q) | ShadowTarget::Surface(q, _) => {
                let d = q - p;
                (d.normalize_or_zero(), d.length())
            }
            ShadowTarget::Toward(d) => (d, f32::INFINITY),
        }
    }
}

impl Bvh {
    /// Visibility from surface point `p` (unit normal `n`) along a light's shadow ray.
    pub fn visible_to(&self, p: Vec3, n: Vec3, t: ShadowTarget) -> bool {
        match t {
            ShadowTarget::Point(q) => self.visible_point(p, n, q),
            ShadowTarget::Surface(q, nq) => self.visible(p, n, q, nq),
            ShadowTarget::Toward(d) => self.visible_dir(p, n, d),
        }
    }
}

/// One light's irradiance at surface point `p` (unit normal `n`), each shadow ray weighed by
/// `visible(target)`: 1 or 0 for an evaluation, or a change of visibility (-1, 0, 1) for the
/// incremental baker, which then gets the change of irradiance (exactly when every ray of an
/// area light changed alike; else to round-off: an evaluation may sum the parts another way).
///
/// - A point, spot or directional light: one ray, times `I cos / d²` (or `E cos`).
/// - A polygon light: its aperture in parts (`polygon_irradiance`, below).
/// - A sphere light: its silhouette in parts (`sphere_irradiance`, below).
pub fn shadowed_irradiance(
    l: &crate::Light,
    p: Vec3,
    n: Vec3,
    mut visible: impl FnMut(ShadowTarget) -> f32,
) -> Vec3 {
    use crate::light::Aperture;
    match &l.aperture {
        Aperture::Point => {
            let inc = l.incident(p);
            let cos = n.dot(inc.to_light);
            if cos <= 0.0 || inc.irradiance == Vec3::ZERO {
                return Vec3::ZERO;
            }
            let target = if l.is_positional() {
                ShadowTarget::Point(l.position)
            } else {
                ShadowTarget::Toward(inc.to_light)
            };
            match visible(target) {
                0.0 => Vec3::ZERO,
                v => inc.irradiance * (cos * v),
            }
        }
        Aperture::Polygon { corners } => polygon_irradiance(l, corners, p, n, visible),
        Aperture::Sphere { radius } => sphere_irradiance(l, *radius, p, n, visible),
    }
}

const _: () = assert!(AREA_SHADOW_RAYS == 1 << crate::light::APERTURE_LEVELS, "one ray a part");

/// A number in [0, 1) from the receiver's bits and `x`: Cranley-Patterson rotations and
/// sample points that are deterministic and decorrelated between neighbouring texels.
fn receiver_hash(p: Vec3, x: u32) -> f32 {
    let mut v = x.wrapping_mul(0x9E37_79B9) ^ p.x.to_bits().rotate_left(7) ^ p.y.to_bits().rotate_left(13);
    v ^= p.z.to_bits().wrapping_mul(0x85EB_CA6B);
    v ^= v >> 16;
    v = v.wrapping_mul(0x7FEB_352D);
    v ^= v >> 15;
    (v >> 8) as f32 / (1u32 << 24) as f32
}

/// A polygon light's irradiance at (p, n) (paper 001 §4.1's direct virtual lights): its
/// aperture split into parts ([`crate::light::aperture_parts`]), one shadow ray a part to a
/// point of it (uniform by area over the part's side of the receiver's plane, placed by a hash
/// of `p`), weighed by `visible` and by the part's own exact unshadowed irradiance (Lambert's
/// contour integral). Without occluders this is the polygon's exact irradiance; in a penumbra
/// each ray carries the light its part gives, where one share of the whole light would not: a
/// receiver that sees the near half of a wide panel and not its far half gets the near half's
/// light, not half the panel's. A part wholly behind the receiver's plane gets no ray, and a
/// ray weighed 0 costs no contour integral.
fn polygon_irradiance(
    l: &crate::Light,
    corners: &std::sync::Arc<[Vec3]>,
    p: Vec3,
    n: Vec3,
    mut visible: impl FnMut(ShadowTarget) -> f32,
) -> Vec3 {
    let area = 0.5 * crate::light::polygon_twice_area(corners).length();
    if (p - l.position).dot(l.direction) <= 0.0 || !(area > 0.0) || l.intensity == Vec3::ZERO {
        return Vec3::ZERO;
    }
    // Radiance x pi x the range window at the centroid: Light::irradiance's factors.
    let scale = l.intensity * (std::f32::consts::PI / area * l.window((l.position - p).length()));
    let parts = aperture_parts(corners);
    let mut weights = [0.0f32; AREA_SHADOW_RAYS as usize];
    let mut sampled = [false; AREA_SHADOW_RAYS as usize];
    for (k, part) in parts.iter().enumerate() {
        let above = part.iter().filter(|c| (**c - p).dot(n) > 0.0).count();
        if above == 0 {
            continue;
        }
        let k = k as u32;
        let u = [receiver_hash(p, 2 * k + 1), receiver_hash(p, 2 * k + 2)];
        let q = if above == part.len() {
            crate::light::polygon_point(part, u)
        } else {
            // The receiver's plane cuts the part: a point of its lit side (a ray to the other
            // would cross the receiver's own surface).
            let lit = crate::form_factor::clip_above_plane(part, p, n);
            if lit.len() < 3 {
                continue;
            }
            crate::light::polygon_point(&lit, u)
        };
        weights[k as usize] = visible(ShadowTarget::Surface(q, l.direction));
        sampled[k as usize] = true;
    }
    // A part with nothing above the receiver's plane gets no ray and has no light: when every
    // ray is weighed alike it takes that weight too, so the whole is taken at once.
    let first = (0..parts.len()).find(|&k| sampled[k]).map(|k| weights[k]);
    if let Some(w) = first.filter(|&w| (0..parts.len()).all(|k| !sampled[k] || weights[k] == w)) {
        weights.iter_mut().zip(sampled).filter(|(_, s)| !s).for_each(|(x, _)| *x = w);
    }
    let weights = &weights[..parts.len()];
    let f = weighed_form_factor(
        weights,
        |k| crate::form_factor::point_to_polygon(p, n, &parts[k]),
        || crate::form_factor::point_to_polygon(p, n, corners),
    );
    scale * f
}

/// `sum_k weights[k] F_k` over an aperture's parts, `part(k)` the form factor `F_k` of part k
/// and `whole()` the whole aperture's (the sum of the parts'): over the fewer parts, those
/// weighed or those not weighed 1 taken from the whole, so a lit receiver integrates one
/// polygon, not 16. Every part weighed alike (all arriving, or all changed the same way in the
/// incremental baker): that weight times the whole, so a lit-to-blocked change is the exact
/// negative of the evaluation, not a sum of parts that differs from the whole by round-off.
fn weighed_form_factor(weights: &[f32], part: impl Fn(usize) -> f32, whole: impl FnOnce() -> f32) -> f32 {
    match weights.first() {
        None => return 0.0,
        Some(&w) if weights.iter().all(|x| *x == w) => return if w == 0.0 { 0.0 } else { w * whole() },
        Some(_) => {}
    }
    let weighed = weights.iter().filter(|w| **w != 0.0).count();
    let short = weights.iter().filter(|w| **w != 1.0).count();
    if short + 1 < weighed {
        let missing: f32 =
            weights.iter().enumerate().filter(|(_, w)| **w != 1.0).map(|(k, w)| (1.0 - w) * part(k)).sum();
        let f = whole() - missing;
        // Round-off could take an evaluation (weights 0 or 1) below zero; a change may be.
        if weights.iter().all(|w| *w >= 0.0) {
            f.max(0.0)
        } else {
            f
        }
    } else {
        weights.iter().enumerate().filter(|(_, w)| **w != 0.0).map(|(k, w)| w * part(k)).sum()
    }
}

/// A sphere light's irradiance at (p, n): its [`crate::light::Silhouette`], the disk whose
/// directions from p are the sphere's, split like a polygon light's aperture, one shadow ray a
/// part to a point of it placed by a hash of `p`, each weighed by its part's form factor. A
/// receiver that sees the whole sphere above its plane uses [`crate::light::unit_silhouette`]'s
/// 16 parts mapped onto the disk, and gets the parts' share of the polygon's form factor times
/// the exact `I cos / d²`; one whose plane cuts the sphere splits the disk's side above its
/// plane into parts of its own (up to 16), and gets their `L pi F`. Without occluders this is
/// [`crate::Light::irradiance`]. In a penumbra a ray carries its part's light, not a sixteenth
/// of the whole (a kerb hiding a low bulb's lower half from the floor beyond: -30 % before,
/// within 1.3 % now; tested). Each ray ends where it meets the sphere's near side. The rays sample their parts by area, not by form factor, so
/// the few parts that a shadow edge crosses near the horizon count their blocked side a
/// little more than its light (-1 to -3 % over such a penumbra, measured). From on or inside
/// the sphere: one ray, to its centre, times [`crate::Light::irradiance`] there (the ground
/// truth, which meets the sphere's surface from outside only, gives nothing there).
fn sphere_irradiance(
    l: &crate::Light,
    radius: f32,
    p: Vec3,
    n: Vec3,
    mut visible: impl FnMut(ShadowTarget) -> f32,
) -> Vec3 {
    // Everything relative to the receiver: a small bulb far from the origin keeps its shape.
    let centre = l.position - p;
    let Some(disk) = crate::light::Silhouette::new(centre, radius, Vec3::ZERO) else {
        return match l.irradiance(p, n) {
            e if e == Vec3::ZERO => e,
            e => e * visible(ShadowTarget::Point(l.position)),
        };
    };
    let inc = l.incident(p);
    let (cos, sin) = (n.dot(inc.to_light), radius / inc.distance);
    if cos <= -sin || inc.irradiance == Vec3::ZERO {
        return Vec3::ZERO;
    }
    // Where the receiver's plane cuts the sphere, the parts are those of the silhouette's side
    // above the plane (made for this receiver), so that every ray goes where light comes from.
    let cut = cos < sin;
    let (_, unit_parts) = crate::light::unit_silhouette();
    let parts: Vec<Vec<Vec3>> = if cut {
        let lit = crate::form_factor::clip_above_plane(&disk.corners(), Vec3::ZERO, n);
        if lit.len() < 3 {
            return Vec3::ZERO;
        }
        crate::light::aperture_parts(&lit, crate::light::APERTURE_LEVELS)
    } else {
        Vec::new()
    };
    let count = if cut { parts.len() } else { unit_parts.len() };
    let part = |k: usize| -> std::borrow::Cow<[Vec3]> {
        if cut {
            std::borrow::Cow::Borrowed(&parts[k][..])
        } else {
            std::borrow::Cow::Owned(unit_parts[k].iter().map(|&c| disk.at(c)).collect())
        }
    };
    let mut weights = [0.0f32; AREA_SHADOW_RAYS as usize];
    for (k, w) in weights.iter_mut().enumerate().take(count) {
        let u = [receiver_hash(p, 2 * k as u32 + 1), receiver_hash(p, 2 * k as u32 + 2)];
        let q = if cut {
            crate::light::polygon_point(&parts[k], u)
        } else {
            disk.at(crate::light::polygon_point(&unit_parts[k], u))
        };
        // The disk lies inside the sphere: the ray ends where it meets the sphere's near
        // side, as light leaves it (geometry inside the ball does not shadow).
        let dir = q.normalize_or_zero();
        let b = dir.dot(centre);
        let along = b - (b * b - (centre.length_squared() - radius * radius)).max(0.0).sqrt();
        *w = visible(ShadowTarget::Point(p + dir * along));
    }
    let weights = &weights[..count];
    // Every ray weighed alike (all arrive, none, or all changed the same way): seen whole,
    // the exact light times that weight without a polygon (cut, `weighed_form_factor` says).
    let same = weights.iter().all(|w| *w == weights[0]).then_some(weights[0]);
    if same == Some(0.0) {
        return Vec3::ZERO;
    }
    if let (false, Some(w)) = (cut, same) {
        return inc.irradiance * (cos * w);
    }
    let whole = crate::form_factor::point_to_polygon(Vec3::ZERO, n, &disk.corners());
    if !(whole > 0.0) {
        return Vec3::ZERO;
    }
    let f = weighed_form_factor(
        weights,
        |k| crate::form_factor::point_to_polygon(Vec3::ZERO, n, &part(k)),
        || whole,
    );
    if cut {
        inc.irradiance * (f / (sin * sin))
    } else {
        inc.irradiance * (cos * f / whole)
    }
}

/// Power (W) `lights` deliver to the triangles `tris` (an entry's cell,
/// [`crate::prm_file::Cells`]): [`crate::cell_light::triangle_light`] with ray-traced
/// visibility. The runtime's CPU twin of its GPU entry pass.
pub fn cell_power(bvh: &Bvh, lights: &[crate::Light], tris: &[[Vec3; 3]]) -> Vec3 {
    tris.iter().map(|t| cell_triangle_light(bvh, lights, t).power).sum()
}

/// The light on one cell triangle ([`crate::cell_light::triangle_light`]), each visibility
/// test one shadow ray.
pub fn cell_triangle_light(
    bvh: &Bvh,
    lights: &[crate::Light],
    t: &[Vec3; 3],
) -> crate::cell_light::TriangleLight {
    crate::cell_light::triangle_light(t, lights, |y, n, l| {
        let seen = if l.is_positional() {
            bvh.visible_point(y, n, l.position)
        } else {
            bvh.visible_dir(y, n, -l.direction)
        };
        seen as u8 as f32
    })
}

/// Möller-Trumbore ray/triangle test, both faces: `(t, u, v)` when `tmin < t < tmax`.
#[inline(always)]
fn intersect(tri: &BvhTriangle, ray: &Ray) -> Option<(f32, f32, f32)> {
    let e1: Vec3A = tri.v1 - tri.v0;
    let e2: Vec3A = tri.v2 - tri.v0;
    let p = ray.direction.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.origin - tri.v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.direction.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > ray.tmin && t < ray.tmax).then_some((t, u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` closed cubes of side 3 (faces inward), 1 apart along x.
    fn cubes(n: usize) -> Scene {
        let mut pos = Vec::new();
        for r in 0..n {
            let o = Vec3::new(4.0 * r as f32, 0.0, 0.0);
            let v = |x: f32, y: f32, z: f32| o + Vec3::new(x, y, z) * 3.0;
            let mut quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| pos.extend([a, b, c, a, c, d]);
            quad(v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.));
            quad(v(0., 1., 0.), v(1., 1., 0.), v(1., 1., 1.), v(0., 1., 1.));
            quad(v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.));
            quad(v(1., 0., 1.), v(0., 0., 1.), v(0., 1., 1.), v(1., 1., 1.));
            quad(v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.));
            quad(v(1., 0., 0.), v(1., 0., 1.), v(1., 1., 1.), v(1., 1., 0.));
        }
        let idx: Vec<u32> = (0..pos.len() as u32).collect();
        let uv = vec![glam::Vec2::ZERO; pos.len()];
        Scene::from_mesh(pos, uv, &idx)
    }

    /// The rooms' trees answer rays inside their rooms themselves (the fallback to the level's
    /// tree would hide a tree that never answers), axis-aligned ones with -0 components too.
    #[test]
    fn rays_in_a_room_are_answered_by_its_own_tree() {
        let scene = cubes(4);
        let bvh = Bvh::build(&scene);
        bvh.localise(&scene, &crate::rooms::Rooms::of_scene(&scene));
        assert!(bvh.is_localised());
        assert_eq!(bvh.local_regions(), 4);
        let local = bvh.local.get().and_then(Option::as_ref).expect("trees made above");
        let mut dirs: Vec<Vec3> = Vec::new();
        for k in 0..64 {
            let z = 1.0 - 2.0 * (k as f32 + 0.5) / 64.0;
            let (r, phi) = ((1.0 - z * z).sqrt(), 2.4 * k as f32);
            dirs.push(Vec3::new(r * phi.cos(), r * phi.sin(), z));
        }
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            // Both signs, and the other components -0.
            dirs.push(axis - Vec3::ONE * 0.0 * -1.0);
            dirs.push(-axis);
        }
        assert!(dirs.iter().any(|d| d.to_array().iter().any(|c| *c == 0.0 && c.is_sign_negative())));
        for r in 0..4 {
            // Off the quads' diagonals, where two triangles tie.
            let o = Vec3::new(4.0 * r as f32 + 1.3, 1.6, 1.1);
            let region = local.region_at(o).expect("a room's middle has its tree");
            for &d in &dirs {
                let inside = region.exit(o, d);
                let own = bvh.closest_in(&region.tree, o, d, inside);
                assert!(own.is_some(), "room {r}: a ray along {d} left its room's tree to the level's");
                assert_eq!(own, bvh.closest_hit_brute_force(o, d, f32::INFINITY), "room {r} along {d}");
                assert_eq!(own, bvh.closest_hit(o, d, f32::INFINITY));
            }
            // A NaN length finds nothing, as in the level's tree.
            assert_eq!(bvh.closest_hit(o, Vec3::X, f32::NAN), None);
            assert!(!bvh.occluded(o, Vec3::X, f32::NAN));
        }
    }
}
