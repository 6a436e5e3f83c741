//! Virtual point lights per real light and per bounce (paper 000 §5.1).
//!
//! Photons leave each light carrying flux: a point light sends `4 pi I / n` per photon in
//! uniform directions; a spot light `I falloff(w) Omega / n` in uniform directions inside its
//! outer cone (solid angle Omega); a directional light `E pi R^2 / n` from a disk of the level's
//! bounding radius R; a sphere light `4 pi I / n` from a uniform point of its surface in a
//! cosine direction about the normal there (a Lambertian sphere: isotropic intensity I), a
//! spot's like a point spot's, each photon from a uniform point of the sphere's disk across
//! its direction (the sphere as seen from far along it); a
//! polygon light `pi I_n / n` from a uniform point of it in a cosine direction; a profiled
//! point light `I rel(w) / (n pdf(w))` in directions drawn from its profile's table, nearly
//! equal each. Where a photon meets a front face, it leaves a VPL of its bounce with the
//! flux it brings (`incident`) and the flux it re-emits (`power = incident x albedo`, Lambertian);
//! it then continues in a cosine direction with that reflected flux, for `bounces` bounces.
//! Photons that leave the level, or meet the back of a one-sided surface, are counted, so energy
//! can be accounted for exactly: emitted = incident on first hits + escaped + absorbed by backs.

use glam::Vec3;
use prm::light::range_window;
use prm::light::Aperture;
use prm::{Bvh, Light, LightKind, Scene};
use rand::Rng;
use rayon::prelude::*;

use prm::sampling::{cosine_direction, stream};

/// A virtual point light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vpl {
    pub position: Vec3,
    pub normal: Vec3,
    /// Flux arriving with the photon, W per channel.
    pub incident: Vec3,
    /// Flux re-emitted (incident x albedo), W per channel.
    pub power: Vec3,
    /// The light it came from (the first light of its [`PhotonSource`]).
    pub light: u32,
    /// 1 for a photon's first hit.
    pub bounce: u32,
}

/// Energy accounting of the photons of one light.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PhotonBudget {
    /// Flux the light emitted.
    pub emitted: Vec3,
    /// Flux that left the level before its first hit.
    pub escaped: Vec3,
    /// Flux that met the back of a one-sided surface at its first hit.
    pub absorbed_by_backs: Vec3,
    /// Flux still re-emitted by the last bounce's VPLs (light the bounce cap leaves out).
    pub beyond_last_bounce: Vec3,
}

/// Where a photon starts, which way and with what flux; `surface` is the normal at its origin
/// when that lies on an aperture's surface (a sphere or polygon light), so the first ray
/// leaves it as from a surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Emission {
    pub origin: Vec3,
    pub dir: Vec3,
    pub flux: Vec3,
    pub surface: Option<Vec3>,
}

/// Emit photon `k` of `photons` from `light`. A directional light shoots from a disk covering
/// the box `bounds`.
pub(crate) fn emit(
    light: &Light,
    bounds: (Vec3, Vec3),
    photons: usize,
    k: usize,
    rng: &mut impl Rng,
) -> Emission {
    let n = photons as f32;
    let at = |origin: Vec3, dir: Vec3, flux: Vec3| Emission { origin, dir, flux, surface: None };
    match (&light.aperture, light.kind, light.profile.as_ref()) {
        (Aperture::Sphere { radius }, LightKind::Spot { outer, .. }, _) => {
            // A direction in the cone as from a point spot, leaving from a uniform point of the
            // sphere's disk across it, moved onto the sphere's side facing it: seen from far
            // along d, a disk of radiance I falloff(d) / (pi R²).
            let d = cone_direction(light.direction, outer.cos(), rng.random(), rng.random());
            let (t, b) = d.any_orthonormal_pair();
            let (r, phi) = (radius * rng.random::<f32>().sqrt(), std::f32::consts::TAU * rng.random::<f32>());
            let across = t * (r * phi.cos()) + b * (r * phi.sin());
            let normal = (across + d * (radius * radius - r * r).max(0.0).sqrt()) / *radius;
            let omega = std::f32::consts::TAU * (1.0 - outer.cos());
            Emission {
                origin: light.position + normal * *radius,
                dir: d,
                flux: light.intensity_towards(d) * (omega / n),
                surface: Some(normal),
            }
        }
        (Aperture::Sphere { radius }, _, _) => {
            let normal = uniform_sphere(rng.random(), rng.random());
            let dir = cosine_direction(normal, rng.random(), rng.random());
            let origin = light.position + normal * *radius;
            Emission { origin, dir, flux: light.flux() / n, surface: Some(normal) }
        }
        (Aperture::Polygon { corners }, _, _) => {
            let origin = prm::light::polygon_point(corners, [rng.random(), rng.random()]);
            let dir = cosine_direction(light.direction, rng.random(), rng.random());
            Emission { origin, dir, flux: light.flux() / n, surface: Some(light.direction) }
        }
        (Aperture::Point, _, Some(pr)) => {
            let (d, pdf) =
                pr.table.sample(light.direction, pr.c0, [rng.random(), rng.random(), rng.random()]);
            let flux = if pdf > 0.0 { light.intensity_towards(d) / (pdf * n) } else { Vec3::ZERO };
            at(light.position, d, flux)
        }
        (Aperture::Point, LightKind::Point, None) => {
            let d = uniform_sphere(rng.random(), rng.random());
            at(light.position, d, light.intensity * (4.0 * std::f32::consts::PI / n))
        }
        (Aperture::Point, LightKind::Spot { outer, .. }, None) => {
            let d = cone_direction(light.direction, outer.cos(), rng.random(), rng.random());
            let omega = std::f32::consts::TAU * (1.0 - outer.cos());
            at(light.position, d, light.intensity_towards(d) * (omega / n))
        }
        (Aperture::Point, LightKind::Directional, None) => {
            let (lo, hi) = bounds;
            let centre = 0.5 * (lo + hi);
            let radius = 0.5 * (hi - lo).length() * 1.01 + 1e-6;
            let (t, b) = light.direction.any_orthonormal_pair();
            // Stratify the disk by photon index along the radius.
            let r = radius * ((k as f32 + rng.random::<f32>()) / n).sqrt();
            let phi = std::f32::consts::TAU * rng.random::<f32>();
            let origin =
                centre - light.direction * (2.0 * radius) + t * (r * phi.cos()) + b * (r * phi.sin());
            at(origin, light.direction, light.intensity * (std::f32::consts::PI * radius * radius / n))
        }
    }
}

/// A direction uniform in the cone of half-angle cosine `cos_outer` about unit `axis`.
fn cone_direction(axis: Vec3, cos_outer: f32, u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - u1 * (1.0 - cos_outer);
    let phi = std::f32::consts::TAU * u2;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (t, b) = axis.any_orthonormal_pair();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + axis * z).normalize()
}

fn uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Lights that share one light's photons, by index into the lights; each photon picks one of
/// them in proportion to its flux. A glTF light is a source of its own; a glowing mesh's
/// polygon lights, which merging cannot make one (a curved shade, a tessellated sign), are one
/// source, so a glowing mesh costs one light's photons, not one light's per polygon.
pub type PhotonSource = Vec<u32>;

/// Every light its own source.
pub fn one_source_per_light(lights: usize) -> Vec<PhotonSource> {
    (0..lights as u32).map(|l| vec![l]).collect()
}

/// The sources of a level's lights: the first `own` (its glTF lights) one each, then `glow`
/// (`prm::emitters::emitters`, whose lights follow them in that order) one source per glowing
/// mesh: emitters of one glTF node and material joined by a shared corner, in the order each
/// mesh first appears. Fifty lamps of one node and material that do not touch are fifty
/// sources.
pub fn emissive_sources(scene: &Scene, own: usize, glow: &[prm::emitters::Emitter]) -> Vec<PhotonSource> {
    // Union-find over the emitters, joined where their triangles share a corner.
    let mut parent: Vec<usize> = (0..glow.len()).collect();
    fn root(parent: &mut [usize], mut k: usize) -> usize {
        while parent[k] != k {
            parent[k] = parent[parent[k]];
            k = parent[k];
        }
        k
    }
    let mut first_at: std::collections::HashMap<(u32, u32, [u32; 3]), usize> =
        std::collections::HashMap::new();
    for (k, e) in glow.iter().enumerate() {
        for &t in &e.triangles {
            let tri = &scene.triangles[t as usize];
            for c in scene.corners(t as usize) {
                let key = (tri.node, tri.material, [c.x.to_bits(), c.y.to_bits(), c.z.to_bits()]);
                let other = *first_at.entry(key).or_insert(k);
                let (a, b) = (root(&mut parent, k), root(&mut parent, other));
                // The earlier emitter stays the root: sources keep their first appearance.
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut sources = one_source_per_light(own);
    let mut source_of: std::collections::HashMap<usize, usize> = std::collections::HashMap::new();
    for k in 0..glow.len() {
        let light = (own + k) as u32;
        let r = root(&mut parent, k);
        match source_of.get(&r) {
            Some(&s) => sources[s].push(light),
            None => {
                source_of.insert(r, sources.len());
                sources.push(vec![light]);
            }
        }
    }
    sources
}

/// Trace `photons` photons from each light for `bounces` bounces. VPLs come out grouped by
/// light, then photon, then bounce; the budget is per light.
pub fn trace_photons(
    scene: &Scene,
    bvh: &Bvh,
    lights: &[Light],
    photons: usize,
    bounces: u32,
    seed: u64,
) -> (Vec<Vpl>, Vec<PhotonBudget>) {
    trace_sources(scene, bvh, lights, &one_source_per_light(lights.len()), photons, bounces, seed)
}

/// Trace `photons` photons from each source for `bounces` bounces. A source of several lights
/// picks each photon's light by flux, stratified over the photons (photon k at `(k + u) / n` of
/// the flux's running sum), and divides its flux by that light's probability: unbiased, and
/// every photon of a source carries about the same flux. A VPL's `light` is its source's first
/// light; VPLs come out grouped by source, then photon, then bounce, and the budget is per
/// source (an empty source has none). A source of one light draws nothing for the pick, so it
/// traces what [`trace_photons`] does.
pub fn trace_sources(
    scene: &Scene,
    bvh: &Bvh,
    lights: &[Light],
    sources: &[PhotonSource],
    photons: usize,
    bounces: u32,
    seed: u64,
) -> (Vec<Vpl>, Vec<PhotonBudget>) {
    let mut all = Vec::new();
    let mut budgets = Vec::new();
    let weight = |l: &Light| {
        let f = l.flux().as_dvec3();
        if f.is_finite() {
            (f.x + f.y + f.z).max(0.0)
        } else {
            0.0
        }
    };
    for source in sources.iter().filter(|s| !s.is_empty()) {
        let first = source[0];
        // Running sums of the source's flux, for the pick.
        let running: Vec<f64> = source
            .iter()
            .scan(0.0, |sum, &l| {
                *sum += weight(&lights[l as usize]);
                Some(*sum)
            })
            .collect();
        let total = running.last().copied().unwrap_or(0.0);
        let per_photon: Vec<(Vec<Vpl>, PhotonBudget)> = (0..photons)
            .into_par_iter()
            .map(|k| {
                let mut rng = stream(seed, 10 + first as u64, k as u64);
                let (light, prob) = if source.len() == 1 || !(total > 0.0) {
                    (&lights[first as usize], 1.0)
                } else {
                    // Below the total: the pick never lands past the last light with flux.
                    let at = ((k as f64 + rng.random::<f64>()) / photons as f64 * total)
                        .min(total * (1.0 - f64::EPSILON));
                    let i = running.partition_point(|&r| r <= at).min(source.len() - 1);
                    let below = if i == 0 { 0.0 } else { running[i - 1] };
                    (&lights[source[i] as usize], ((running[i] - below) / total) as f32)
                };
                let mut budget = PhotonBudget::default();
                let mut out = Vec::new();
                let e = emit(light, scene.bounds(), photons, k, &mut rng);
                let (mut origin, mut dir, mut flux) = (e.origin, e.dir, e.flux / prob);
                budget.emitted = flux;
                let mut from_surface: Option<Vec3> = e.surface;
                for bounce in 1..=bounces {
                    let hit = match from_surface {
                        None => bvh.closest_hit(origin, dir, f32::INFINITY),
                        Some(n) => bvh.trace_from_surface(origin, n, dir),
                    };
                    let Some(hit) = hit else {
                        if bounce == 1 {
                            budget.escaped = flux;
                        }
                        break;
                    };
                    let t = hit.triangle as usize;
                    let Some(n) = scene.facing_normal(t, dir) else {
                        if bounce == 1 {
                            budget.absorbed_by_backs = flux;
                        }
                        break;
                    };
                    if bounce == 1 && light.range.is_some() {
                        // glTF's range window, applied where the photon lands.
                        flux *= light.range.map_or(1.0, |r| range_window(hit.t, r));
                    }
                    let y = scene.point(t, hit.bary());
                    let power = flux * scene.albedo(t, hit.bary());
                    out.push(Vpl { position: y, normal: n, incident: flux, power, light: first, bounce });
                    if bounce == bounces {
                        budget.beyond_last_bounce = power;
                        break;
                    }
                    if power == Vec3::ZERO {
                        break;
                    }
                    origin = y;
                    from_surface = Some(n);
                    dir = cosine_direction(n, rng.random(), rng.random());
                    flux = power;
                }
                (out, budget)
            })
            .collect();
        // Summed in f64: 200,000 photons' flux in f32 drifts by 1e-3.
        let mut b = [glam::DVec3::ZERO; 4];
        for (v, pb) in per_photon {
            all.extend(v);
            for (sum, x) in
                b.iter_mut().zip([pb.emitted, pb.escaped, pb.absorbed_by_backs, pb.beyond_last_bounce])
            {
                *sum += x.as_dvec3();
            }
        }
        budgets.push(PhotonBudget {
            emitted: b[0].as_vec3(),
            escaped: b[1].as_vec3(),
            absorbed_by_backs: b[2].as_vec3(),
            beyond_last_bounce: b[3].as_vec3(),
        });
    }
    (all, budgets)
}
