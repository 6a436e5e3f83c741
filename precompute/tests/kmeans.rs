//! Entry clustering (`cluster::cluster_entries`, k-means on `(p / L, n)`, L = sqrt(A / k)):
//! clumps it must recover, the Lloyd fixed point it must stop at, its structure, and its
//! independence of units and thread count.

use glam::Vec3;
use prm::prm_file::Entry;
use prm_precompute::cluster::{cluster_entries, Clustering};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn entry(position: Vec3, normal: Vec3) -> Entry {
    Entry { position, normal, albedo: Vec3::splat(0.5), area: 1.0, triangle: 0 }
}

/// Entries of a bundled level, and its total area.
fn level_entries(n: usize) -> (Vec<Entry>, f64) {
    let scene = prm::gltf_load::load_scene(root().join("assets/two_rooms.glb"), &Default::default()).unwrap();
    (prm_precompute::entries::sample_entries(&scene, n, 3), scene.total_area())
}

/// Assignment and member lists describe the same partition of 0..n into non-empty, ascending
/// clusters, at most `k` of them.
fn assert_structure(c: &Clustering, n: usize, k: usize) {
    assert_eq!(c.assignment.len(), n);
    assert!(!c.members.is_empty() && c.members.len() <= k.max(1), "{} clusters for k = {k}", c.members.len());
    let mut seen = vec![false; n];
    for (ci, m) in c.members.iter().enumerate() {
        assert!(!m.is_empty() || n == 0, "cluster {ci} is empty");
        assert!(m.windows(2).all(|w| w[0] < w[1]), "cluster {ci} not ascending");
        for &i in m {
            assert!(!std::mem::replace(&mut seen[i as usize], true), "entry {i} in two clusters");
            assert_eq!(c.assignment[i as usize], ci as u32, "entry {i}: assignment disagrees with members");
        }
    }
    assert!(seen.iter().all(|&s| s), "an entry is in no cluster");
}

#[test]
fn well_separated_clumps_are_recovered_exactly() {
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    // Five clumps 100 L apart, each 0.02 L across, with the same normal; then five more, as
    // tight, differing from the first five only in normal (opposite faces of a thin wall).
    let (k, l) = (10usize, 1.0f64);
    let mut entries = Vec::new();
    let mut truth = Vec::new();
    for c in 0..k {
        let centre = Vec3::new((c % 5) as f32 * 100.0, 0.0, 0.0);
        let normal = if c < 5 { Vec3::Y } else { -Vec3::Y };
        for _ in 0..20 {
            let jitter = Vec3::new(rng.random(), rng.random(), rng.random()) * 0.02;
            truth.push(c);
            entries.push(entry(centre + jitter, normal));
        }
    }
    // Shuffle, so clumps are not contiguous runs of indices.
    let mut order: Vec<usize> = (0..entries.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.random_range(0..=i));
    }
    let entries: Vec<Entry> = order.iter().map(|&i| entries[i]).collect();
    let truth: Vec<usize> = order.iter().map(|&i| truth[i]).collect();
    for seed in 0..5 {
        let c = cluster_entries(&entries, k, l * l * k as f64, 30, seed);
        assert_structure(&c, entries.len(), k);
        assert_eq!(c.members.len(), k);
        // Same clump <=> same cluster.
        for i in 0..entries.len() {
            for j in 0..i {
                assert_eq!(
                    truth[i] == truth[j],
                    c.assignment[i] == c.assignment[j],
                    "seed {seed}: entries {i} and {j}"
                );
            }
        }
    }
}

#[test]
fn converged_clusters_are_a_lloyd_fixed_point() {
    let (entries, area) = level_entries(800);
    for k in [7usize, 40] {
        // Enough iterations that Lloyd's algorithm converges (it stops early when it does).
        let c = cluster_entries(&entries, k, area, 1000, 9);
        assert_structure(&c, entries.len(), k);
        assert_eq!(c.members.len(), k);
        // The feature space, rebuilt here: position over L = sqrt(A / k), then the normal.
        let l = (area / k as f64).sqrt();
        let feat = |e: &Entry| -> [f64; 6] {
            let p = e.position.as_dvec3() / l;
            [p.x, p.y, p.z, e.normal.x as f64, e.normal.y as f64, e.normal.z as f64]
        };
        let means: Vec<[f64; 6]> = c
            .members
            .iter()
            .map(|m| {
                let mut s = [0.0f64; 6];
                for &i in m {
                    for (a, b) in s.iter_mut().zip(feat(&entries[i as usize])) {
                        *a += b;
                    }
                }
                s.map(|a| a / m.len() as f64)
            })
            .collect();
        let d2 = |a: &[f64; 6], b: &[f64; 6]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>();
        let mut close = 0;
        for (i, e) in entries.iter().enumerate() {
            let f = feat(e);
            let own = d2(&f, &means[c.assignment[i] as usize]);
            for (ci, m) in means.iter().enumerate() {
                let other = d2(&f, m);
                // The code works in f32 (features ~10 in size, centres rounded to f32): 1e-4 in
                // squared feature distance is ~100x its round-off and far below the spacing of
                // the means (~1).
                assert!(
                    own <= other + 1e-4,
                    "k {k}: entry {i} is nearer cluster {ci} ({other}) than its own ({own})"
                );
                close += (ci != c.assignment[i] as usize && other - own < 0.05) as usize;
            }
        }
        // The check is not vacuous: some entries sit near a boundary between two means.
        assert!(close > 0, "k {k}: no entry is near a cluster boundary");
    }
}

#[test]
fn edge_cases_keep_the_structure() {
    let (entries, area) = level_entries(50);
    let empty = cluster_entries(&[], 4, area, 10, 0);
    assert!(empty.assignment.is_empty() && empty.members == vec![Vec::<u32>::new()]);
    for k in [0usize, 1, 2, 49, 50, 80] {
        let c = cluster_entries(&entries, k, area, 10, 0);
        assert_structure(&c, entries.len(), k.min(50));
        match k {
            0 | 1 => assert_eq!(c.members.len(), 1),
            _ if k >= 50 => assert!(c.members.iter().all(|m| m.len() == 1), "k {k}: one entry per cluster"),
            _ => {}
        }
    }
    // All entries at one point: one distinct feature, k asked for 5. Still a partition.
    let same = vec![entry(Vec3::ONE, Vec3::Y); 20];
    assert_structure(&cluster_entries(&same, 5, 4.0, 10, 0), 20, 5);
}

#[test]
fn the_same_clusters_at_any_power_of_two_scale() {
    // Positions x 2^m and area x 4^m scale L by exactly 2^m, so every feature p / L is the same
    // float: the clustering must be identical, not just similar.
    let (entries, area) = level_entries(600);
    let base = cluster_entries(&entries, 24, area, 30, 5);
    for m in [-10i32, -1, 3, 12] {
        let s = 2f32.powi(m);
        let scaled: Vec<Entry> =
            entries.iter().map(|e| Entry { position: e.position * s, area: e.area * s * s, ..*e }).collect();
        assert_eq!(cluster_entries(&scaled, 24, area * 4f64.powi(m), 30, 5), base, "scale 2^{m}");
    }
}

#[test]
fn the_same_clusters_at_one_and_four_threads() {
    let (entries, area) = level_entries(600);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| cluster_entries(&entries, 24, area, 30, 5))
    };
    assert_eq!(run(1), run(4));
}
