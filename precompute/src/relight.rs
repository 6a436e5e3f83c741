//! Exact cluster weights on the CPU: each entry's irradiance from the real lights with
//! ray-traced visibility, and the indirect lightmap they give with every pane. This is what
//! the runtime approximates with shadow maps and top-K selection; the precompute's error is
//! measured with it.

use glam::Vec3;
use prm::prm_file::Prm;
use prm::{Bvh, Light};
use rayon::prelude::*;

/// Irradiance (W/m²) at every entry from `lights`, with shadow rays.
pub fn entry_irradiance(prm: &Prm, bvh: &Bvh, lights: &[Light]) -> Vec<Vec3> {
    prm.entries
        .par_iter()
        .map(|e| {
            let mut sum = Vec3::ZERO;
            for l in lights {
                let inc = l.incident(e.position);
                let cos = e.normal.dot(inc.to_light);
                if cos <= 0.0 || inc.irradiance == Vec3::ZERO {
                    continue;
                }
                let visible = if l.is_positional() { bvh.visible_point(e.position, e.normal, l.position) } else { bvh.visible_dir(e.position, e.normal, inc.to_light) };
                if visible {
                    sum += inc.irradiance * cos;
                }
            }
            sum
        })
        .collect()
}

/// The indirect lightmap (full atlas, row-major) for these lights, with all panes weighted by
/// their members' mean irradiance.
pub fn indirect_lightmap(prm: &Prm, bvh: &Bvh, lights: &[Light]) -> Vec<Vec3> {
    let e = entry_irradiance(prm, bvh, lights);
    prm.compose(&prm.cluster_weights(&e))
}
