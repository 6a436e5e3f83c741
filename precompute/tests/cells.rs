//! Entry cells (`prm_precompute::cells`): on the bundled levels they tile the surface, each
//! entry inside its own cell, every cell facing its entry's way.

use std::path::PathBuf;

use prm::{load_scene, LoadOptions};
use prm_precompute::cells::entry_cells;
use prm_precompute::entries::sample_entries;

#[test]
fn cells_tile_the_levels_and_hold_their_entries() {
    for name in ["cornell.glb", "chamber.glb", "two_rooms.glb"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets").join(name);
        let scene = load_scene(path, &LoadOptions::default()).unwrap();
        let entries = sample_entries(&scene, 2048, 1);
        // Drop every fifth entry, as if enclosed: its cell must go with it.
        let keep: Vec<bool> = (0..entries.len()).map(|j| j % 5 != 0).collect();
        let (all, all_report) = entry_cells(&scene, &entries, &vec![true; entries.len()]);
        let (kept, _) = entry_cells(&scene, &entries, &keep);
        let total = scene.total_area();
        let covered: f64 = (0..entries.len()).map(|j| all.area(j) as f64).sum();
        // The cells and the triangles no entry took add up to the level (f32 corners: 1e-4).
        let sum = covered + all_report.area_without_entry;
        assert!(
            (sum / total - 1.0).abs() < 1e-4,
            "{name}: cells {covered} + left {} vs {total}",
            all_report.area_without_entry
        );
        assert!(
            all_report.area_without_entry < 1e-3 * total,
            "{name}: {} of {total} left out",
            all_report.area_without_entry
        );
        let kept_js: Vec<usize> = (0..entries.len()).filter(|&j| keep[j]).collect();
        assert_eq!(kept.first.len(), kept_js.len() + 1, "{name}");
        // An entry's own region (the fan around it) does not depend on which others are kept
        // (triangles without an entry go to the nearest kept one, so those may move).
        let own = |cell: &[[glam::Vec3; 3]], j: usize| {
            cell.iter().filter(|t| t[0] == entries[j].position).copied().collect::<Vec<_>>()
        };
        for (k, &j) in kept_js.iter().enumerate() {
            assert_eq!(own(kept.of(k), j), own(all.of(j), j), "{name}: entry {j}'s region changed");
        }
        let kept_area: f64 = (0..kept_js.len()).map(|k| kept.area(k) as f64).sum();
        assert!(kept_area < 0.85 * covered, "{name}: dropped entries' cells kept ({kept_area} of {covered})");
        for (j, e) in entries.iter().enumerate() {
            let cell = all.of(j);
            assert!(!cell.is_empty(), "{name}: entry {j} has no cell");
            // Counter-clockwise from the front: every piece faces the entry's way.
            for t in cell {
                let n = (t[1] - t[0]).cross(t[2] - t[0]);
                assert!(n.dot(e.normal) >= 0.0, "{name}: entry {j}: a cell piece faces away");
            }
            // The entry is the fan's apex: it lies in its cell.
            let own = cell.iter().filter(|t| t[0] == e.position).count();
            assert!(own >= 1, "{name}: entry {j} is not in its cell");
        }
    }
}
