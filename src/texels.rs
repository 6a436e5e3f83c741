//! The lightmap texel set: the exit points of DESIGN.md §3 (paper 000 §4's missed-texel problem).
//!
//! Layout: a W x H atlas over `TEXCOORD_1`; texel (i, j) covers the square
//! `u in [i, i+1]/W, v in [j, j+1]/H`, its centre is `((i+0.5)/W, (j+0.5)/H)`, row j = 0 is
//! v = 0 (glTF's top row and EXR's first row).
//!
//! **Coverage is exact.** A texel is covered when some triangle's UV image overlaps its square
//! with positive area (separating-axis test, overlap above 1e-7 texel). Rasterising texel
//! centres would miss slivers and tiny triangles that cover no centre; conservative
//! rasterisation on a GPU needs the paper's workaround. On the CPU we test the square directly,
//! so no texel is missed and none is invented.
//!
//! **Sample point.** The texel's point is its centre clamped into the owning triangle, the
//! owner being the triangle that contains the centre, else the nearest one (ties: first in scene
//! order). When the clamp lands on an edge (a barycentric below 1e-9), the point moves 0.01
//! texel toward the triangle's centroid: edges are often seams with another wall, and a point on
//! one lets rays leak through it (DESIGN.md §3). The normal is the owner's geometric normal.
//!
//! **Buried points** (`buried`): a sample point under something standing on its surface (a
//! texel half under a pillar) moves to the visible part of its texel, and a texel with no
//! visible part is dropped and filled like the gutter. Every estimator uses
//! [`TexelSet::build_visible`]; [`TexelSet::build`] alone is the geometric set.
//!
//! **Dilation.** Bilinear lookup at a point inside a triangle reads the 2x2 texels around it,
//! all within one texel (8-neighbourhood) of a covered texel. So every empty texel with a covered
//! 8-neighbour gets a [`Dilation`] entry: its value is the mean of its covered 4-neighbours, or
//! of its covered diagonal neighbours if it has no 4-neighbour. After [`TexelSet::dilate`],
//! bilinear sampling anywhere on the surface never reads an empty texel.

use glam::{DVec2, Vec3};
use rayon::prelude::*;

use crate::scene::Scene;

#[cfg(all(feature = "bvh", feature = "sampling"))]
mod buried;
mod smoothing;
#[cfg(all(feature = "bvh", feature = "sampling"))]
pub use buried::{is_buried, Burial, BURIAL_RAYS};
pub use smoothing::Smoothing;

/// Overlap (in texels) below which a triangle and a texel square are taken as only touching.
pub const COVERAGE_EPS: f64 = 1e-7;
/// How far (in texels) a sample point clamped onto an edge is pulled into the triangle.
pub const EDGE_PULL: f64 = 0.01;

/// One covered texel: an exit point.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Texel {
    /// Column.
    pub i: u32,
    /// Row (row 0 is v = 0).
    pub j: u32,
    /// World-space sample point on the owning triangle.
    pub position: Vec3,
    /// Unit geometric normal of the owning triangle (front face).
    pub normal: Vec3,
    /// Owning triangle (index into [`Scene::triangles`]).
    pub triangle: u32,
    /// Barycentrics of `position` in the owning triangle.
    pub bary: Vec3,
}

/// An empty texel next to covered ones, filled from them so bilinear lookups stay on the surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Dilation {
    /// Flat atlas index (`j * width + i`) of the empty texel.
    pub target: u32,
    /// Flat atlas indices of the covered texels it averages; `count` of them are used.
    pub sources: [u32; 4],
    pub count: u8,
}

/// The covered texels of an atlas, with the dilation ring around them.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TexelSet {
    pub width: u32,
    pub height: u32,
    /// Covered texels in row-major order.
    pub texels: Vec<Texel>,
    /// Per atlas texel: index into `texels`, or [`TexelSet::EMPTY`].
    pub index: Vec<u32>,
    /// Empty texels to fill after writing the covered ones.
    pub dilation: Vec<Dilation>,
    /// Triangles whose UV image has zero area: they own no texel.
    pub zero_uv_area_triangles: usize,
    /// Dilated texels whose sources lie in different UV charts (too little padding at this size).
    pub shared_gutter_texels: usize,
    /// What [`TexelSet::unbury`] moved and dropped (zero until it runs).
    #[cfg(all(feature = "bvh", feature = "sampling"))]
    pub buried: Burial,
    /// The atlas texels (row-major) whose centre [`TexelSet::unbury`] found buried, moved or
    /// dropped: where a texel may stand for surface inside a solid
    /// ([`TexelSet::visible_areas`]).
    #[cfg(all(feature = "bvh", feature = "sampling"))]
    #[serde(default)]
    pub buried_centres: Vec<u32>,
}

/// A candidate owner of a texel.
#[derive(Clone, Copy)]
struct Candidate {
    flat: u32,
    triangle: u32,
    distance: f64,
    bary: [f64; 3],
}

impl TexelSet {
    /// Marks an atlas texel that no triangle covers.
    pub const EMPTY: u32 = u32::MAX;

    /// Build the texel set of `scene` for a `width` x `height` atlas.
    pub fn build(scene: &Scene, width: u32, height: u32) -> TexelSet {
        assert!(width > 0 && height > 0, "atlas size must be positive");
        let size = DVec2::new(width as f64, height as f64);
        let per_triangle: Vec<(Vec<Candidate>, bool)> = (0..scene.triangles.len())
            .into_par_iter()
            .map(|t| {
                let uv = scene.uv1_corners(t).map(|v| v.as_dvec2() * size);
                if (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs() < 1e-12 {
                    return (Vec::new(), true);
                }
                (triangle_candidates(&uv, t as u32, width, height), false)
            })
            .collect();

        // Merge in scene order so the owner does not depend on thread count.
        let n = (width as usize) * (height as usize);
        let mut best: Vec<Option<Candidate>> = vec![None; n];
        let mut zero_uv_area_triangles = 0;
        for (cands, zero) in &per_triangle {
            zero_uv_area_triangles += *zero as usize;
            for c in cands {
                let slot = &mut best[c.flat as usize];
                match slot {
                    Some(b) if c.distance >= b.distance - 1e-12 => {}
                    _ => *slot = Some(*c),
                }
            }
        }
        drop(per_triangle);

        let mut index = vec![Self::EMPTY; n];
        let mut texels = Vec::new();
        for (flat, c) in best.iter().enumerate() {
            let Some(c) = c else { continue };
            index[flat] = texels.len() as u32;
            texels.push(make_texel(scene, c, size, width));
        }
        let mut set = TexelSet {
            width,
            height,
            texels,
            index,
            dilation: Vec::new(),
            zero_uv_area_triangles,
            shared_gutter_texels: 0,
            #[cfg(all(feature = "bvh", feature = "sampling"))]
            buried: Burial::default(),
            #[cfg(all(feature = "bvh", feature = "sampling"))]
            buried_centres: Vec::new(),
        };
        set.dilation = set.dilation_ring();
        set.shared_gutter_texels = set.count_shared_gutters(&crate::uv::charts(scene));
        set
    }

    /// Number of covered texels.
    pub fn len(&self) -> usize {
        self.texels.len()
    }

    /// True when no texel is covered.
    pub fn is_empty(&self) -> bool {
        self.texels.is_empty()
    }

    /// Per covered texel (in `texels` order), the world area of the surface it stands for:
    /// each triangle's part inside the texel's square of the atlas, at that triangle's world
    /// area per atlas area. A texel on a chart's edge holds only the part its charts cover;
    /// together they hold the area of every triangle with lightmap UVs of positive area (a
    /// part of a triangle in a texel another triangle won is that texel's too).
    pub fn covered_areas(&self, scene: &Scene) -> Vec<f32> {
        let size = DVec2::new(self.width as f64, self.height as f64);
        let mut area = vec![0.0f64; self.texels.len()];
        for t in 0..scene.triangles.len() {
            let uv = scene.uv1_corners(t).map(|v| v.as_dvec2() * size);
            let uv_area = 0.5 * (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs();
            if !(uv_area > 1e-12) {
                continue;
            }
            let per = scene.area(t) as f64 / uv_area;
            let (lo, hi) = (uv[0].min(uv[1]).min(uv[2]), uv[0].max(uv[1]).max(uv[2]));
            let range = |a: f64, b: f64, n: u32| (a.floor().max(0.0) as u32)..(b.ceil().min(n as f64) as u32);
            for j in range(lo.y, hi.y, self.height) {
                for i in range(lo.x, hi.x, self.width) {
                    let k = self.index[(j * self.width + i) as usize];
                    if k == Self::EMPTY {
                        continue;
                    }
                    let inside = clip_to_square(&uv, DVec2::new(i as f64, j as f64));
                    area[k as usize] += polygon_area(&inside) * per;
                }
            }
        }
        area.into_iter().map(|a| a as f32).collect()
    }

    /// Coverage mask per atlas texel (row-major).
    pub fn mask(&self) -> Vec<bool> {
        self.index.iter().map(|&k| k != Self::EMPTY).collect()
    }

    /// Scatter per-texel values into a full atlas image (empty texels get `empty`) and dilate.
    pub fn to_image<T: Copy + Dilatable>(&self, values: &[T], empty: T) -> Vec<T> {
        assert_eq!(values.len(), self.texels.len(), "one value per covered texel");
        let mut img = vec![empty; self.index.len()];
        for (t, v) in self.texels.iter().zip(values) {
            img[(t.j * self.width + t.i) as usize] = *v;
        }
        self.dilate(&mut img);
        img
    }

    /// Fill the dilation ring of a full atlas image from its covered texels.
    pub fn dilate<T: Copy + Dilatable>(&self, img: &mut [T]) {
        self.dilate_rows(img, 0, 0..self.height);
    }

    /// [`TexelSet::dilate`] on a window of whole atlas rows (`img` holds the rows from
    /// `first_row` on, row-major), filling only the targets in `rows`: their sources lie at
    /// most one row away, which the window must hold.
    pub fn dilate_rows<T: Copy + Dilatable>(
        &self,
        img: &mut [T],
        first_row: u32,
        rows: std::ops::Range<u32>,
    ) {
        self.dilate_rows_in(img, first_row, rows, 0..self.width);
    }

    /// [`TexelSet::dilate_rows`] for the targets in columns `cols` only (their sources lie at
    /// most one column outside).
    pub fn dilate_rows_in<T: Copy + Dilatable>(
        &self,
        img: &mut [T],
        first_row: u32,
        rows: std::ops::Range<u32>,
        cols: std::ops::Range<u32>,
    ) {
        let w = self.width as usize;
        let offset = first_row as usize * w;
        let cols = cols.start.min(self.width) as usize..cols.end.min(self.width) as usize;
        if cols.start >= cols.end {
            return;
        }
        for row in rows {
            let at = |x: usize| row as usize * w + x;
            let from = self.dilation.partition_point(|d| (d.target as usize) < at(cols.start));
            let to = self.dilation.partition_point(|d| (d.target as usize) < at(cols.end));
            for d in &self.dilation[from..to.max(from)] {
                let src = &d.sources[..d.count as usize];
                img[d.target as usize - offset] =
                    T::mean(src.iter().map(|&s| img[s as usize - offset]), src.len());
            }
        }
    }

    /// Side of one texel in scene units on triangle `t`: the square root of its world area per
    /// texel of its lightmap-UV area.
    pub fn world_texel_size(&self, scene: &Scene, t: usize) -> f32 {
        let uv = scene.uv1_corners(t);
        let texels =
            0.5 * ((uv[1] - uv[0]).perp_dot(uv[2] - uv[0])).abs() * (self.width as f32 * self.height as f32);
        (scene.area(t) / texels.max(1e-12)).sqrt()
    }

    fn dilation_ring(&self) -> Vec<Dilation> {
        let (w, h) = (self.width as i64, self.height as i64);
        let covered = |i: i64, j: i64| {
            i >= 0 && j >= 0 && i < w && j < h && self.index[(j * w + i) as usize] != Self::EMPTY
        };
        let mut out = Vec::new();
        for j in 0..h {
            for i in 0..w {
                if covered(i, j) {
                    continue;
                }
                let mut d = Dilation { target: (j * w + i) as u32, sources: [0; 4], count: 0 };
                for ring in [[(1, 0), (-1, 0), (0, 1), (0, -1)], [(1, 1), (-1, 1), (1, -1), (-1, -1)]] {
                    for (di, dj) in ring {
                        if covered(i + di, j + dj) {
                            d.sources[d.count as usize] = ((j + dj) * w + i + di) as u32;
                            d.count += 1;
                        }
                    }
                    if d.count > 0 {
                        out.push(d);
                        break;
                    }
                }
            }
        }
        out
    }

    fn count_shared_gutters(&self, chart: &[u32]) -> usize {
        self.dilation
            .iter()
            .filter(|d| {
                let ids: Vec<u32> = d.sources[..d.count as usize]
                    .iter()
                    .map(|&s| chart[self.texels[self.index[s as usize] as usize].triangle as usize])
                    .collect();
                ids.iter().any(|&c| c != ids[0])
            })
            .count()
    }
}

/// Values a dilated texel can be made of.
pub trait Dilatable: Sized {
    fn mean(values: impl Iterator<Item = Self>, count: usize) -> Self;
}

impl Dilatable for Vec3 {
    fn mean(values: impl Iterator<Item = Self>, count: usize) -> Self {
        values.fold(Vec3::ZERO, |a, b| a + b) / count as f32
    }
}

impl Dilatable for f32 {
    fn mean(values: impl Iterator<Item = Self>, count: usize) -> Self {
        values.sum::<f32>() / count as f32
    }
}

/// Every texel triangle `uv` (in texel units) overlaps, with its clamped centre.
fn triangle_candidates(uv: &[DVec2; 3], triangle: u32, width: u32, height: u32) -> Vec<Candidate> {
    let lo = uv[0].min(uv[1]).min(uv[2]);
    let hi = uv[0].max(uv[1]).max(uv[2]);
    let i0 = (lo.x.floor().max(0.0)) as i64;
    let j0 = (lo.y.floor().max(0.0)) as i64;
    let i1 = (hi.x.ceil() as i64).min(width as i64);
    let j1 = (hi.y.ceil() as i64).min(height as i64);
    let mut out = Vec::new();
    for j in j0..j1 {
        for i in i0..i1 {
            if !overlaps_square(uv, i as f64, j as f64) {
                continue;
            }
            let centre = DVec2::new(i as f64 + 0.5, j as f64 + 0.5);
            let bary = closest_barycentrics(centre, uv);
            let q = uv[0] * bary[0] + uv[1] * bary[1] + uv[2] * bary[2];
            out.push(Candidate {
                flat: (j as u32) * width + i as u32,
                triangle,
                distance: (q - centre).length(),
                bary,
            });
        }
    }
    out
}

/// Separating-axis test of triangle `t` against the unit square at (x0, y0), all in texels.
/// True when they overlap by more than [`COVERAGE_EPS`] along every axis.
pub fn overlaps_square(t: &[DVec2; 3], x0: f64, y0: f64) -> bool {
    let square = [
        DVec2::new(x0, y0),
        DVec2::new(x0 + 1.0, y0),
        DVec2::new(x0 + 1.0, y0 + 1.0),
        DVec2::new(x0, y0 + 1.0),
    ];
    let mut axes = [DVec2::X, DVec2::Y, DVec2::ZERO, DVec2::ZERO, DVec2::ZERO];
    for k in 0..3 {
        let e = t[(k + 1) % 3] - t[k];
        axes[2 + k] = DVec2::new(-e.y, e.x);
    }
    for a in axes {
        let len = a.length();
        if len == 0.0 {
            continue;
        }
        let a = a / len;
        let (pmin, pmax) = t
            .iter()
            .map(|p| p.dot(a))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), d| (l.min(d), h.max(d)));
        let (qmin, qmax) = square
            .iter()
            .map(|p| p.dot(a))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), d| (l.min(d), h.max(d)));
        if pmax <= qmin + COVERAGE_EPS || qmax <= pmin + COVERAGE_EPS {
            return false;
        }
    }
    true
}

/// Barycentrics of the point of 2D triangle `t` closest to `p`.
pub fn closest_barycentrics(p: DVec2, t: &[DVec2; 3]) -> [f64; 3] {
    let (a, b, c) = (t[0], t[1], t[2]);
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if den != 0.0 {
        let v = (d11 * v2.dot(v0) - d01 * v2.dot(v1)) / den;
        let w = (d00 * v2.dot(v1) - d01 * v2.dot(v0)) / den;
        if v >= 0.0 && w >= 0.0 && v + w <= 1.0 {
            return [1.0 - v - w, v, w];
        }
    }
    let mut best = (f64::INFINITY, [1.0, 0.0, 0.0]);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        let e = t[j] - t[i];
        let s = if e.length_squared() > 0.0 {
            ((p - t[i]).dot(e) / e.length_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = (t[i] + e * s - p).length();
        if d < best.0 {
            let mut bc = [0.0; 3];
            bc[i] = 1.0 - s;
            bc[j] = s;
            best = (d, bc);
        }
    }
    best.1
}

fn make_texel(scene: &Scene, c: &Candidate, size: DVec2, width: u32) -> Texel {
    let t = c.triangle as usize;
    let mut bc = c.bary;
    if bc.iter().cloned().fold(f64::INFINITY, f64::min) < 1e-9 {
        let uv = scene.uv1_corners(t).map(|v| v.as_dvec2() * size);
        let q = uv[0] * bc[0] + uv[1] * bc[1] + uv[2] * bc[2];
        let centroid = (uv[0] + uv[1] + uv[2]) / 3.0;
        let s = (EDGE_PULL / (centroid - q).length().max(1e-12)).min(0.5);
        bc = bc.map(|b| b * (1.0 - s) + s / 3.0);
    }
    let [a, b, cc] = scene.corners(t).map(|v| v.as_dvec3());
    let p = a * bc[0] + b * bc[1] + cc * bc[2];
    Texel {
        i: c.flat % width,
        j: c.flat / width,
        position: p.as_vec3(),
        normal: scene.face_normal(t),
        triangle: c.triangle,
        bary: Vec3::new(bc[0] as f32, bc[1] as f32, bc[2] as f32),
    }
}

/// Triangle `uv` clipped to the unit square at `corner` (Sutherland-Hodgman).
fn clip_to_square(uv: &[DVec2; 3], corner: DVec2) -> Vec<DVec2> {
    let mut poly = uv.to_vec();
    // (axis, bound, keep below): x >= x0, x <= x0 + 1, y >= y0, y <= y0 + 1.
    for (axis, bound, below) in
        [(0, corner.x, false), (0, corner.x + 1.0, true), (1, corner.y, false), (1, corner.y + 1.0, true)]
    {
        let inside = |p: DVec2| if below { p[axis] <= bound } else { p[axis] >= bound };
        let mut out = Vec::with_capacity(poly.len() + 2);
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            if inside(a) {
                out.push(a);
            }
            if inside(a) != inside(b) {
                let t = (bound - a[axis]) / (b[axis] - a[axis]);
                out.push(a + (b - a) * t);
            }
        }
        poly = out;
        if poly.is_empty() {
            break;
        }
    }
    poly
}

/// Area of a simple polygon (shoelace), either winding.
fn polygon_area(poly: &[DVec2]) -> f64 {
    let n = poly.len();
    (0..n).map(|k| poly[k].perp_dot(poly[(k + 1) % n])).sum::<f64>().abs() * 0.5
}
