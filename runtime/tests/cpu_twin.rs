//! The CPU twin: top-K with K = C is the full sum, selection order, and an unchanged frame
//! does no compose work.

mod common;
use common::open_box;
use std::sync::atomic::AtomicBool;

use glam::Vec3;
use prm::{Bvh, Scene};
use prm_runtime::cpu::{self, entry_irradiance, select_top_k, CpuTwin};

fn bake(scene: &Scene) -> prm::prm_file::Prm {
    let bvh = Bvh::build(scene);
    let p = prm_precompute::precompute::PrecomputeParams {
        entries: 256,
        paths: 16,
        clusters: 24,
        atlas: 24,
        ..Default::default()
    };
    prm_precompute::precompute::precompute(scene, &bvh, &p, &|_, _, _| {}, &AtomicBool::new(false)).unwrap().0
}

#[test]
fn top_k_equal_to_c_is_the_full_sum_and_smaller_k_takes_the_strongest() {
    let scene = open_box();
    let prm = bake(&scene);
    let bvh = Bvh::build(&scene);
    let e = entry_irradiance(&prm, &bvh, &scene.lights);
    let w = cpu::cluster_weights(&prm, &e);
    let full = cpu::compose(&prm, &w);
    let mut twin = CpuTwin::new(&prm, &bvh, prm.clusters().len());
    let all = twin.frame(&scene.lights).to_vec();
    for (a, b) in all.iter().zip(&full) {
        assert!((*a - *b).abs().max_element() <= 1e-5 * b.max_element().max(1e-6), "{a} vs {b}");
    }
    // The K strongest carry the most light, strongest first.
    let energies: Vec<f32> = prm.clusters().iter().map(|c| c.energy).collect();
    let top = select_top_k(&w, &energies, 4);
    assert_eq!(top.len(), 4);
    let score = |c: usize| prm::luminance(w[c]) * energies[c];
    assert!(top.windows(2).all(|p| score(p[0]) >= score(p[1])));
    assert!((0..w.len()).filter(|c| !top.contains(c)).all(|c| score(c) <= score(top[3])));
    // Zero-weight clusters are never selected.
    let zero: Vec<Vec3> =
        w.iter().enumerate().map(|(c, x)| if c % 2 == 0 { Vec3::ZERO } else { *x }).collect();
    assert!(select_top_k(&zero, &energies, 100).iter().all(|c| c % 2 == 1));
}

#[test]
fn an_unchanged_frame_does_no_compose_work() {
    let scene = open_box();
    let prm = bake(&scene);
    let bvh = Bvh::build(&scene);
    let mut twin = CpuTwin::new(&prm, &bvh, 32);
    let first = twin.frame(&scene.lights).to_vec();
    assert_eq!(twin.composes, 1);
    let again = twin.frame(&scene.lights).to_vec();
    assert_eq!(twin.composes, 1, "same lights: no compose");
    assert_eq!(first, again);
    let mut moved = scene.lights.clone();
    moved[0].position.x -= 0.3;
    let third = twin.frame(&moved).to_vec();
    assert_eq!(twin.composes, 2);
    assert_ne!(first, third, "a moved light changes the lightmap");
    assert!(third.iter().all(|v| v.is_finite() && v.min_element() >= 0.0));
}
