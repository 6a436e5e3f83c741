//! The CPU twin proper (feature `cpu-twin`): ray-traced entry irradiance and the per-frame
//! lightmap with the unchanged-frame cache.

use glam::Vec3;
use prm::cell_light::TriangleLight;
use prm::prm_file::Prm;
use prm::{Bvh, Light};

use crate::Budget;
use rayon::prelude::*;

use super::{
    add_and_clamp, compose_local, compose_selected, pane_weights_with, select_top_k, sight_eye, sighted,
    LightSight, LinkLight, NearTables, TileBudget, UpClose,
};

/// The light on every cell triangle ([`prm::prm_file::Cells`] order) from `lights`, each
/// visibility test a shadow ray ([`prm::bvh::cell_triangle_light`]), as the GPU's entry pass
/// computes it with shadow maps.
pub fn cell_lights(prm: &Prm, bvh: &Bvh, lights: &[Light]) -> Vec<TriangleLight> {
    prm.cells().triangles.par_iter().map(|t| prm::bvh::cell_triangle_light(bvh, lights, t)).collect()
}

/// Irradiance of every entry point from `lights`: the power its cell receives (ray-traced
/// visibility, [`cell_lights`]) over the entry's area, as the GPU pass computes it.
pub fn entry_irradiance(prm: &Prm, bvh: &Bvh, lights: &[Light]) -> Vec<Vec3> {
    entry_irradiance_from(prm, &cell_lights(prm, bvh, lights))
}

/// The entries' irradiance from their cell triangles' light.
pub fn entry_irradiance_from(prm: &Prm, cell_lights: &[TriangleLight]) -> Vec<Vec3> {
    let cells = prm.cells();
    prm.entries()
        .iter()
        .enumerate()
        .map(|(j, e)| {
            if e.area > 0.0 {
                let of = &cell_lights[cells.first[j] as usize..cells.first[j + 1] as usize];
                of.iter().map(|t| t.power).sum::<Vec3>() / e.area
            } else {
                Vec3::ZERO
            }
        })
        .collect()
}

/// The light on the near-field links of hot cells ([`LinkLight`]), each cell triangle's
/// light ray-traced as for the entries' irradiance ([`cell_lights`]).
pub fn link_light(
    prm: &Prm,
    bvh: &Bvh,
    tables: &NearTables,
    entry_irradiance: &[Vec3],
    lights: &[Light],
) -> LinkLight {
    let mut l = LinkLight::new(prm, tables, entry_irradiance, &cell_lights(prm, bvh, lights), lights);
    l.sight = light_sight(prm, bvh, tables, lights);
    l
}

/// How the far texels see the lights ([`LightSight`]): the first [`super::CLOSE_SIGHTS`] point
/// and spot lights that light a cell up close from their eyes ([`sight_eye`], [`UpClose`]; on
/// the GPU each has a cube of shadow maps there, a spot's besides its frustum:
/// `crate::lights::layers`), each seen from a far texel where a ray from it reaches the eye
/// (the GPU: the cube's shadow maps there), for the lights that light some cell up close.
pub fn light_sight(prm: &Prm, bvh: &Bvh, tables: &NearTables, lights: &[Light]) -> LightSight {
    let up = UpClose::new(prm, tables);
    let first_hit = |o: Vec3, d: Vec3, tmax: f32| bvh.closest_hit(o, d, tmax).map(|h| h.t);
    let eye: Vec<Vec3> = lights.iter().map(|l| sight_eye(l, first_hit, up.spacing())).collect();
    let close = up.lights(lights, &eye);
    let at: Vec<Option<Light>> = lights
        .iter()
        .zip(sighted(&close))
        .zip(&close)
        .map(|((l, seen), &close)| {
            // Every light up close has a cube (a spot's besides its frustum).
            debug_assert!(!close || crate::lights::layers(l, 1, close) >= crate::contract::CUBE_LAYERS);
            seen.then(|| l.clone())
        })
        .collect();
    let mut sight = LightSight { at, eye, seen: vec![Vec::new(); lights.len()] };
    let mut used = vec![false; lights.len()];
    for (j, e) in prm.entries().iter().enumerate() {
        if let Some(k) = sight.lit_by(tables.centroid[j], e.normal, tables.size[j]) {
            used[k as usize] = true;
        }
    }
    let texels = &prm.far().texels;
    for (k, &eye) in sight.eye.iter().enumerate() {
        if used[k] {
            sight.seen[k] = texels
                .par_iter()
                .map(|t| bvh.visible_point(t.position, t.normal, eye) as u8 as f32)
                .collect();
        }
    }
    sight
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
        let cell_lights = cell_lights(self.prm, self.bvh, lights);
        let e = entry_irradiance_from(self.prm, &cell_lights);
        let mut link_light = LinkLight::new(self.prm, &self.near, &e, &cell_lights, lights);
        link_light.sight = light_sight(self.prm, self.bvh, &self.near, lights);
        let (w, near) = pane_weights_with(self.prm, &self.near, &link_light, &e);
        if self.budget == Budget::Local {
            let budget = self.tile_budget.get_or_insert_with(|| TileBudget::new(self.prm, &self.layout));
            let local = compose_local(self.prm, budget, &self.layout, &w, self.top_k, self.residual);
            self.lightmap = local.lightmap;
            self.last_selected = local.kept.iter().filter(|&&c| c).count();
        } else {
            let energies: Vec<f32> = self.prm.clusters().iter().map(|c| c.energy).collect();
            let selected = select_top_k(&w, &energies, self.top_k);
            let mut chosen = vec![false; w.len()];
            for &c in &selected {
                chosen[c] = true;
            }
            self.lightmap = compose_selected(self.prm, &w, &chosen, self.residual, &self.layout);
            self.last_selected = selected.len();
        }
        add_and_clamp(&mut self.lightmap, &near);
        self.composes += 1;
        self.last_lights = Some(lights.to_vec());
        &self.lightmap
    }
}
