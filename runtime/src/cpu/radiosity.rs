//! Hierarchical radiosity with clustering on the lightmap atlas, over precomputed visibility
//! (paper 003 §4.1-4.5), on the CPU: the twin a GPU version is to be held to.
//!
//! - **Hierarchy** (§4.2), built once per object from its texels at rest: a binary median-cut
//!   tree (split at the median of the longest axis of the points' box), each node with a
//!   bounding sphere over its texels' points (widened by their size), its area, the area-
//!   weighted sum of its normals and the range of its leaves. Stored depth first in one array
//!   with a skip pointer per node (§4.2.1): a node's left child is the next entry, and `skip`
//!   is where traversal goes when the subtree is not entered. The objects' trees follow one
//!   another, so one stackless walk covers the level; nodes move with their object's pose.
//! - **Gather** (§4.3): each receiver texel walks the trees; the oracle refines a node when
//!   the receiver is within twice its radius or when the node's flux could bring more than
//!   `threshold` times the level's mean exitance (upper bound `Φ / (π (d - r)²)`, lightcuts'
//!   bound without its cosine terms); otherwise the node sends
//!   `Φ max(0, u·m) max(0, -u·n_r) / (π d²)` (m: the mean normal, shorter where the node's
//!   normals disagree), a single texel `B A cos cos / (π d²)`, or within 3 texel sizes
//!   `Φ F / a` with `F` the exact form factor of the texel's shape (its atlas square clipped
//!   to its chart's border, mapped onto its triangle's plane, of area `a`: Lambert's contour integral, clipped to the
//!   receiver's side; a texel's point, often clamped onto a chart's edge, stands for it poorly
//!   at a corner; in the first bounce, the shape's parts each with their own share of the
//!   direct light, [`SenderLight`]), times visibility to a representative texel of the node.
//! - **Bounces** (§4.1): `E_1` gathers `albedo x E_direct`, `E_k+1` gathers `albedo x E_k`;
//!   the indirect lightmap is `E_1 + ... + E_n`, plus the bounces not taken as the rest of a
//!   geometric series at the last pass's power ratio (`E_n k / (1 - k)`). Each pass is scaled
//!   to deliver the power it was sent less what escapes the level (power conservation: the
//!   cut and the point-sampled texels lose a few per cent a bounce, which compounds). The final pass is the final gather (§4.4) with
//!   **jittering** (§4.5): its representative texel is drawn per receiver and node from the
//!   node's leaves (a hash, so frames are deterministic), so the cut's discretisation becomes
//!   noise instead of bands. The earlier passes use each node's middle leaf.
//!
//! Visibility between a receiver and a sender comes from [`prm::visibility::Visibility`]: the
//! CSSM of each end's object, the occluder maps of the other movables.

use glam::{Mat3, Vec3};
use prm::visibility::{Poses, Visibility};
use prm::{Scene, TexelSet};
use rayon::prelude::*;

/// How finely the gather refines.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadiosityParams {
    /// Diffuse bounces of indirect light (the last is the final gather). Default 6, and the rest estimated (`tail`).
    pub bounces: u32,
    /// Refinement threshold relative to the level's mean exitance (smaller: larger cuts,
    /// slower, more exact). Default 0.02.
    pub threshold: f32,
    /// Jitter the final gather's representative texels (§4.5). Default on.
    pub jitter: bool,
    /// Add the bounces not taken as the rest of a geometric series, at the power ratio of
    /// the last two passes (a closed level keeps about its mean albedo each bounce). Default on.
    pub tail: bool,
    /// Scale each pass's light so that the power it delivers is the power sent less the share
    /// escaping the level (`Visibility::escape`): the cut's approximations and the texels'
    /// point sampling lose a few per cent a bounce, which compounds over bounces. At most
    /// [`MAX_CONSERVE`]. Default on.
    pub conserve: bool,
}

pub use crate::radiosity::MAX_CONSERVE;

impl Default for RadiosityParams {
    fn default() -> Self {
        RadiosityParams { bounces: 6, threshold: 0.02, jitter: true, tail: true, conserve: true }
    }
}

/// One node of the hierarchy (module doc), in its object's rest frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    pub centre: Vec3,
    pub radius: f32,
    /// Area-weighted sum of the texels' normals, divided by the area (|m| <= 1).
    pub normal: Vec3,
    pub area: f32,
    pub object: u32,
    /// Leaves `first..end` of [`Hierarchy::leaves`] are this node's texels.
    pub first: u32,
    pub end: u32,
    /// Next node when this subtree is skipped (`u32::MAX`: the walk ends).
    pub skip: u32,
}

impl Node {
    pub fn is_leaf(&self) -> bool {
        self.end - self.first == 1
    }
}

/// The texel hierarchy of a level (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct Hierarchy {
    pub nodes: Vec<Node>,
    /// Texel indices in leaf order.
    pub leaves: Vec<u32>,
    /// Per texel: its area (square metres) and albedo.
    pub area: Vec<f32>,
    pub albedo: Vec<Vec3>,
    /// Per texel: its atlas square clipped to its chart's border, mapped onto its triangle's
    /// plane (rest frame): the shape it sends with up close (planar charts: they tile it).
    pub shapes: Vec<Shape>,
}

/// A convex polygon of up to 7 vertices (a square clipped by a triangle) and its area.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    pub points: [Vec3; 7],
    pub len: u8,
    /// Square metres.
    pub area: f32,
}

impl Shape {
    pub fn vertices(&self) -> &[Vec3] {
        &self.points[..self.len as usize]
    }
}

/// Texel `t`'s atlas square clipped to its chart (the edges of its triangle that no other
/// triangle shares in the atlas: `boundary[k]` for edge k -> k + 1), mapped onto the triangle.
/// Not the whole square: where a chart ends at a hole (a door's opening under its lintel) the
/// square's far part would hang over nothing and send light from there. Edges inside a chart
/// (a wall's diagonal) are not cut: the squares tile the chart.
fn texel_shape(scene: &Scene, texels: &TexelSet, t: &prm::Texel, boundary: [bool; 3]) -> Shape {
    let tri = t.triangle as usize;
    let size = glam::Vec2::new(texels.width as f32, texels.height as f32);
    let [a, b, c] = scene.corners(tri);
    let uv = scene.uv1_corners(tri).map(|u| u * size);
    let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = e1.perp_dot(e2);
    let point = Shape { points: [t.position; 7], len: 1, area: 0.0 };
    if !(det.abs() > 1e-12) {
        return point;
    }
    let (i, j) = (t.i as f32, t.j as f32);
    let mut poly: Vec<glam::Vec2> =
        [(i, j), (i + 1.0, j), (i + 1.0, j + 1.0), (i, j + 1.0)].map(|(x, y)| glam::Vec2::new(x, y)).to_vec();
    // Sutherland-Hodgman against the triangle's three edges, inside = same side as the third
    // corner.
    for k in (0..3).filter(|&k| boundary[k]) {
        let (p, q, r) = (uv[k], uv[(k + 1) % 3], uv[(k + 2) % 3]);
        let side = |x: glam::Vec2| (q - p).perp_dot(x - p) * (q - p).perp_dot(r - p).signum();
        let mut out = Vec::with_capacity(poly.len() + 1);
        for m in 0..poly.len() {
            let (u, v) = (poly[m], poly[(m + 1) % poly.len()]);
            let (du, dv) = (side(u), side(v));
            if du >= 0.0 {
                out.push(u);
            }
            if (du >= 0.0) != (dv >= 0.0) {
                out.push(u + (v - u) * (du / (du - dv)));
            }
        }
        poly = out;
        if poly.len() < 3 {
            return point;
        }
    }
    let to_world = |q: glam::Vec2| {
        let d = q - uv[0];
        let (s, r) = (d.perp_dot(e2) / det, e1.perp_dot(d) / det);
        a + (b - a) * s + (c - a) * r
    };
    let mut shape = point;
    shape.len = poly.len().min(7) as u8;
    for (k, q) in poly.iter().take(7).enumerate() {
        shape.points[k] = to_world(*q);
    }
    let v = shape.vertices();
    shape.area = 0.5 * (1..v.len() - 1).map(|k| (v[k] - v[0]).cross(v[k + 1] - v[0])).sum::<Vec3>().length();
    shape
}

impl Hierarchy {
    /// Build the trees of every object of `scene` over `texels` (at rest).
    pub fn build(scene: &Scene, texels: &TexelSet) -> Hierarchy {
        // Without a shape (a texel on a sliver), an equal share of its triangle.
        let mut owned = vec![0u32; scene.triangles.len()];
        for t in &texels.texels {
            owned[t.triangle as usize] += 1;
        }
        let area: Vec<f32> = texels
            .texels
            .iter()
            .map(|t| scene.area(t.triangle as usize) / owned[t.triangle as usize] as f32)
            .collect();
        let albedo = texels.texels.iter().map(|t| scene.albedo(t.triangle as usize, t.bary)).collect();
        // Atlas edges used by two triangles are inside a chart.
        let key = |a: glam::Vec2, b: glam::Vec2| {
            let (a, b) = ((a.x.to_bits(), a.y.to_bits()), (b.x.to_bits(), b.y.to_bits()));
            if a <= b {
                (a, b)
            } else {
                (b, a)
            }
        };
        let mut uses = std::collections::HashMap::new();
        for t in 0..scene.triangles.len() {
            let uv = scene.uv1_corners(t);
            for k in 0..3 {
                *uses.entry(key(uv[k], uv[(k + 1) % 3])).or_insert(0u32) += 1;
            }
        }
        let shapes: Vec<Shape> = texels
            .texels
            .iter()
            .map(|t| {
                let uv = scene.uv1_corners(t.triangle as usize);
                let boundary = [0, 1, 2].map(|k| uses[&key(uv[k], uv[(k + 1) % 3])] < 2);
                texel_shape(scene, texels, t, boundary)
            })
            .collect();
        // A texel's area is its shape's: the shapes tile the surface.
        let area: Vec<f32> =
            area.iter().zip(&shapes).map(|(a, s)| if s.area > 0.0 { s.area } else { *a }).collect();
        let mut h = Hierarchy { nodes: Vec::new(), leaves: Vec::new(), area, albedo, shapes };
        for o in 0..=scene.movables.len() as u32 {
            let mut ids: Vec<u32> = (0..texels.len() as u32)
                .filter(|&t| scene.object(texels.texels[t as usize].triangle as usize) == o)
                .collect();
            if ids.is_empty() {
                continue;
            }
            let root = h.nodes.len();
            h.split(texels, o, &mut ids);
            // Each object's root skips to the next object's root (patched below).
            h.nodes[root].skip = u32::MAX;
            if root > 0 {
                let mut k = 0;
                while h.nodes[k].skip != u32::MAX {
                    k = h.nodes[k].skip as usize;
                }
                h.nodes[k].skip = root as u32;
            }
        }
        h
    }

    /// Append the subtree over `ids` depth first; returns nothing, patches skip pointers.
    fn split(&mut self, texels: &TexelSet, object: u32, ids: &mut [u32]) {
        let at = self.nodes.len();
        let first = self.leaves.len() as u32;
        let pos = |t: u32| texels.texels[t as usize].position;
        let (lo, hi) = ids
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &t| (lo.min(pos(t)), hi.max(pos(t))));
        let area: f32 = ids.iter().map(|&t| self.area[t as usize]).sum();
        let centre = (lo + hi) * 0.5;
        let radius = ids
            .iter()
            .map(|&t| (pos(t) - centre).length() + self.area[t as usize].sqrt() * 0.71)
            .fold(0.0f32, f32::max);
        let normal =
            ids.iter().map(|&t| texels.texels[t as usize].normal * self.area[t as usize]).sum::<Vec3>()
                / area.max(1e-30);
        self.nodes.push(Node { centre, radius, normal, area, object, first, end: first, skip: u32::MAX });
        if ids.len() == 1 {
            self.leaves.push(ids[0]);
        } else {
            let axis = (hi - lo).max_position();
            let mid = ids.len() / 2;
            ids.select_nth_unstable_by(mid, |&a, &b| pos(a)[axis].total_cmp(&pos(b)[axis]).then(a.cmp(&b)));
            let (left, right) = ids.split_at_mut(mid);
            let left_at = self.nodes.len();
            self.split(texels, object, left);
            let right_at = self.nodes.len();
            self.nodes[left_at].skip = right_at as u32;
            self.split(texels, object, right);
        }
        let end = self.leaves.len() as u32;
        self.nodes[at].end = end;
        // A right child's skip is its parent's, set by the caller's caller; fix the chain:
        // every node whose skip is unset inside this subtree continues after it.
        let after = self.nodes.len() as u32;
        for n in &mut self.nodes[at + 1..] {
            if n.skip == u32::MAX {
                n.skip = after;
            }
        }
    }
}

/// Visibility between two texels at their current positions `pr` and `ps`, in [0, 1].
pub trait PairVisibility: Sync {
    fn between(&self, poses: &Poses, r: usize, pr: Vec3, s: usize, ps: Vec3) -> f32;
}

/// The precomputed answer (paper 003 §3): CSSMs and occluder maps.
impl PairVisibility for Visibility {
    fn between(&self, poses: &Poses, r: usize, pr: Vec3, s: usize, ps: Vec3) -> f32 {
        Visibility::between(self, poses, r, pr, s, ps)
    }
}

/// The exact answer the precomputed one approximates: a shadow ray through the posed level
/// between the texels' points, each lifted off its surface (the twin for tests and reports).
pub struct RayVisibility<'a> {
    /// BVH of the level under the frame's poses.
    pub bvh: &'a prm::Bvh,
    /// Texel positions and normals under the poses ([`posed_points`]).
    pub points: &'a [(Vec3, Vec3)],
}

impl PairVisibility for RayVisibility<'_> {
    fn between(&self, _: &Poses, r: usize, _: Vec3, s: usize, _: Vec3) -> f32 {
        let ((pr, nr), (ps, ns)) = (self.points[r], self.points[s]);
        self.bvh.visible(pr, nr, ps, ns) as u32 as f32
    }
}

/// One frame's inputs: where every texel is, and the objects' poses.
pub struct Frame<'a> {
    pub poses: &'a Poses,
    /// Texel positions and unit normals under the poses.
    pub points: &'a [(Vec3, Vec3)],
}

/// Texel positions and normals under `poses` (texels at rest in `texels`).
pub fn posed_points(scene: &Scene, texels: &TexelSet, poses: &Poses) -> Vec<(Vec3, Vec3)> {
    poses.texel_points(scene, &texels.texels)
}

/// The direct light the texels send with: per texel its mean over its shape, and how that
/// divides over the shape's parts, the triangles from its centroid to each edge. The first
/// bounce's near field sends by parts: a lamp 15 cm from a corner lights one side of a texel
/// twice as brightly as the other, and the texels beside it, a few cm away, see mostly one
/// side (the corner lamp: 12 % -> 4.6 % against the ground truth).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SenderLight {
    /// Direct irradiance per texel, the mean over its shape (W/m²).
    pub mean: Vec<Vec3>,
    /// Per texel, part `i` (centroid, vertex `i`, vertex `i + 1`): its mean irradiance over
    /// the texel's, in luminance (area-weighted, they average to 1); 1 where unknown.
    pub parts: Vec<[f32; 7]>,
}

impl SenderLight {
    /// `mean` spread evenly over each texel's shape.
    pub fn uniform(mean: Vec<Vec3>) -> SenderLight {
        SenderLight { parts: vec![[1.0; 7]; mean.len()], mean }
    }
}

/// The direct light each texel *sends* with ([`SenderLight`]), in the posed level. For
/// point, spot and directional lights the unshadowed part is exact at any distance: the power
/// the light delivers to each part of the shape (`prm::Light::triangle_power`) over its area;
/// it is scaled by the shape's visible share, the irradiance-weighted mean of shadow rays from
/// its centroid and the points halfway from it to each vertex. Area lights: the mean of the
/// shadowed irradiance at those points, the same on every part. A texel without a shape: its
/// point's irradiance. The lightmap's receivers stay points.
pub fn sender_direct(
    scene: &Scene,
    texels: &TexelSet,
    h: &Hierarchy,
    frame: &Frame,
    bvh: &prm::Bvh,
    lights: &[prm::Light],
) -> SenderLight {
    let (mean, parts) = texels
        .texels
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            let shape = &h.shapes[k];
            let normal = frame.points[k].1;
            if shape.len < 3 || !(shape.area > 0.0) {
                return (prm::bvh::direct_irradiance(bvh, lights, frame.points[k].0, normal), [1.0; 7]);
            }
            let pose = frame.poses.to_world[scene.object(t.triangle as usize) as usize];
            let v: Vec<Vec3> = shape.vertices().iter().map(|p| pose.transform_point3(*p)).collect();
            let c = v.iter().sum::<Vec3>() / v.len() as f32;
            let parts: Vec<[Vec3; 3]> = (0..v.len())
                .map(|i| {
                    let tri = [c, v[i], v[(i + 1) % v.len()]];
                    // Counter-clockwise seen from the front, as triangle_power wants.
                    if (tri[1] - tri[0]).cross(tri[2] - tri[0]).dot(normal) < 0.0 {
                        [tri[0], tri[2], tri[1]]
                    } else {
                        tri
                    }
                })
                .collect();
            let samples: Vec<Vec3> = std::iter::once(c).chain(v.iter().map(|p| c.lerp(*p, 0.5))).collect();
            // Power on each part (W), and spread evenly (W/m²).
            let mut power = [Vec3::ZERO; 7];
            let mut even = Vec3::ZERO;
            for l in lights {
                if l.is_area() {
                    let one = std::slice::from_ref(l);
                    let e: Vec3 =
                        samples.iter().map(|&p| prm::bvh::direct_irradiance(bvh, one, p, normal)).sum();
                    even += e / samples.len() as f32;
                    continue;
                }
                let each: Vec<Vec3> = parts.iter().map(|tri| l.triangle_power(tri)).collect();
                if each.iter().all(|p| *p == Vec3::ZERO) {
                    continue;
                }
                let (mut seen, mut total) = (0.0f32, 0.0f32);
                for &p in &samples {
                    let inc = l.incident(p);
                    let w = prm::luminance(inc.irradiance) * normal.dot(inc.to_light);
                    if !(w > 0.0) {
                        continue;
                    }
                    total += w;
                    let visible = if l.is_positional() {
                        bvh.visible_point(p, normal, l.position)
                    } else {
                        bvh.visible_dir(p, normal, inc.to_light)
                    };
                    if visible {
                        seen += w;
                    }
                }
                if total > 0.0 {
                    for (sum, p) in power.iter_mut().zip(&each) {
                        *sum += *p * (seen / total);
                    }
                }
            }
            let mean = power.iter().sum::<Vec3>() / shape.area + even;
            let mut ratio = [1.0f32; 7];
            let m = prm::luminance(mean);
            if m > 0.0 {
                for (i, tri) in parts.iter().enumerate() {
                    let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
                    if area > 0.0 {
                        ratio[i] = prm::luminance(power[i] / area + even) / m;
                    }
                }
            }
            (mean, ratio)
        })
        .unzip();
    SenderLight { mean, parts }
}

/// What a frame's radiosity did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RadiosityStats {
    /// Node transfers (the cuts' sizes) over all receivers and passes.
    pub transfers: u64,
    /// Visibility queries.
    pub queries: u64,
}

/// The indirect irradiance at every texel from the direct light `light` (module doc).
pub fn indirect(
    h: &Hierarchy,
    vis: &impl PairVisibility,
    frame: &Frame,
    light: &SenderLight,
    params: &RadiosityParams,
    escape: &[f32],
) -> (Vec<Vec3>, RadiosityStats) {
    let direct = &light.mean;
    let mut total = vec![Vec3::ZERO; direct.len()];
    let mut stats = RadiosityStats::default();
    let mut from = direct.to_vec();
    let power = |e: &[Vec3]| -> f64 {
        e.iter().zip(&h.area).zip(&h.albedo).map(|((e, a), r)| (prm::luminance(*e * *r) * a) as f64).sum()
    };
    let mut decay = 0.0f64;
    for pass in 0..params.bounces {
        let exitance: Vec<Vec3> = from.iter().zip(&h.albedo).map(|(e, a)| *e * *a).collect();
        let jitter = params.jitter && pass + 1 == params.bounces;
        let parts = (pass == 0 && light.parts.len() == direct.len()).then_some(&light.parts[..]);
        let (mut gathered, s) = gather(h, vis, frame, &exitance, parts, params.threshold, jitter);
        if params.conserve {
            let sent: f64 = exitance
                .iter()
                .zip(&h.area)
                .zip(escape)
                .map(|((b, a), e)| (prm::luminance(*b) * a * (1.0 - e)) as f64)
                .sum();
            let got: f64 = gathered.iter().zip(&h.area).map(|(g, a)| (prm::luminance(*g) * a) as f64).sum();
            let scale = conserve_scale(sent, got);
            for g in &mut gathered {
                *g *= scale;
            }
        }
        stats.transfers += s.transfers;
        stats.queries += s.queries;
        for (t, g) in total.iter_mut().zip(&gathered) {
            *t += *g;
        }
        let (before, after) = (power(&from), power(&gathered));
        decay = if before > 0.0 { after / before } else { 0.0 };
        from = gathered;
    }
    // The bounces not taken: each pass so far kept `decay` of the reflected power, and the
    // rest of the geometric series, shaped like the last pass, is `last x k / (1 - k)`.
    if params.tail && params.bounces > 1 {
        let k = decay.clamp(0.0, 0.95) as f32;
        for (t, g) in total.iter_mut().zip(&from) {
            *t += *g * (k / (1.0 - k));
        }
    }
    (total, stats)
}

/// The factor that makes a pass deliver `sent` instead of `got`, within [1, MAX_CONSERVE]
/// (never darker: a pass that delivers more than was sent is left alone).
pub fn conserve_scale(sent: f64, got: f64) -> f32 {
    if got > 0.0 {
        ((sent / got) as f32).clamp(1.0, MAX_CONSERVE)
    } else {
        1.0
    }
}

/// One pass: irradiance at every texel from exitance `b` (W/m²) at every texel; with
/// `parts` ([`SenderLight::parts`]), a texel in the near field sends by its shape's parts.
pub fn gather(
    h: &Hierarchy,
    vis: &impl PairVisibility,
    frame: &Frame,
    b: &[Vec3],
    parts: Option<&[[f32; 7]]>,
    threshold: f32,
    jitter: bool,
) -> (Vec<Vec3>, RadiosityStats) {
    // Pull (§4.1): node flux from the leaves; leaves are contiguous per node.
    // In f64: a node's flux is a difference of prefix sums over the whole level.
    let mut prefix = vec![glam::DVec3::ZERO; h.leaves.len() + 1];
    for (k, &t) in h.leaves.iter().enumerate() {
        prefix[k + 1] = prefix[k] + (b[t as usize] * h.area[t as usize]).as_dvec3();
    }
    let flux: Vec<Vec3> =
        h.nodes.iter().map(|n| (prefix[n.end as usize] - prefix[n.first as usize]).as_vec3()).collect();
    let total_area: f32 = h.area.iter().sum();
    let mean = prm::luminance(prefix[h.leaves.len()].as_vec3()) / total_area.max(1e-30);
    if !(mean > 0.0) {
        return (vec![Vec3::ZERO; b.len()], RadiosityStats::default());
    }
    let bound = threshold * mean * std::f32::consts::PI;
    let rot: Vec<Mat3> = frame.poses.to_world.iter().map(|m| Mat3::from_mat4(*m)).collect();
    let results: Vec<(Vec3, u64, u64)> = (0..b.len())
        .into_par_iter()
        .map(|r| {
            let (x, nr) = frame.points[r];
            let (mut e, mut transfers, mut queries) = (Vec3::ZERO, 0u64, 0u64);
            let mut k = 0u32;
            while (k as usize) < h.nodes.len() {
                let n = &h.nodes[k as usize];
                let phi = flux[k as usize];
                if phi == Vec3::ZERO {
                    k = n.skip;
                    continue;
                }
                let pose = frame.poses.to_world[n.object as usize];
                let c = pose.transform_point3(n.centre);
                let d = (x - c).length();
                let refine = !n.is_leaf()
                    && (d < 2.0 * n.radius || prm::luminance(phi) > bound * (d - n.radius).powi(2));
                if refine {
                    k += 1;
                    continue;
                }
                let here = k;
                k = n.skip;
                let leaf = if n.is_leaf() {
                    n.first
                } else if jitter {
                    n.first + (hash(r as u32, here) % (n.end - n.first))
                } else {
                    (n.first + n.end) / 2
                };
                let s = h.leaves[leaf as usize] as usize;
                if s == r {
                    continue;
                }
                let (ps, ns) = frame.points[s];
                let (from, m) = if n.is_leaf() { (ps, ns) } else { (c, rot[n.object as usize] * n.normal) };
                let v = from - x;
                let d2 = v.length_squared();
                if !(d2 > 0.0) {
                    continue;
                }
                let u = v / d2.sqrt();
                let (cos_r, cos_s) = (u.dot(nr), -u.dot(m));
                if cos_r <= 0.0 || cos_s <= 0.0 {
                    continue;
                }
                let g = if n.is_leaf() && d2 < NEAR * NEAR * n.area {
                    // Near a texel its point is a poor stand-in: its shape (module doc) by
                    // Lambert's contour integral, clipped to the receiver's side (a corner's
                    // other wall); its flux spread over the shape, or over its parts as the
                    // direct light fell on them (the first bounce).
                    let pose = frame.poses.to_world[n.object as usize];
                    let shape = &h.shapes[s];
                    if shape.area <= 0.0 {
                        continue;
                    }
                    let square: Vec<Vec3> =
                        shape.vertices().iter().map(|q| pose.transform_point3(*q)).collect();
                    let f = match parts {
                        Some(parts) => {
                            let c = square.iter().sum::<Vec3>() / square.len() as f32;
                            (0..square.len())
                                .map(|i| {
                                    let tri = [c, square[i], square[(i + 1) % square.len()]];
                                    parts[s][i] * prm::form_factor::point_to_polygon(x, nr, &tri)
                                })
                                .sum()
                        }
                        None => prm::form_factor::point_to_polygon(x, nr, &square),
                    };
                    if f <= 0.0 {
                        continue;
                    }
                    f / shape.area
                } else {
                    cos_r * cos_s / (std::f32::consts::PI * d2)
                };
                transfers += 1;
                queries += 1;
                let vis_rs = vis.between(frame.poses, r, x, s, ps);
                e += phi * g * vis_rs;
            }
            (e, transfers, queries)
        })
        .collect();
    let mut stats = RadiosityStats::default();
    let e = results
        .iter()
        .map(|&(e, t, q)| {
            stats.transfers += t;
            stats.queries += q;
            e
        })
        .collect();
    (e, stats)
}

pub use crate::radiosity::NEAR;

/// A small integer hash (jittered representatives).
fn hash(a: u32, b: u32) -> u32 {
    let mut h = a.wrapping_mul(0x9E37_79B1) ^ b.wrapping_mul(0x85EB_CA77);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    h
}
