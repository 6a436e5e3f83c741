//! Light paths kept with their VPLs (paper 001 §3.3, §4.2).
//!
//! Every path of a light carries about the same energy: a light gets `ceil(Phi / q)` paths for
//! the level's quantum `q` (luminance, W). At each hit a VPL re-emits what arrived times the
//! albedo. Paper 001 lets every path go on with the same energy, which over-counts the second
//! and later bounces by 1 / (product of albedos) unless a path survives each bounce with the
//! albedo's probability; here it does (Russian roulette on the largest channel, the flux
//! divided by that probability), which keeps the estimate unbiased and the paths' energies
//! close to equal.
//!
//! A path's random numbers come from streams keyed by (light id, path index, bounce), so a
//! path traced again on a changed level makes the same choices until it meets the change:
//! validation is tracing again and comparing, and a path the edit does not touch comes out
//! bit-identical.

use glam::Vec3;
use prm::light::range_window;
use prm::sampling::{cosine_direction, stream};
use rand::Rng;
use rayon::prelude::*;

use super::level::{LightSlot, Version};
use crate::reference::vpl::emit;

/// Where a path met a surface: a VPL.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vertex {
    pub position: Vec3,
    /// Unit normal of the side the path arrived on.
    pub normal: Vec3,
    pub triangle: u32,
    /// The glTF node that placed the triangle (the object the VPL is linked to).
    pub node: u32,
    /// Flux arriving, W per channel.
    pub incident: Vec3,
    /// Flux the VPL re-emits (incident x albedo), W per channel.
    pub power: Vec3,
}

/// One light path.
#[derive(Clone, Debug, PartialEq)]
pub struct Path {
    pub vertices: Vec<Vertex>,
}

/// Bounce cap and seed of the paths.
#[derive(Clone, Copy, Debug)]
pub struct PathParams {
    pub max_bounces: u32,
    pub seed: u64,
}

/// Luminance weights (Rec. 709), for the path quantum.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A light's emitted flux (W per channel): one photon of one carries it all.
pub fn light_flux(light: &LightSlot, bounds: (Vec3, Vec3)) -> Vec3 {
    let mut rng = stream(0, 0, 0);
    // A spot's photon flux depends on its direction (the falloff); its axis is the most.
    match light.light.kind {
        // With a radius too: its photons leave in the cone as a point spot's do.
        prm::LightKind::Spot { outer, .. } if light.light.profile.is_none() => {
            light.light.intensity * (std::f32::consts::TAU * (1.0 - outer.cos()))
        }
        prm::LightKind::Directional => emit(&light.light, bounds, 1, 0, &mut rng).flux,
        _ => light.light.flux(),
    }
}

/// How many paths a light gets for quantum `q`, at most `most` (the bake's paths). A level's
/// lights share its paths by flux when it is opened; a light edited brighter later would take
/// more (one 1e4 times the level's light, 1e4 times the bake's paths: an edit that never
/// ended), so it is held to `most`, its paths then carrying more than `q` each.
pub fn path_count(light: &LightSlot, bounds: (Vec3, Vec3), q: f32, most: usize) -> usize {
    let l = luminance(light_flux(light, bounds));
    if !(l > 0.0) || !(q > 0.0) {
        return 0;
    }
    ((l / q).ceil().min(most as f32) as usize).clamp(1, most.max(1))
}

/// Trace path `index` of the `count` paths of `light` on version `v`.
pub fn trace(
    v: &Version,
    light: &LightSlot,
    index: usize,
    count: usize,
    bounds: (Vec3, Vec3),
    p: PathParams,
) -> Path {
    let tag = 1000 + light.id as u64;
    let key = |bounce: u64| (index as u64) << 8 | bounce;
    let mut rng = stream(p.seed, tag, key(0));
    let e = emit(&light.light, bounds, count, index, &mut rng);
    let (mut origin, mut dir, mut flux) = (e.origin, e.dir, e.flux);
    let mut vertices = Vec::new();
    let mut from_surface: Option<Vec3> = e.surface;
    for bounce in 1..=p.max_bounces.min(255) {
        let hit = match from_surface {
            None => v.bvh.closest_hit(origin, dir, f32::INFINITY),
            Some(n) => v.bvh.trace_from_surface(origin, n, dir),
        };
        let Some(hit) = hit else { break };
        let t = hit.triangle as usize;
        let Some(n) = v.scene.facing_normal(t, dir) else { break };
        if bounce == 1 {
            if let Some(r) = light.light.range {
                flux *= range_window(hit.t, r);
            }
        }
        let y = v.scene.point(t, hit.bary());
        let power = flux * v.scene.albedo(t, hit.bary());
        vertices.push(Vertex {
            position: y,
            normal: n,
            triangle: hit.triangle,
            node: v.scene.triangles[t].node,
            incident: flux,
            power,
        });
        if bounce == p.max_bounces {
            break;
        }
        let mut rng = stream(p.seed, tag, key(bounce as u64));
        let survive = (power.max_element() / flux.max_element().max(f32::MIN_POSITIVE)).min(1.0);
        if !(survive > 0.0) || rng.random::<f32>() >= survive {
            break;
        }
        origin = y;
        from_surface = Some(n);
        dir = cosine_direction(n, rng.random(), rng.random());
        flux = power / survive;
    }
    Path { vertices }
}

/// The paths of one light.
#[derive(Clone, Debug)]
pub struct LightPaths {
    pub light: LightSlot,
    pub paths: Vec<Path>,
}

/// Trace all `count` paths of `light`.
pub fn trace_all(
    v: &Version,
    light: &LightSlot,
    count: usize,
    bounds: (Vec3, Vec3),
    p: PathParams,
) -> LightPaths {
    let paths = (0..count).into_par_iter().map(|i| trace(v, light, i, count, bounds, p)).collect();
    LightPaths { light: light.clone(), paths }
}

/// A VPL that appeared or went, and the flux of a path segment that now lands elsewhere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Change {
    /// A VPL added (+) or removed (-) at a position: differential invalid flux (signed).
    Vpl { position: Vec3, power: Vec3, added: bool },
    /// A segment leaving `from` (a VPL's position, or `None` for the light itself) that hit
    /// something else than before: absolute invalid flux of the cluster it leaves.
    Segment { from: Option<Vec3>, flux: Vec3 },
}

/// Trace every path of `lp` again on `v`; replace those that changed and say what changed.
/// Returns the number of paths that changed.
pub fn validate(
    v: &Version,
    lp: &mut LightPaths,
    bounds: (Vec3, Vec3),
    p: PathParams,
    changes: &mut Vec<Change>,
) -> usize {
    let count = lp.paths.len();
    let light = lp.light.clone();
    let fresh: Vec<Option<(Path, Vec<Change>)>> = lp
        .paths
        .par_iter()
        .enumerate()
        .map(|(i, old)| {
            let new = trace(v, &light, i, count, bounds, p);
            if new == *old {
                return None;
            }
            let k = old.vertices.iter().zip(&new.vertices).take_while(|(a, b)| a == b).count();
            let mut ch = Vec::new();
            let from = if k == 0 { None } else { Some(old.vertices[k - 1].position) };
            let seg = old.vertices.get(k).or(new.vertices.get(k)).map_or(Vec3::ZERO, |x| x.incident);
            ch.push(Change::Segment { from, flux: seg });
            for x in &old.vertices[k..] {
                ch.push(Change::Vpl { position: x.position, power: x.power, added: false });
            }
            for x in &new.vertices[k..] {
                ch.push(Change::Vpl { position: x.position, power: x.power, added: true });
            }
            Some((new, ch))
        })
        .collect();
    let mut n = 0;
    for (slot, f) in lp.paths.iter_mut().zip(fresh) {
        if let Some((path, ch)) = f {
            *slot = path;
            changes.extend(ch);
            n += 1;
        }
    }
    n
}
