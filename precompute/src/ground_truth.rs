//! The ground truth: an independent Monte Carlo path tracer (DESIGN.md §7).
//!
//! It shares only the scene (with its sidedness rule, [`prm::Scene::facing_normal`]) and the
//! ray queries with the rest of PRM, so a mistake in the precompute or the reference baker
//! cannot hide in it. **Its sampling code is its own on purpose** (cosine directions, stream
//! seeding, roulette): `prm::sampling` serves the bakers it judges, and a fault there must
//! show up as a disagreement with this tracer, not be shared by both.
//!
//! **Estimator.** Irradiance at a surface point x0 with normal n is
//! `E(x0) = E_punctual(x0) + pi * L(x1 -> x0)`, the second term estimated with one
//! cosine-sampled direction per sample (pdf cos/pi). Along the path x1, x2, ... with albedo
//! rho_k and Russian-roulette continuation probability q_k, the throughput is
//! `beta_k = prod_{i<=k} rho_i / prod_{i<k} q_i` and one sample is
//!
//! - direct:   `E_punctual(x0) + pi Le(x1)`
//! - indirect: `sum_{k>=1} beta_k E_punctual(x_k) + sum_{k>=2} beta_{k-1} pi Le(x_k)`
//!
//! where `E_punctual` is next-event estimation to every point, spot and directional light
//! (shadow ray, no noise) and Le is the emitted radiance of a front face. Back faces of
//! one-sided surfaces absorb. Roulette starts after [`GtParams::rr_depth`] bounces with
//! `q = max(rho)` (clamped to [0.05, 1]), so it is unbiased; `max_bounces` is an explicit,
//! reported cap (paths cut there are counted).

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DVec3, Vec3};
use prm::{Bvh, Scene, Texel};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::parallel::{par_texels, Cancelled, Control};
use crate::params::{require, ParamError};

/// Ground-truth parameters.
#[derive(Clone, Debug)]
pub struct GtParams {
    /// Paths per texel (or pixel).
    pub spp: u32,
    /// Hard cap on path length; paths reaching it are counted in [`GtStats::truncated`].
    pub max_bounces: u32,
    /// Bounces before Russian roulette starts.
    pub rr_depth: u32,
    /// Seed of every per-texel random stream.
    pub seed: u64,
}

impl GtParams {
    /// Quick look: 64 paths per texel.
    pub fn preview() -> Self {
        GtParams { spp: 64, max_bounces: 1000, rr_depth: 3, seed: 0 }
    }
    /// Reference quality: 1024 paths per texel.
    pub fn production() -> Self {
        GtParams { spp: 1024, ..Self::preview() }
    }

    /// Reject absurd values with an error naming the parameter.
    pub fn validate(&self) -> Result<(), ParamError> {
        require((1..=1 << 24).contains(&self.spp), "spp", self.spp, "1 to 16777216")?;
        require(self.max_bounces >= 1, "max bounces", self.max_bounces, "at least 1")?;
        Ok(())
    }
}

impl Default for GtParams {
    fn default() -> Self {
        Self::preview()
    }
}

/// Per-point result: means and standard errors of the mean.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Irradiance {
    pub direct: Vec3,
    pub indirect: Vec3,
    pub direct_stderr: Vec3,
    pub indirect_stderr: Vec3,
}

/// The noise of a ground-truth lightmap's indirect layer in the error metric's units
/// (`prm::metric`): sqrt(sum of squared luminance standard errors / sum of squared luminance).
pub fn indirect_noise(values: &[Irradiance]) -> f64 {
    let (mut se2, mut y2) = (0.0f64, 0.0f64);
    for v in values {
        se2 += (prm::luminance(v.indirect_stderr) as f64).powi(2);
        y2 += (prm::luminance(v.indirect) as f64).powi(2);
    }
    if y2 > 0.0 {
        (se2 / y2).sqrt()
    } else {
        0.0
    }
}

/// Counters over a whole run.
#[derive(Debug, Default)]
pub struct GtStats {
    pub paths: AtomicUsize,
    pub rays: AtomicUsize,
    pub truncated: AtomicUsize,
}

/// One path tracer over a scene.
pub struct Tracer<'a> {
    pub scene: &'a Scene,
    pub bvh: &'a Bvh,
    pub params: GtParams,
    pub stats: GtStats,
}

/// A cosine-distributed unit direction around unit `n` (the judge's own copy: see the module
/// doc).
fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let (t, b) = n.any_orthonormal_pair();
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

impl<'a> Tracer<'a> {
    pub fn new(scene: &'a Scene, bvh: &'a Bvh, params: GtParams) -> Self {
        Tracer { scene, bvh, params, stats: GtStats::default() }
    }

    /// Irradiance from the punctual lights at `p` (normal `n`), with shadow rays.
    pub fn punctual(&self, p: Vec3, n: Vec3) -> Vec3 {
        let mut e = Vec3::ZERO;
        for light in &self.scene.lights {
            let inc = light.incident(p);
            let cos = n.dot(inc.to_light);
            if cos <= 0.0 || inc.irradiance == Vec3::ZERO {
                continue;
            }
            self.stats.rays.fetch_add(1, Ordering::Relaxed);
            let visible = if light.is_positional() {
                self.bvh.visible_point(p, n, light.position)
            } else {
                self.bvh.visible_dir(p, n, inc.to_light)
            };
            if visible {
                e += inc.irradiance * cos;
            }
        }
        e
    }

    /// One sample of (direct, indirect) irradiance at surface point `p` with normal `n`.
    pub fn sample(&self, p: Vec3, n: Vec3, e_punctual: Vec3, rng: &mut Pcg64Mcg) -> (Vec3, Vec3) {
        let mut direct = e_punctual;
        let mut indirect = Vec3::ZERO;
        let mut beta = Vec3::ONE;
        let (mut x, mut nx) = (p, n);
        let mut bounce = 0u32;
        self.stats.paths.fetch_add(1, Ordering::Relaxed);
        loop {
            let d = cosine_direction(nx, rng.random(), rng.random());
            self.stats.rays.fetch_add(1, Ordering::Relaxed);
            let Some(hit) = self.bvh.trace_from_surface(x, nx, d) else { break };
            let t = hit.triangle as usize;
            let Some(nh) = self.scene.facing_normal(t, d) else { break };
            let material = self.scene.material(t);
            bounce += 1;
            let xh = self.scene.point(t, hit.bary());
            if material.emissive != Vec3::ZERO {
                let le = beta * material.emissive * std::f32::consts::PI;
                if bounce == 1 {
                    direct += le
                } else {
                    indirect += le
                }
            }
            let rho = self.scene.albedo(t, hit.bary());
            beta *= rho;
            if beta == Vec3::ZERO {
                break;
            }
            indirect += beta * self.punctual(xh, nh);
            if bounce >= self.params.max_bounces {
                self.stats.truncated.fetch_add(1, Ordering::Relaxed);
                break;
            }
            if bounce >= self.params.rr_depth {
                let q = rho.max_element().clamp(0.05, 1.0);
                if rng.random::<f32>() >= q {
                    break;
                }
                beta /= q;
            }
            x = xh;
            nx = nh;
        }
        (direct, indirect)
    }

    /// Mean and standard error of `spp` samples at one point, on its own random stream.
    pub fn irradiance(&self, p: Vec3, n: Vec3, stream: u64) -> Irradiance {
        let mut rng = Pcg64Mcg::seed_from_u64(
            self.params.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03).wrapping_add(stream),
        );
        let e_punctual = self.punctual(p, n);
        // Welford's running mean and squared deviation, in f64: constant samples give exactly
        // zero error, and long runs lose nothing to cancellation.
        let (mut md, mut m2d, mut mi, mut m2i) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        let spp = self.params.spp.max(1);
        for k in 1..=spp {
            let (d, i) = self.sample(p, n, e_punctual, &mut rng);
            let (d, i) = (d.as_dvec3(), i.as_dvec3());
            let (dd, di) = (d - md, i - mi);
            md += dd / k as f64;
            mi += di / k as f64;
            m2d += dd * (d - md);
            m2i += di * (i - mi);
        }
        let stderr = |m2: DVec3| {
            if spp < 2 {
                return Vec3::ZERO;
            }
            (m2.max(DVec3::ZERO) / ((spp - 1) as f64 * spp as f64)).map(f64::sqrt).as_vec3()
        };
        Irradiance {
            direct: md.as_vec3(),
            indirect: mi.as_vec3(),
            direct_stderr: stderr(m2d),
            indirect_stderr: stderr(m2i),
        }
    }

    /// Irradiance at every texel, in parallel, deterministic at any thread count (each texel
    /// seeds its own stream from its atlas index); `control` reports progress and stops it.
    pub fn texels(
        &self,
        texels: &[Texel],
        width: u32,
        control: Control,
    ) -> Result<Vec<Irradiance>, Cancelled> {
        par_texels(
            texels,
            control,
            || (),
            |_, t| self.irradiance(t.position, t.normal, (t.j as u64) * width as u64 + t.i as u64),
        )
    }

    /// Radiance seen along a camera ray: emission plus albedo/pi x irradiance at the first
    /// front-facing hit (one irradiance sample), black for misses and back faces.
    pub fn radiance(&self, origin: Vec3, dir: Vec3, rng: &mut Pcg64Mcg) -> Vec3 {
        self.stats.rays.fetch_add(1, Ordering::Relaxed);
        let Some(hit) = self.bvh.closest_hit(origin, dir, f32::INFINITY) else { return Vec3::ZERO };
        let t = hit.triangle as usize;
        let Some(n) = self.scene.facing_normal(t, dir) else { return Vec3::ZERO };
        let material = self.scene.material(t);
        let p = self.scene.point(t, hit.bary());
        let (d, i) = self.sample(p, n, self.punctual(p, n), rng);
        material.emissive + self.scene.albedo(t, hit.bary()) / std::f32::consts::PI * (d + i)
    }
}
