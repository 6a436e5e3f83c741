//! Levels of many rooms (issue 13): generated lightmap UVs keep each room's texels together in
//! the atlas, and the density defaults give every room the same texels per square metre.

use std::collections::HashMap;

use prm::gltf_load::{load_scene, LoadOptions};
use prm::{Scene, TexelSet};
use prm_precompute::scenes::halls;

/// A small variant of the bundled halls (2 x 2 halls, coarse pillars) loaded as the CLI loads
/// a level without `TEXCOORD_1` and without `--atlas`: UVs generated at the density's size.
fn small_halls(dir: &std::path::Path, texel_size: f32) -> Scene {
    let path = dir.join("halls.glb");
    std::fs::write(&path, halls(2, 2, 8, 2).to_glb()).unwrap();
    let opts = LoadOptions { unwrap_resolution: None, texel_size, ..Default::default() };
    load_scene(&path, &opts).unwrap()
}

/// Which hall (of the 13 m grid) a world point is in; corridors count with the hall before them.
fn hall_of(p: glam::Vec3) -> (i32, i32) {
    ((p.x / 13.0).floor() as i32, (p.z / 13.0).floor() as i32)
}

#[test]
fn generated_uvs_keep_each_hall_together_in_the_atlas() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_halls(dir.path(), 0.25);
    let atlas = scene.report.generated_atlas.expect("UVs were generated");
    assert_eq!(Ok(atlas), prm::density::atlas_side(&scene, 0.25));
    assert!(prm::uv::find_overlaps(&scene).is_empty(), "generated UVs overlap");
    let set = TexelSet::build(&scene, atlas, atlas);
    // Per 16-texel atlas tile, the halls whose texels it holds.
    let tile = 16;
    let mut halls_in: HashMap<(u32, u32), Vec<(i32, i32)>> = HashMap::new();
    for t in &set.texels {
        let h = hall_of(t.position);
        let v = halls_in.entry((t.i / tile, t.j / tile)).or_default();
        if !v.contains(&h) {
            v.push(h);
        }
    }
    let shared = halls_in.values().filter(|v| v.len() > 1).count();
    let fraction = shared as f64 / halls_in.len() as f64;
    // Zone by zone, tiles are shared only along the borders of the zones' rectangles (a zone
    // is 6 tiles across at this size): 0.29 of the occupied tiles. Packed chart by chart, by
    // size, as uvunwrap does unaided: 0.61.
    assert!(fraction <= 0.4, "{shared} of {} occupied tiles hold texels of several halls", halls_in.len());
}

#[test]
fn density_gives_the_texel_size_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    for texel in [0.18f32, 0.3] {
        let scene = small_halls(dir.path(), texel);
        let atlas = scene.report.generated_atlas.unwrap();
        let set = TexelSet::build(&scene, atlas, atlas);
        // World size of a covered texel: within 15 % of what was asked (the packing's coverage
        // is an estimate, and the side a multiple of 16).
        let size = (scene.total_area() / set.len() as f64).sqrt();
        assert!((size / texel as f64 - 1.0).abs() <= 0.15, "asked {texel} m, got {size:.3} m at {atlas}^2");
    }
}
