//! The report's light placement (issue 12): error against where the light is, as a level
//! designer places it. Two sets of placements, each measured like a frame of the rig (ground
//! truth, PRM all panes and top-32, reference):
//!
//! - every keyframe of the level's torch rig (`<level>_torches.json` beside the level, or
//!   `--torches`): mid-room, along walls, over floors, in corners, under the ceiling;
//! - a height sweep: the torch at its lowest keyframe's spot, raised from 2 cm to 2 m above the
//!   surface under it (placements above the level's top are left out).
//!
//! Each placement states its distance to the nearest surface (brute force over the triangles).

use std::path::{Path, PathBuf};

use anyhow::Result;
use glam::Vec3;
use prm::prm_file::Prm;
use prm::rig::Rig;
use prm_runtime::Gpu;

use super::measure::Level;
use super::rig::{report_runtime, rig_frame, Frame};
use super::Budget;

pub struct Placement {
    pub label: String,
    /// Distance from the light to the nearest surface (scene units).
    pub distance: f32,
    /// From the height sweep (else a keyframe of the torch rig).
    pub sweep: bool,
    pub frame: Frame,
}

/// `<dir>/<stem>_torches.json` beside the level, if there is one.
pub fn torch_rig_beside(scene: &Path) -> Option<PathBuf> {
    let stem = scene.file_stem()?.to_string_lossy().into_owned();
    let p = scene.with_file_name(format!("{stem}_torches.json"));
    p.is_file().then_some(p)
}

/// Every placement of the torch rig's first animated light, measured.
pub fn placements(
    b: &Budget,
    level: &Level,
    torches: &Rig,
    map: &Prm,
    gpu: Option<&Gpu>,
    seed: u64,
) -> Result<Vec<Placement>> {
    let Some(k) = torches.lights.iter().position(|l| !l.keys.is_empty()) else { return Ok(Vec::new()) };
    let keys: Vec<(f64, Vec3)> = torches.lights[k].keys.iter().map(|key| (key.0, key.1)).collect();
    let mut rt = report_runtime(gpu, level, map)?;
    let mut todo: Vec<(String, bool, Vec<prm::Light>)> = keys
        .iter()
        .enumerate()
        .map(|(i, &(t, _))| (format!("torch rig keyframe {i}"), false, torches.at_time(t)))
        .collect();
    // The sweep: straight up from the lowest keyframe's spot.
    if let Some(&(t, low)) = keys.iter().min_by(|a, b| a.1.y.total_cmp(&b.1.y)) {
        let floor = low.y - level.scene.nearest_surface_distance(low);
        let top = level.scene.bounds().1.y;
        for &h in &b.placement_heights {
            let p = Vec3::new(low.x, floor + h, low.z);
            if p.y >= top - 0.01 * (top - floor) {
                continue;
            }
            let mut lights = torches.at_time(t);
            lights[k].position = p;
            todo.push((format!("{h} above the surface"), true, lights));
        }
    }
    let mut out = Vec::new();
    for (i, (label, sweep, lights)) in todo.into_iter().enumerate() {
        eprintln!("light placement {} ({label})...", i + 1);
        let distance = level.scene.nearest_surface_distance(lights[k].position);
        let frame = rig_frame(b, level, &lights, map, rt.as_mut(), seed)?;
        out.push(Placement { label, distance, sweep, frame });
    }
    Ok(out)
}
