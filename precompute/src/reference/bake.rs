//! The reference bake: virtual polygon and sphere lights for one fixed light setup, evaluated
//! at every texel (paper 000 §5-§6, DESIGN.md §6).
//!
//! Per real light (or photon source: an emissive mesh's polygon lights share one,
//! [`super::vpl::PhotonSource`]) and per bounce, separately (paper §7.1: bounces differ in
//! spatial frequency):
//! the VPLs are split into planar segments (RANSAC) and the rest; planar segments are clustered
//! with a 2D kd-tree and each cluster becomes a polygon light; the rest a 3D kd-tree and sphere
//! lights. A virtual light's power is the sum of its VPLs' power, exactly.
//!
//! Evaluation at a texel (p, n): direct light of the real lights with a shadow ray; for every
//! virtual light its analytic irradiance (form factor, epsilon shift of half a texel, point
//! fallback) times a soft visibility: the fraction of `visibility_samples` of its member VPLs
//! that the texel sees, the members drawn in proportion to their point-light kernel at the
//! texel. Ray-traced visibility replaces the paper's PCSS.
//! Sampling members rather than points of the polygon matters: a convex hull of floor VPLs can
//! span the foot of a block, and points there are hidden though no light is there (measured on
//! cornell: 4 % of the indirect light lost at 512 VPLs per light). Its error is the Monte Carlo
//! error of that fraction, which the ground-truth comparison includes.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{Vec2, Vec3};
use prm::{Bvh, Light, Scene, Texel, TexelSet};
use rand::Rng;
use rayon::prelude::*;

use super::form_factor::{PolygonLight, SphereLight};
use super::kdtree::cluster;
use super::planes::detect_planes;
use super::polygon::light_polygon;
use super::vpl::{one_source_per_light, trace_sources, PhotonBudget, PhotonSource, Vpl};
use crate::parallel::{par_texels, Cancelled, Control};
use crate::params::{require, require_atlas, ParamError};
use prm::sampling::stream;

/// Reference-bake parameters.
#[derive(Clone, Debug)]
pub struct BakeParams {
    /// Photons per real light.
    pub photons: usize,
    /// Bounces traced (1 = one indirect bounce).
    pub bounces: u32,
    /// VPLs per virtual light (the kd-trees' target leaf size) at the first bounce; it doubles
    /// with each further bounce.
    pub cluster_size: usize,
    /// Smallest planar segment, in VPLs.
    pub min_plane: usize,
    /// Shadow rays per texel and virtual light.
    pub visibility_samples: u32,
    pub atlas: prm::density::Atlas,
    pub seed: u64,
    /// Leave out the real lights' direct light.
    pub indirect_only: bool,
}

impl Default for BakeParams {
    fn default() -> Self {
        BakeParams {
            photons: 40_000,
            bounces: 12,
            cluster_size: 64,
            min_plane: 32,
            visibility_samples: 2,
            atlas: prm::density::Atlas::single(256),
            seed: 0,
            indirect_only: false,
        }
    }
}

impl BakeParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        require((1..=100_000_000).contains(&self.photons), "vpls", self.photons, "1 to 1e8")?;
        require((1..=64).contains(&self.bounces), "bounces", self.bounces, "1 to 64")?;
        require((1..=1_000_000).contains(&self.cluster_size), "cluster size", self.cluster_size, "1 to 1e6")?;
        require(
            (1..=256).contains(&self.visibility_samples),
            "visibility samples",
            self.visibility_samples,
            "1 to 256",
        )?;
        require_atlas(self.atlas)?;
        Ok(())
    }
}

/// A polygon light with the VPLs its visibility is sampled at (at most [`MAX_SAMPLES`]).
#[derive(Clone, Debug)]
pub struct PolygonCluster {
    pub light: PolygonLight,
    pub samples: Vec<(Vec3, Vec3)>,
}

/// Member VPLs kept per virtual light for visibility.
pub const MAX_SAMPLES: usize = 64;

/// Up to MAX_SAMPLES members, evenly strided (deterministic).
fn sample_members(members: impl ExactSizeIterator<Item = (Vec3, Vec3)>) -> Vec<(Vec3, Vec3)> {
    let n = members.len();
    let stride = n.div_ceil(MAX_SAMPLES).max(1);
    members.step_by(stride).collect()
}

/// A sphere light with the VPL positions its visibility is sampled at.
#[derive(Clone, Debug)]
pub struct SphereCluster {
    pub light: SphereLight,
    pub samples: Vec<(Vec3, Vec3)>,
}

/// All virtual lights and their accounting.
#[derive(Clone, Debug, Default)]
pub struct VirtualLights {
    pub polygons: Vec<PolygonCluster>,
    pub spheres: Vec<SphereCluster>,
    pub vpl_count: usize,
    /// Total VPL power and total virtual-light power (equal by construction).
    pub vpl_power: Vec3,
    pub light_power: Vec3,
    pub budgets: Vec<PhotonBudget>,
}

/// Photons, VPLs and virtual lights for `lights`, each light its own photon source.
pub fn virtual_lights(scene: &Scene, bvh: &Bvh, lights: &[Light], p: &BakeParams) -> VirtualLights {
    virtual_lights_of_sources(scene, bvh, lights, &one_source_per_light(lights.len()), p)
}

/// Photons, VPLs and virtual lights for `lights` shooting from `sources`
/// ([`super::vpl::trace_sources`]): `p.photons` a source, and a source's VPLs clustered
/// together.
pub fn virtual_lights_of_sources(
    scene: &Scene,
    bvh: &Bvh,
    lights: &[Light],
    sources: &[PhotonSource],
    p: &BakeParams,
) -> VirtualLights {
    let (vpls, budgets) = trace_sources(scene, bvh, lights, sources, p.photons, p.bounces, p.seed);
    let mut out = VirtualLights { vpl_count: vpls.len(), budgets, ..Default::default() };
    out.vpl_power = vpls.iter().fold(Vec3::ZERO, |a, v| a + v.power);
    let delta = 1e-4 * scene.diagonal().max(1e-30);
    let positions: Vec<Vec3> = vpls.iter().map(|v| v.position).collect();
    let normals: Vec<Vec3> = vpls.iter().map(|v| v.normal).collect();
    // Groups of one source and one bounce, in the order they first appear.
    let mut groups: Vec<((u32, u32), Vec<u32>)> = Vec::new();
    let mut group_of: std::collections::HashMap<(u32, u32), usize> = std::collections::HashMap::new();
    for (i, v) in vpls.iter().enumerate() {
        let key = (v.light, v.bounce);
        let g = *group_of.entry(key).or_insert_with(|| {
            groups.push((key, Vec::new()));
            groups.len() - 1
        });
        groups[g].1.push(i as u32);
    }
    let per_group: Vec<(Vec<PolygonCluster>, Vec<SphereCluster>)> = groups
        .par_iter()
        .map(|((light, bounce), members)| {
            let seed = p.seed ^ ((*light as u64) << 32 | *bounce as u64);
            let (planes, rest) =
                detect_planes(&positions, &normals, members, delta, p.min_plane.max(3), seed);
            let mut polys = Vec::new();
            for seg in &planes {
                let q: Vec<[f32; 2]> =
                    seg.members.iter().map(|&i| seg.project(positions[i as usize]).to_array()).collect();
                let (lo, hi) = q.iter().fold(([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]), |(l, h), x| {
                    ([l[0].min(x[0]), l[1].min(x[1])], [h[0].max(x[0]), h[1].max(x[1])])
                });
                // The root cell is the segment's own bounding box: the border growth closes
                // gaps between neighbouring lights but must not carry a light past the
                // surface's edge, where walls would hide it and its power would be lost.
                for leaf in cluster(&q, cluster_size(p.cluster_size, *bounce), lo, hi) {
                    let pts: Vec<Vec2> = leaf.members.iter().map(|&k| Vec2::from(q[k as usize])).collect();
                    let poly = light_polygon(&pts, Vec2::from(leaf.lo), Vec2::from(leaf.hi));
                    let power = leaf
                        .members
                        .iter()
                        .fold(Vec3::ZERO, |a, &k| a + vpls[seg.members[k as usize] as usize].power);
                    if poly.len() >= 3 {
                        let samples = sample_members(leaf.members.iter().map(|&k| {
                            let v = &vpls[seg.members[k as usize] as usize];
                            (v.position, v.normal)
                        }));
                        polys.push(PolygonCluster {
                            light: PolygonLight::new(
                                poly.iter().map(|v| seg.lift(*v)).collect(),
                                seg.normal,
                                power,
                            ),
                            samples,
                        });
                    }
                }
            }
            let mut spheres = Vec::new();
            if !rest.is_empty() {
                let q: Vec<[f32; 3]> = rest.iter().map(|&i| positions[i as usize].to_array()).collect();
                let (lo, hi) = q.iter().fold(([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]), |(l, h), x| {
                    (std::array::from_fn(|d| l[d].min(x[d])), std::array::from_fn(|d| h[d].max(x[d])))
                });
                for leaf in cluster(&q, cluster_size(p.cluster_size, *bounce), lo, hi) {
                    let ms: Vec<&Vpl> =
                        leaf.members.iter().map(|&k| &vpls[rest[k as usize] as usize]).collect();
                    let power = ms.iter().fold(Vec3::ZERO, |a, v| a + v.power);
                    let centre = (ms.iter().fold(glam::DVec3::ZERO, |a, v| a + v.position.as_dvec3())
                        / ms.len() as f64)
                        .as_vec3();
                    let normal = ms.iter().fold(Vec3::ZERO, |a, v| a + v.normal).normalize_or_zero();
                    let radius =
                        (ms.iter().map(|v| (v.position - centre).length_squared() as f64).sum::<f64>()
                            / ms.len() as f64)
                            .sqrt() as f32;
                    let samples = sample_members(ms.iter().map(|v| (v.position, v.normal)));
                    spheres.push(SphereCluster {
                        light: SphereLight {
                            centre,
                            radius,
                            normal: if normal == Vec3::ZERO { Vec3::Y } else { normal },
                            power,
                        },
                        samples,
                    });
                }
            }
            (polys, spheres)
        })
        .collect();
    for (polys, spheres) in per_group {
        out.polygons.extend(polys);
        out.spheres.extend(spheres);
    }
    out.light_power = out
        .polygons
        .iter()
        .map(|l| l.light.power)
        .chain(out.spheres.iter().map(|s| s.light.power))
        .fold(Vec3::ZERO, |a, b| a + b);
    out
}

/// Leaf size for a bounce: doubling with each bounce, because each bounce's light is smoother
/// than the last (paper 000 §7.1), so later bounces need fewer, larger lights.
fn cluster_size(base: usize, bounce: u32) -> usize {
    base.saturating_mul(1usize << (bounce - 1).min(16))
}

/// Per-texel direct and indirect irradiance.
pub struct Baked {
    pub direct: Vec<Vec3>,
    pub indirect: Vec<Vec3>,
    pub rays: usize,
}

/// Evaluate the virtual lights (and the real lights' direct light) at every texel.
pub fn evaluate(
    scene: &Scene,
    bvh: &Bvh,
    set: &TexelSet,
    lights: &[Light],
    vl: &VirtualLights,
    p: &BakeParams,
    control: Control,
) -> Result<Baked, Cancelled> {
    let ev = Evaluator { scene, bvh, set, lights, vl, p, rays: AtomicUsize::new(0) };
    let values = par_texels(&set.texels, control, || (), |_, t| ev.texel(t))?;
    let (direct, indirect) = values.into_iter().unzip();
    Ok(Baked { direct, indirect, rays: ev.rays.load(Ordering::Relaxed) })
}

/// What [`evaluate`] reads, and the rays it has cast.
struct Evaluator<'a> {
    scene: &'a Scene,
    bvh: &'a Bvh,
    set: &'a TexelSet,
    lights: &'a [Light],
    vl: &'a VirtualLights,
    p: &'a BakeParams,
    rays: AtomicUsize,
}

impl Evaluator<'_> {
    /// (direct, indirect) irradiance at texel `t`.
    fn texel(&self, t: &Texel) -> (Vec3, Vec3) {
        let mut rng = stream(self.p.seed, 30, (t.j * self.set.width + t.i) as u64);
        // Half a texel, in world units, for the epsilon shift.
        let eps = 0.5 * self.set.world_texel_size(self.scene, t.triangle as usize);
        let direct = if self.p.indirect_only {
            Vec3::ZERO
        } else {
            self.rays.fetch_add(self.lights.len(), Ordering::Relaxed);
            prm::bvh::direct_irradiance(self.bvh, self.lights, t.position, t.normal)
        };
        let mut indirect = Vec3::ZERO;
        let s = self.p.visibility_samples;
        for pc in &self.vl.polygons {
            let e = pc.light.irradiance(t.position, t.normal, eps);
            if e != Vec3::ZERO {
                let r2_min = pc.light.area() / pc.samples.len() as f32;
                self.rays.fetch_add(s as usize, Ordering::Relaxed);
                indirect +=
                    e * soft_visibility(self.bvh, t.position, t.normal, &pc.samples, r2_min, s, &mut rng);
            }
        }
        for sc in &self.vl.spheres {
            let e = sc.light.irradiance(t.position, t.normal);
            if e != Vec3::ZERO {
                let r2_min = sc.light.radius * sc.light.radius;
                self.rays.fetch_add(s as usize, Ordering::Relaxed);
                indirect +=
                    e * soft_visibility(self.bvh, t.position, t.normal, &sc.samples, r2_min, s, &mut rng);
            }
        }
        (direct, indirect)
    }
}

/// The share of a virtual light that receiver (p, n) sees, from `s` shadow rays to its member
/// VPLs `samples` (position, normal), drawn in proportion to their own point-light kernel
/// cos cos / r² (r² kept above `r2_min`, the light's area per sample), so that near parts of a
/// large light count for what they give. A plain fraction of members undercounts a light whose
/// far members hide behind pillars while its near ones shine: 4-6 % of the chamber's indirect
/// light was lost that way. Stratified over the kernel's distribution.
pub(crate) fn soft_visibility(
    bvh: &Bvh,
    p: Vec3,
    n: Vec3,
    samples: &[(Vec3, Vec3)],
    r2_min: f32,
    s: u32,
    rng: &mut rand_pcg::Pcg64Mcg,
) -> f32 {
    let mut seen = 0;
    // Draws come in ascending order, and a member that dominates the kernel (the receiver
    // close to it) is drawn in several strata: its ray, the same each time, is traced once.
    let mut last: Option<(usize, bool)> = None;
    visibility_draws(p, n, samples, r2_min, s, rng, |i| {
        let v = match last {
            Some((j, v)) if j == i => v,
            _ => {
                let (q, nq) = samples[i];
                bvh.visible(p, n, q, nq)
            }
        };
        last = Some((i, v));
        seen += v as u32;
    });
    seen as f32 / s as f32
}

/// The members [`soft_visibility`] sends its `s` shadow rays to, drawn in proportion to their
/// point-light kernel at (p, n), stratified: `visit` gets each drawn index in turn. The same
/// random stream gives the same draws, so a caller can tell which rays a value rests on.
pub(crate) fn visibility_draws(
    p: Vec3,
    n: Vec3,
    samples: &[(Vec3, Vec3)],
    r2_min: f32,
    s: u32,
    rng: &mut rand_pcg::Pcg64Mcg,
    mut visit: impl FnMut(usize),
) {
    // Members are few (at most MAX_SAMPLES here, fewer in the incremental baker): the CDF
    // lives on the stack.
    let mut stack = [0.0f32; MAX_SAMPLES];
    let mut heap = Vec::new();
    let cdf: &mut [f32] = if samples.len() <= MAX_SAMPLES {
        &mut stack[..samples.len()]
    } else {
        heap.resize(samples.len(), 0.0);
        &mut heap
    };
    kernel_weights(p, n, samples, r2_min, cdf);
    let mut total = 0.0f32;
    for c in cdf.iter_mut() {
        total += *c;
        *c = total;
    }
    for k in 0..s {
        let u = (k as f32 + rng.random::<f32>()) / s as f32;
        let i = if total > 0.0 {
            cdf.partition_point(|&c| c < u * total).min(samples.len() - 1)
        } else {
            rng.random_range(0..samples.len())
        };
        visit(i);
    }
}

/// Each member's point-light kernel at (p, n), `cos_q cos_p / (r² max(r², r2_min))`, into
/// `out`: four members at a time, with the same operations in the same order as one at a time
/// (the same values, so the same draws; a twin test holds them to it). A bake draws from these
/// for every texel and virtual light.
fn kernel_weights(p: Vec3, n: Vec3, samples: &[(Vec3, Vec3)], r2_min: f32, out: &mut [f32]) {
    use glam::Vec4;
    for (chunk, out) in samples.chunks(4).zip(out.chunks_mut(4)) {
        let lane = |f: fn(&(Vec3, Vec3)) -> f32| {
            Vec4::from_array(std::array::from_fn(|j| chunk.get(j).map_or(0.0, f)))
        };
        let (dx, dy, dz) = (p.x - lane(|s| s.0.x), p.y - lane(|s| s.0.y), p.z - lane(|s| s.0.z));
        let (nx, ny, nz) = (lane(|s| s.1.x), lane(|s| s.1.y), lane(|s| s.1.z));
        let r2 = dx * dx + dy * dy + dz * dz;
        let cos_q = (nx * dx + ny * dy + nz * dz).max(Vec4::ZERO);
        let cos_p = (-(n.x * dx + n.y * dy + n.z * dz)).max(Vec4::ZERO);
        let w = (cos_q * cos_p) / (r2 * r2.max(Vec4::splat(r2_min))).max(Vec4::splat(1e-30));
        out.copy_from_slice(&w.to_array()[..out.len()]);
    }
}

/// The virtual lights as a Wavefront OBJ: polygons as faces, spheres as octahedra.
pub fn to_obj(vl: &VirtualLights) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "# prm reference baker: virtual polygon lights (g polygons) and sphere lights (g spheres)\n",
    );
    let mut next = 1;
    let _ = writeln!(s, "g polygons");
    for l in vl.polygons.iter().map(|p| &p.light) {
        for v in &l.vertices {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        let idx: Vec<String> = (next..next + l.vertices.len()).map(|i| i.to_string()).collect();
        let _ = writeln!(s, "f {}", idx.join(" "));
        next += l.vertices.len();
    }
    let _ = writeln!(s, "g spheres");
    for sc in &vl.spheres {
        let (c, r) = (sc.light.centre, sc.light.radius.max(1e-4));
        for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
            let v = c + d * r;
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        for f in [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]] {
            let _ = writeln!(s, "f {} {} {}", next + f[0], next + f[1], next + f[2]);
        }
        next += 6;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn kernel_weights_are_the_one_at_a_time_formula_exactly() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let v = |rng: &mut rand_pcg::Pcg64Mcg| {
            Vec3::new(rng.random_range(-4.0..4.0), rng.random_range(-4.0..4.0), rng.random_range(-4.0..4.0))
        };
        for len in 0..=MAX_SAMPLES {
            let (p, n) = (v(&mut rng), v(&mut rng).normalize());
            // Some members at the receiver itself (r² = 0) and some facing away.
            let samples: Vec<(Vec3, Vec3)> = (0..len)
                .map(|k| (if k % 7 == 3 { p } else { v(&mut rng) }, v(&mut rng).normalize()))
                .collect();
            let r2_min = rng.random_range(0.0..0.5);
            let mut out = vec![f32::NAN; len];
            kernel_weights(p, n, &samples, r2_min, &mut out);
            for ((q, nq), w) in samples.iter().zip(&out) {
                let d = p - *q;
                let r2 = d.length_squared();
                let one = (nq.dot(d).max(0.0) * (-n.dot(d)).max(0.0)) / (r2 * r2.max(r2_min)).max(1e-30);
                // The same value; a zero's sign may differ (f32::max and the lanes' max pick
                // either of -0 and +0), which no comparison of the CDF tells apart.
                assert!(one == *w, "{len} members: {one} against {w}");
            }
        }
    }
}
