//! One measurement of the report: a method's lightmap at the covered texels, against the ground
//! truth computed the same way for every part.

use anyhow::{anyhow, bail, Result};
use glam::Vec3;
use prm::prm_file::Prm;
use prm::{Bvh, Light, Scene, TexelSet};
use prm_precompute::ground_truth::{GtParams, Tracer};
use prm_precompute::parallel::Control;
use prm_precompute::reference::bake::{evaluate, virtual_lights, BakeParams};
use prm_runtime::cpu::CpuTwin;
use prm_runtime::Runtime;

/// The level as every measurement sees it: its triangles, their BVH and the covered texels.
pub struct Level {
    pub scene: Scene,
    pub bvh: Bvh,
    pub set: TexelSet,
}

impl Level {
    /// The BVH and the texel set at `atlas`²; a level without texels there is refused.
    pub fn new(scene: Scene, atlas: u32) -> Result<Level> {
        let bvh = Bvh::build(&scene);
        let set = TexelSet::build_visible(&scene, &bvh, atlas, atlas);
        if set.is_empty() {
            bail!("the level has no lightmap texels at {}^2", atlas);
        }
        Ok(Level { scene, bvh, set })
    }

    /// The level with the texels of `map`'s atlas (one page or several), as `prm evaluate`
    /// measures it.
    pub fn for_map(scene: Scene, map: &Prm) -> Result<Level> {
        let bvh = Bvh::build(&scene);
        let h = map.header();
        let set = TexelSet::build_visible(&scene, &bvh, h.atlas_width, h.atlas_height);
        if set.is_empty() {
            bail!("the level has no lightmap texels in its map's atlas");
        }
        Ok(Level { scene, bvh, set })
    }
}

/// Ground-truth indirect irradiance per covered texel, and its noise in the metric's units.
pub fn ground_truth(level: &Level, lights: &[Light], spp: u32, seed: u64) -> Result<(Vec<Vec3>, f64)> {
    let mut lit = level.scene.clone();
    lit.lights = lights.to_vec();
    let tracer = Tracer::new(&lit, &level.bvh, GtParams { spp, seed, ..GtParams::default() });
    let v = tracer
        .texels(&level.set.texels, level.set.width, Control::none())
        .map_err(|_| anyhow!("ground truth stopped"))?;
    Ok((v.iter().map(|r| r.indirect).collect(), prm_precompute::ground_truth::indirect_noise(&v)))
}

pub fn at_texels(set: &TexelSet, img: &[Vec3]) -> Vec<Vec3> {
    set.texels.iter().map(|t| img[(t.j * set.width + t.i) as usize]).collect()
}

pub fn compare(set: &TexelSet, img: &[Vec3], gt: &[Vec3]) -> (f64, f64) {
    compare_texels(&at_texels(set, img), gt)
}

pub fn compare_texels(a: &[Vec3], gt: &[Vec3]) -> (f64, f64) {
    let c = prm::metric::compare(a, gt, None);
    (c.error, c.bias)
}

/// The reference baker's indirect irradiance per covered texel, with `(photons, VPLs per
/// virtual light)`.
pub fn reference(
    level: &Level,
    lights: &[Light],
    (photons, cluster): (usize, usize),
    atlas: u32,
    seed: u64,
) -> Result<Vec<Vec3>> {
    let p = BakeParams {
        photons,
        cluster_size: cluster,
        atlas: prm::density::Atlas::single(atlas),
        seed,
        indirect_only: true,
        ..BakeParams::default()
    };
    p.validate().map_err(|e| anyhow!("bad reference parameter: {e}"))?;
    let (scene, bvh) = (&level.scene, &level.bvh);
    let vl = virtual_lights(scene, bvh, lights, &p);
    let baked = evaluate(scene, bvh, &level.set, lights, &vl, &p, Control::none())
        .map_err(|_| anyhow!("reference stopped"))?;
    Ok(baked.indirect)
}

/// The runtime's lightmap for these lights and top-K: the GPU's if there is one.
pub fn runtime_lightmap(
    rt: Option<&mut Runtime>,
    map: &Prm,
    bvh: &Bvh,
    lights: &[Light],
    k: usize,
) -> Result<Vec<Vec3>> {
    match rt {
        Some(rt) => {
            rt.set_top_k(k)?;
            rt.update(lights)?;
            Ok(rt.read_lightmap()?)
        }
        None => Ok(CpuTwin::new(map, bvh, k).frame(lights).to_vec()),
    }
}
