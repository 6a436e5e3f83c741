//! A level with moving objects, lit by hierarchical radiosity over precomputed visibility
//! (paper 003): what `prm render --mode cssm` and the report's moving-objects section share.
//!
//! [`MovingLevel`] holds the level at rest, its texels, visibility, texel hierarchy and the
//! rig's motion; [`MovingLevel::frame`] poses it at a time, lights the texels directly (each
//! texel's mean over its shape) and runs the radiosity from that: on the GPU, shadow maps of
//! the posed level light the texels (`RadiosityPass::light_texels`) and nothing leaves the GPU
//! but the lightmap; on the CPU, rays in the posed level do
//! (`prm_runtime::cpu::radiosity::sender_direct`). It optionally measures the result, and a
//! PRM of the level at rest, against the ground truth of the posed level on the same texels
//! (noise removed in quadrature).

use std::path::Path;
use std::time::Instant;

use anyhow::{anyhow, Result};
use glam::Vec3;
use prm::rig::{Motion, Rig};
use prm::visibility::{Poses, Visibility};
use prm::{Bvh, Scene, TexelSet};
use prm_precompute::ground_truth::{indirect_noise, GtParams, Tracer};
use prm_precompute::parallel::Control;
use prm_runtime::cpu::radiosity::{indirect, posed_points, sender_direct, Frame, Hierarchy, RadiosityParams};
use prm_runtime::cpu::CpuTwin;
use prm_runtime::radiosity::RadiosityPass;
use prm_runtime::Gpu;

/// The level, its texels, visibility and hierarchy, and the rig's motion.
pub struct MovingLevel {
    pub scene: Scene,
    pub texels: TexelSet,
    pub vis: Visibility,
    pub hierarchy: Hierarchy,
    pub rig: Rig,
    pub motion: Motion,
}

/// Where a frame runs on the GPU: the adapter, the level's pass and its shadow maps' size.
pub struct GpuFrame<'a> {
    pub gpu: &'a Gpu,
    pub pass: &'a mut RadiosityPass,
    pub shadow_size: u32,
}

/// One frame of a [`MovingLevel`].
pub struct FrameEval {
    pub lights: Vec<prm::Light>,
    pub posed: Scene,
    pub bvh: Bvh,
    /// Indirect irradiance per texel.
    pub indirect: Vec<Vec3>,
    /// Direct light at the texels: shadow maps and the texel pass on the GPU (waited for),
    /// rays on the CPU.
    pub direct_s: f64,
    pub radiosity_s: f64,
    /// Node transfers (CPU radiosity only).
    pub transfers: Option<u64>,
    /// (error, bias, ground-truth noise) of the radiosity, with a ground truth.
    pub error: Option<(f64, f64, f64)>,
    /// (error, bias) of the PRM at rest on the same texels, with a ground truth and a map.
    pub prm_error: Option<(f64, f64)>,
}

impl MovingLevel {
    /// `rig_path` only names the rig in messages.
    pub fn new(
        scene: Scene,
        texels: TexelSet,
        vis: Visibility,
        rig: Rig,
        rig_path: &Path,
    ) -> Result<MovingLevel> {
        vis.check_objects(&scene, &texels.texels).map_err(|e| {
            anyhow!(
                "the visibility does not fit the level's movable objects: {e}; run `prm visibility` again"
            )
        })?;
        let motion = rig.object_motion(rig_path, &scene)?;
        let hierarchy = Hierarchy::build(&scene, &texels);
        Ok(MovingLevel { scene, texels, vis, hierarchy, rig, motion })
    }

    /// The level `args` with its visibility file `vis_path` (the level loaded at the file's
    /// atlas, its texels checked against it) and the rig `rig` (the level's lights without one).
    pub fn load(args: &crate::common::SceneArgs, vis_path: &Path, rig: Option<&Path>) -> Result<MovingLevel> {
        let (w, h) = prm::visibility::visibility_atlas(vis_path)?;
        crate::common::check_atlas(w)?;
        if h != w {
            anyhow::bail!("{}: a {w} x {h} atlas; visibility files hold square atlases", vis_path.display());
        }
        let scene = crate::common::load(args, w, false)?;
        let texels = prm_precompute::visibility::moving_texel_set(&scene, w, h);
        let vis = prm::visibility::read_visibility(
            vis_path,
            prm::fingerprint::geometry_fingerprint(&scene),
            texels.len(),
        )?;
        let rig_data = crate::common::load_rig(rig, &scene)?;
        MovingLevel::new(scene, texels, vis, rig_data, rig.unwrap_or(Path::new("(no rig)")))
    }

    /// The frame at `time` seconds (module doc). `gpu` runs the radiosity there; `gt_spp`
    /// measures it (with `seed`), and `baseline` the PRM's twin beside it.
    #[allow(clippy::too_many_arguments)]
    pub fn frame(
        &self,
        time: f64,
        params: &RadiosityParams,
        gpu: Option<GpuFrame<'_>>,
        gt_spp: Option<u32>,
        seed: u64,
        baseline: Option<&mut CpuTwin>,
    ) -> Result<FrameEval> {
        let lights = self.rig.at_time(time);
        let moves = self.motion.at_time(time);
        let poses = Poses::new(&moves);
        let posed = self.scene.moved(&moves);
        let bvh = Bvh::build_with_extent(&posed, self.scene.diagonal());
        let points = posed_points(&self.scene, &self.texels, &poses);
        let frame = Frame { poses: &poses, points: &points };
        let (indirect, transfers, direct_s, radiosity_s) = match gpu {
            Some(GpuFrame { gpu: g, pass, shadow_size }) => {
                let t = Instant::now();
                pass.light_texels(&g.device, &g.queue, &posed, &poses, &lights, shadow_size)?;
                let _ = g.device.poll(wgpu::PollType::wait_indefinitely());
                let direct_s = t.elapsed().as_secs_f64();
                let t = Instant::now();
                let e = pass.indirect_lit(&g.device, &g.queue, params)?;
                (e, None, direct_s, t.elapsed().as_secs_f64())
            }
            None => {
                let t = Instant::now();
                // What each texel sends with: its direct light averaged over its shape.
                let direct = sender_direct(&self.scene, &self.texels, &self.hierarchy, &frame, &bvh, &lights);
                let direct_s = t.elapsed().as_secs_f64();
                let t = Instant::now();
                let (e, stats) =
                    indirect(&self.hierarchy, &self.vis, &frame, &direct, params, &self.vis.escape);
                (e, Some(stats.transfers), direct_s, t.elapsed().as_secs_f64())
            }
        };
        let mut out = FrameEval {
            lights,
            posed,
            bvh,
            indirect,
            direct_s,
            radiosity_s,
            transfers,
            error: None,
            prm_error: None,
        };
        if let Some(spp) = gt_spp {
            let mut moved = self.texels.texels.clone();
            for (m, &(p, n)) in moved.iter_mut().zip(&points) {
                m.position = p;
                m.normal = n;
            }
            let mut lit = out.posed.clone();
            lit.lights = out.lights.clone();
            let gt = Tracer::new(&lit, &out.bvh, GtParams { spp, seed, ..GtParams::preview() })
                .texels(&moved, self.texels.width, Control::none())
                .map_err(|_| anyhow!("ground truth stopped"))?;
            let truth: Vec<Vec3> = gt.iter().map(|g| g.indirect).collect();
            let noise = indirect_noise(&gt);
            let denoise = |e: f64| (e * e - noise * noise).max(0.0).sqrt();
            let c = prm::metric::compare(&out.indirect, &truth, None);
            out.error = Some((denoise(c.error), c.bias, noise));
            if let Some(twin) = baseline {
                let img = twin.frame(&out.lights);
                let w = self.texels.width;
                let prm_ind: Vec<Vec3> =
                    self.texels.texels.iter().map(|t| img[(t.j * w + t.i) as usize]).collect();
                let c = prm::metric::compare(&prm_ind, &truth, None);
                out.prm_error = Some((denoise(c.error), c.bias));
            }
        }
        Ok(out)
    }
}
