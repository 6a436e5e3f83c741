//! The CPU twin proper (feature `cpu-twin`): ray-traced entry irradiance and the per-frame
//! lightmap with the unchanged-frame cache.

use glam::Vec3;
use prm::prm_file::Prm;
use prm::{Bvh, Light};

use crate::Budget;
use rayon::prelude::*;

use super::concentrate::triangle_visibility;
use super::{
    add_and_clamp, compose_local, compose_selected, dipole_moments, dipole_offsets, pane_weights_with,
    select_top_k, LinkLight, NearTables, TileBudget,
};

/// Irradiance of every entry point from `lights`: the power its cell receives (ray-traced
/// visibility, [`prm::bvh::cell_power`]) over the entry's area, as the GPU pass computes it.
pub fn entry_irradiance(prm: &Prm, bvh: &Bvh, lights: &[Light]) -> Vec<Vec3> {
    let cells = prm.cells();
    prm.entries()
        .par_iter()
        .enumerate()
        .map(
            |(j, e)| {
                if e.area > 0.0 {
                    prm::bvh::cell_power(bvh, lights, cells.of(j)) / e.area
                } else {
                    Vec3::ZERO
                }
            },
        )
        .collect()
}

/// The light on the near-field links of hot cells ([`LinkLight`]), each cell triangle's
/// visibility ray-traced from its centroid as for the entries' irradiance.
pub fn link_light(
    prm: &Prm,
    bvh: &Bvh,
    tables: &NearTables,
    entry_irradiance: &[Vec3],
    lights: &[Light],
) -> LinkLight {
    let visible = |c: Vec3, n: Vec3, l: &Light| {
        if l.is_positional() {
            bvh.visible_point(c, n, l.position)
        } else {
            bvh.visible_dir(c, n, -l.direction)
        }
    };
    LinkLight::new(prm, tables, entry_irradiance, |t| triangle_visibility(t, lights, visible), lights)
}

/// The per-frame CPU lightmap, remembering the last lights to skip unchanged frames.
pub struct CpuTwin<'a> {
    prm: &'a Prm,
    bvh: &'a Bvh,
    top_k: usize,
    layout: prm::prm_file::TileLayout,
    last_lights: Option<Vec<Light>>,
    lightmap: Vec<Vec3>,
    /// Composes performed (a frame with unchanged lights adds none).
    pub composes: usize,
    /// Clusters composed in the last compose (under a local budget: kept at some vertex).
    pub last_selected: usize,
    residual: bool,
    budget: Budget,
    tile_budget: Option<TileBudget>,
    near: NearTables,
}

impl<'a> CpuTwin<'a> {
    /// A twin composing the `top_k` strongest panes (all of them when `top_k` >= C).
    pub fn new(prm: &'a Prm, bvh: &'a Bvh, top_k: usize) -> Self {
        let n = prm.texel_count();
        CpuTwin {
            prm,
            bvh,
            top_k,
            layout: prm.layout(),
            last_lights: None,
            lightmap: vec![Vec3::ZERO; n],
            composes: 0,
            last_selected: 0,
            residual: true,
            budget: Budget::default(),
            tile_budget: None,
            near: NearTables::new(prm),
        }
    }

    /// Whether groups stand in for the clusters left out (default true); the next frame
    /// recomposes.
    pub fn set_residual(&mut self, on: bool) {
        self.residual = on;
        self.last_lights = None;
    }

    /// Where the budget of `top_k` panes applies (default local: at each tile grid vertex); the next frame
    /// recomposes.
    pub fn set_budget(&mut self, budget: Budget) {
        self.budget = budget;
        self.last_lights = None;
    }

    /// The indirect lightmap (full atlas, row-major, W/m²) for these lights.
    pub fn frame(&mut self, lights: &[Light]) -> &[Vec3] {
        if self.last_lights.as_deref() == Some(lights) {
            return &self.lightmap;
        }
        let e = entry_irradiance(self.prm, self.bvh, lights);
        let link_light = link_light(self.prm, self.bvh, &self.near, &e, lights);
        let moments = dipole_moments(self.prm, &self.near, &e);
        let lin = dipole_offsets(self.prm, &self.near, &moments);
        let (w, near) = pane_weights_with(self.prm, &self.near, &link_light, &e, &lin);
        if self.budget == Budget::Local {
            let budget = self.tile_budget.get_or_insert_with(|| TileBudget::new(self.prm, &self.layout));
            let local =
                compose_local(self.prm, budget, &self.layout, &w, &moments, self.top_k, self.residual);
            self.lightmap = local.lightmap;
            self.last_selected = local.kept.iter().filter(|&&c| c).count();
        } else {
            let energies: Vec<f32> = self.prm.clusters().iter().map(|c| c.energy).collect();
            let selected = select_top_k(&w, &energies, self.top_k);
            let mut chosen = vec![false; w.len()];
            for &c in &selected {
                chosen[c] = true;
            }
            self.lightmap = compose_selected(self.prm, &w, &moments, &chosen, self.residual, &self.layout);
            self.last_selected = selected.len();
        }
        add_and_clamp(&mut self.lightmap, &near);
        self.composes += 1;
        self.last_lights = Some(lights.to_vec());
        &self.lightmap
    }
}
