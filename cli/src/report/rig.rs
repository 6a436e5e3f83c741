//! The report's moving-light rig: per frame, the error of PRM top-32, PRM all panes and the
//! reference, and their flicker from one frame to the next.

use std::path::Path;

use anyhow::{bail, Result};
use glam::Vec3;
use prm::prm_file::Prm;
use prm::rig::Rig;
use prm::{luminance, Light, Scene};
use prm_runtime::{Gpu, Runtime, RuntimeParams};

use super::measure::{at_texels, compare_texels, ground_truth, reference, runtime_lightmap, Level};
use super::Budget;

pub struct Frame {
    pub gt_noise: f64,
    /// (PRM top-32, PRM all, reference) error
    pub errors: [f64; 3],
    /// Their biases (signed, over the ground truth's mean), in the same order.
    pub biases: [f64; 3],
    /// Per-texel signed luminance error of each, for flicker.
    pub residuals: [Vec<f32>; 3],
    pub gt_mean: f64,
    pub gt: Vec<f32>,
}

/// The level's first light sweeping across the middle 40 % of the level's width.
pub fn default_rig(scene: &Scene) -> Result<Rig> {
    let Some(first) = scene.lights.first() else { bail!("the level has no lights; give a --rig") };
    let (lo, hi) = scene.bounds();
    let dx = (hi.x - lo.x) * 0.2;
    let json = if first.is_positional() {
        let p = first.position;
        format!(
            r#"{{"lights": [{{"name": {:?}, "keyframes": [{{"time": 0, "position": [{}, {}, {}]}}, {{"time": 1, "position": [{}, {}, {}]}}]}}]}}"#,
            first.name,
            p.x - dx,
            p.y,
            p.z,
            p.x + dx,
            p.y,
            p.z
        )
    } else {
        let d = first.direction;
        format!(
            r#"{{"lights": [{{"name": {:?}, "keyframes": [{{"time": 0, "direction": [{}, {}, {}]}}, {{"time": 1, "direction": [{}, {}, {}]}}]}}]}}"#,
            first.name,
            d.x - 0.2,
            d.y,
            d.z,
            d.x + 0.2,
            d.y,
            d.z
        )
    };
    Ok(Rig::parse(Path::new("(default rig)"), &json, &scene.lights)?)
}

/// The GPU runtime the report's frames are composed on (top-32 picked locally + groups, 1024² shadow maps),
/// or none without an adapter (then the CPU twin).
pub fn report_runtime(gpu: Option<&Gpu>, level: &Level, map: &Prm) -> Result<Option<Runtime>> {
    Ok(match gpu {
        Some(g) => Some(Runtime::new(
            &g.device,
            &g.queue,
            &level.scene,
            map,
            RuntimeParams { top_k: 32, shadow_size: 1024, residual: true, ..Default::default() },
        )?),
        None => None,
    })
}

/// Every frame of the rig, measured: on the GPU runtime when there is one (else the CPU twin).
pub fn rig_frames(
    b: &Budget,
    level: &Level,
    rig: &Rig,
    map: &Prm,
    gpu: Option<&Gpu>,
    seed: u64,
) -> Result<Vec<Frame>> {
    let mut frames = Vec::new();
    let mut rt = report_runtime(gpu, level, map)?;
    for f in 0..b.rig_frames {
        eprintln!("rig frame {} of {}...", f + 1, b.rig_frames);
        let lights = rig.frame(f, b.rig_frames);
        frames.push(rig_frame(b, level, &lights, map, rt.as_mut(), seed)?);
    }
    Ok(frames)
}

/// One frame of the rig: ground truth, PRM top-32, PRM all panes and the reference.
pub fn rig_frame(
    b: &Budget,
    level: &Level,
    lights: &[Light],
    map: &Prm,
    mut rt: Option<&mut Runtime>,
    seed: u64,
) -> Result<Frame> {
    let (g, g_noise) = ground_truth(level, lights, b.rig_gt_spp, seed)?;
    let top = runtime_lightmap(rt.as_deref_mut(), map, &level.bvh, lights, 32)?;
    let all = runtime_lightmap(rt, map, &level.bvh, lights, usize::MAX)?;
    let rf = reference(level, lights, b.rig_reference, b.atlas, seed)?;
    let top = at_texels(&level.set, &top);
    let all = at_texels(&level.set, &all);
    let res = |x: &[Vec3]| x.iter().zip(&g).map(|(a, b)| luminance(*a) - luminance(*b)).collect::<Vec<f32>>();
    let (top_c, all_c, rf_c) = (compare_texels(&top, &g), compare_texels(&all, &g), compare_texels(&rf, &g));
    Ok(Frame {
        gt_noise: g_noise,
        errors: [top_c.0, all_c.0, rf_c.0],
        biases: [top_c.1, all_c.1, rf_c.1],
        residuals: [res(&top), res(&all), res(&rf)],
        gt_mean: g.iter().map(|v| luminance(*v) as f64).sum::<f64>() / g.len() as f64,
        gt: g.iter().map(|v| luminance(*v)).collect(),
    })
}

/// Per transition f-1 -> f: each method's flicker, and how much the ground truth itself changed
/// (RMS, over its mean): the real change of the lighting.
pub fn flicker(frames: &[Frame]) -> Vec<([f64; 3], f64)> {
    frames
        .windows(2)
        .map(|w| {
            let mean = 0.5 * (w[0].gt_mean + w[1].gt_mean);
            let rms = |a: &[f32], b: &[f32]| {
                (a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64)
                    .sqrt()
            };
            let v = [0, 1, 2].map(|m| {
                if mean > 0.0 {
                    rms(&w[1].residuals[m], &w[0].residuals[m]) / mean
                } else {
                    0.0
                }
            });
            let change = rms(&w[1].gt, &w[0].gt);
            (v, if mean > 0.0 { change / mean } else { 0.0 })
        })
        .collect()
}
