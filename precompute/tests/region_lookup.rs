//! `transport::RegionLookup` (which entry owns a surface point) against a brute-force twin of
//! its documented rule, over every texel of the bundled levels, and its empty cases.

use glam::Vec3;
use prm::prm_file::Entry;
use prm::{Bvh, Scene, TexelSet};
use prm_precompute::transport::{RegionLookup, TransportStats};

/// The rule, over all entries and without a grid: among entries whose normal is within 60
/// degrees of the point's (cos >= 0.5), nearest first (ties to the lower index), the first of
/// the 4 nearest that is visible from the point; if none of those is, the nearest; `None` when
/// no entry is compatible.
fn owner_brute_force(entries: &[Entry], p: Vec3, n: Vec3, bvh: &Bvh) -> Option<u32> {
    let mut c: Vec<(f32, u32)> = entries
        .iter()
        .enumerate()
        .filter(|(_, e)| e.normal.dot(n) >= 0.5)
        .map(|(i, e)| ((e.position - p).length_squared(), i as u32))
        .collect();
    c.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    c.iter()
        .take(4)
        .find(|&&(_, i)| bvh.visible(p, n, entries[i as usize].position, entries[i as usize].normal))
        .or(c.first())
        .map(|&(_, i)| i)
}

fn level(name: &str) -> Scene {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    prm::gltf_load::load_scene(root.join("assets").join(name), &Default::default()).unwrap()
}

#[test]
fn owners_equal_the_brute_force_rule_on_every_texel() {
    for (name, n) in [("two_rooms.glb", 512), ("cornell.glb", 300)] {
        let scene = level(name);
        let bvh = Bvh::build(&scene);
        let entries = prm_precompute::entries::sample_entries(&scene, n, 0);
        let lookup = RegionLookup::new(&entries, scene.total_area());
        let set = TexelSet::build(&scene, 48, 48);
        let stats = TransportStats::default();
        let (mut behind, mut owned) = (0, 0);
        for t in &set.texels {
            let want = owner_brute_force(&entries, t.position, t.normal, &bvh);
            let got = lookup.owner(t.position, t.normal, &bvh, &stats);
            assert_eq!(got, want, "{name}: texel ({}, {}) at {}", t.i, t.j, t.position);
            owned += got.is_some() as usize;
            // How often visibility, not distance, decided: the nearest compatible entry is hidden.
            let nearest = entries
                .iter()
                .enumerate()
                .filter(|(_, e)| e.normal.dot(t.normal) >= 0.5)
                .min_by(|a, b| {
                    (a.1.position - t.position)
                        .length_squared()
                        .total_cmp(&(b.1.position - t.position).length_squared())
                        .then(a.0.cmp(&b.0))
                })
                .map(|(i, _)| i as u32);
            behind += (got != nearest) as usize;
        }
        // Every texel has a compatible entry in these closed levels; and the visibility branch
        // is exercised (near corners and behind walls the nearest entry is hidden).
        assert_eq!(owned, set.len(), "{name}: texels without an owner");
        assert!(behind > 0, "{name}: visibility never decided an owner");
    }
}

#[test]
fn no_entries_or_no_compatible_entry_means_no_owner() {
    let scene = level("cornell.glb");
    let bvh = Bvh::build(&scene);
    let stats = TransportStats::default();
    let p = Vec3::new(0.2, 0.0, 0.2);
    assert_eq!(RegionLookup::new(&[], scene.total_area()).owner(p, Vec3::Y, &bvh, &stats), None);
    // Entries all facing more than 60 degrees away from the point's normal.
    let entries: Vec<Entry> = (0..20)
        .map(|i| Entry {
            position: p + Vec3::new(i as f32 * 0.01, 0.0, 0.0),
            normal: Vec3::new(1.0, 0.55, 0.0).normalize(),
            albedo: Vec3::ONE,
            area: 0.01,
            triangle: 0,
        })
        .collect();
    assert!(entries[0].normal.dot(Vec3::Y) < 0.5);
    let lookup = RegionLookup::new(&entries, scene.total_area());
    assert_eq!(lookup.owner(p, Vec3::Y, &bvh, &stats), None);
    assert_eq!(owner_brute_force(&entries, p, Vec3::Y, &bvh), None);
    // ...but a point facing them is owned (the same lookup, so the None above is the normals).
    assert!(lookup.owner(p, entries[0].normal, &bvh, &stats).is_some());
}
