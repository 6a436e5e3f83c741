//! The precompute against analytic answers and twins: the furnace, superposition, a
//! brute-force scatter twin on a tiny scene, the file's bad-input errors, determinism.

use std::path::Path;
use std::sync::atomic::AtomicBool;

mod common;

use common::{quads, unit_box_faces, v};
use glam::Vec3;
use prm::prm_file::{Prm, PrmError, PrmParts};
use prm::{Bvh, Scene, TexelSet};
use prm_precompute::cells::entry_cells;
use prm_precompute::cluster::cluster_entries;
use prm_precompute::entries::sample_entries;
use prm_precompute::precompute::{precompute, PrecomputeError, PrecomputeParams};
use prm_precompute::transport::{Estimator, Transport};
use prm_runtime::cpu;

/// A closed unit box, faces inward.
fn closed_box(albedo: f32) -> Scene {
    quads(&unit_box_faces(), albedo)
}

/// An open box (floor and three walls), albedo 0.7.
fn open_box() -> Scene {
    quads(
        &[
            [v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)],
            [v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)],
            [v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.)],
            [v(1., 0., 0.), v(1., 0., 1.), v(1., 1., 1.), v(1., 1., 0.)],
        ],
        0.7,
    )
}

fn params(entries: u32, paths: u32, clusters: u32, atlas: u32) -> PrecomputeParams {
    PrecomputeParams {
        entries,
        paths,
        clusters,
        atlas: prm::density::Atlas::single(atlas),
        ..PrecomputeParams::production()
    }
}

fn bake(scene: &Scene, p: &PrecomputeParams) -> Prm {
    let bvh = Bvh::build(scene);
    precompute(scene, &bvh, p, &|_, _, _| {}, &AtomicBool::new(false)).unwrap().0
}

/// Values at the covered texels of a full-atlas image.
fn at_texels(set: &TexelSet, img: &[Vec3]) -> Vec<Vec3> {
    set.texels.iter().map(|t| img[(t.j * set.width + t.i) as usize]).collect()
}

#[test]
fn furnace_gives_a_over_one_minus_a_everywhere() {
    // Gather walks in a closed grey box with roulette q = a: each walk credits a per vertex and
    // has a geometric number of vertices (mean 1/(1-a)), so the expected indirect irradiance for
    // unit entry irradiance everywhere is exactly a/(1-a), with per-walk variance
    // a^2 a/(1-a)^2. The stored panes add half-float rounding (< 1e-3 relative). No smoothing:
    // the walked part is a/(1-a) less the links' exact first bounce, which varies steeply near
    // the box's edges, and at this 24^2 atlas (a face is ~10 texels) the default filter would
    // blur that by more than the walk noise (tests/smoothing.rs holds the filter).
    for a in [0.5f32, 0.9] {
        let scene = closed_box(a);
        let p = PrecomputeParams { smooth_radius: 0.0, ..params(512, 256, 24, 24) };
        let prm = bake(&scene, &p);
        let set = TexelSet::build(&scene, 24, 24);
        let img = cpu::compose(&prm, &vec![Vec3::ONE; prm.clusters().len()]);
        let vals = at_texels(&set, &img);
        let want = a / (1.0 - a);
        let sigma_walk = a * (a).sqrt() / (1.0 - a);
        let sigma_texel = sigma_walk / (p.paths as f32).sqrt();
        let mean = vals.iter().map(|v| v.x).sum::<f32>() / vals.len() as f32;
        let sigma_mean = sigma_texel / (vals.len() as f32).sqrt();
        assert!(
            (mean - want).abs() <= 4.0 * sigma_mean + 2e-3 * want,
            "a = {a}: mean {mean} vs {want} (sigma {sigma_mean})"
        );
        for (t, x) in set.texels.iter().zip(&vals) {
            assert!(
                (x.x - want).abs() <= 6.0 * sigma_texel + 2e-3 * want,
                "a = {a}: texel ({}, {}) {} vs {want}",
                t.i,
                t.j,
                x.x
            );
            assert!((x.y - x.x).abs() <= 2e-3 * want, "grey box stays grey");
        }
    }
}

#[test]
fn the_tables_cutoff_keeps_the_furnace_at_a_over_one_minus_a() {
    // The next-bounce table's weak elements played out (`transport::Cutoff`) at a reach where
    // most of the closed box's elements are weak (a cluster's first bounce at a cell is about
    // 0.02-0.05 here; the cutoff of a 21-entry cluster at 12 spacings is 0.046): each is
    // unbiased, so the box's mean irradiance stays a/(1-a). The draws are shared by every
    // texel, so the mean's tolerance is theirs (about 1 % here), not the walks'.
    let a = 0.5f32;
    let scene = closed_box(a);
    let set = TexelSet::build(&scene, 24, 24);
    let mean_of = |cutoff: f32| {
        let p = PrecomputeParams { smooth_radius: 0.0, next_cutoff: cutoff, ..params(512, 64, 24, 24) };
        let prm = bake(&scene, &p);
        // The map says which cutoff made it.
        assert_eq!(prm.header().provenance["next_cutoff"].as_f64(), Some(f64::from(cutoff)));
        let vals = at_texels(&set, &cpu::compose(&prm, &vec![Vec3::ONE; prm.clusters().len()]));
        (vals.iter().map(|v| v.x).sum::<f32>() / vals.len() as f32, vals)
    };
    let want = a / (1.0 - a);
    let (whole, all) = mean_of(0.0);
    let (played, cut) = mean_of(12.0);
    assert!((played - want).abs() <= 0.04 * want, "with the cutoff: mean {played} vs {want}");
    assert!((whole - want).abs() <= 0.02 * want, "without: mean {whole} vs {want}");
    // The cutoff did play elements out: the same walks give another lightmap.
    let moved = all.iter().zip(&cut).filter(|(x, y)| (x.x - y.x).abs() > 1e-3 * want).count();
    assert!(moved > all.len() / 2, "only {moved} of {} texels changed", all.len());
}

#[test]
fn superposition_and_clustering_invariance() {
    // An open box (floor and three walls) lit unevenly.
    let scene = open_box();
    let bvh = Bvh::build(&scene);
    // Smoothing and near links off: the walks' own values are compared, not their filtered
    // neighbourhood or the links' exact first bounce (`transport::LinkedCells`).
    // The panes as walked (not scaled to their power: `each_pane_delivers_...`).
    let p = PrecomputeParams {
        smooth_radius: 0.0,
        near_radius: 0.0,
        match_power: false,
        ..params(256, 32, 12, 20)
    };
    let prm = bake(&scene, &p);
    let set = TexelSet::build(&scene, 20, 20);
    let weights: Vec<Vec3> =
        (0..prm.clusters().len()).map(|c| Vec3::new(c as f32 * 0.3, 1.0, (c % 3) as f32)).collect();
    let composed = at_texels(&set, &cpu::compose(&prm, &weights));
    // The same walks evaluated directly for that field.
    let entries = sample_entries(&scene, 256, p.seed);
    let (_, owners, _) = entry_cells(&scene, &entries, &[true; 256]);
    let clustering = cluster_entries(&entries, 12, scene.total_area(), p.kmeans_iterations as usize, p.seed);
    assert_eq!(clustering.members.len(), prm.clusters().len());
    let tr = Transport {
        scene: &scene,
        bvh: &bvh,
        entries: &entries,
        owners: &owners,
        linked: None,
        next: None,
        assignment: &clustering.assignment,
        clusters: clustering.members.len(),
        paths: p.paths,
        max_bounces: p.max_bounces,
        seed: p.seed,
        stats: Default::default(),
    };
    let direct = tr.gather_field(&set, &weights);
    let peak = direct.iter().map(|v| v.max_element()).fold(0.0f32, f32::max);
    for (a, b) in composed.iter().zip(&direct) {
        // Each pane texel is stored within half a logarithmic step (1.9 %) of its value, and
        // every term here is positive, so the sum is within 1.9 % of its own value (plus float
        // round-off); tiles share a colour, exact here (grey albedo).
        let bound = (*b * 0.0186 + Vec3::splat(1e-5 * peak)).max_element();
        assert!((*a - *b).abs().max_element() <= bound, "{a} vs {b}");
    }
    // With uniform weights the sum of all panes does not depend on the clustering: C = N
    // (each entry its own cluster) and C = 12 give the same lightmap.
    let ones = |prm: &Prm| at_texels(&set, &cpu::compose(prm, &vec![Vec3::ONE; prm.clusters().len()]));
    let per_entry = bake(
        &scene,
        &PrecomputeParams {
            smooth_radius: 0.0,
            near_radius: 0.0,
            match_power: false,
            ..params(256, 32, 256, 20)
        },
    );
    assert_eq!(per_entry.clusters().len(), 256);
    assert!(per_entry.clusters().iter().enumerate().all(|(c, cl)| cl.members == vec![c as u32]));
    for (a, b) in ones(&per_entry).iter().zip(&ones(&prm)) {
        // Each side within 1.9 % of the exact sum (stored codes), so within 3.8 % of each other.
        let bound = (a.max(*b) * 0.0373 + Vec3::splat(1e-5 * peak.max(1.0))).max_element();
        assert!((*a - *b).abs().max_element() <= bound, "{a} vs {b}");
    }
}

#[test]
fn gather_agrees_with_a_brute_force_scatter_twin() {
    // Floor lit, walls dark: the walls' indirect light is the floor's first bounce.
    let scene = quads(
        &[
            [v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)],
            [v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)],
            [v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.)],
        ],
        0.6,
    );
    let set = TexelSet::build(&scene, 16, 16);
    let estimate = |est: Estimator| {
        let prm = bake(&scene, &PrecomputeParams { estimator: est, ..params(1024, 1024, 16, 16) });
        let e: Vec<Vec3> =
            prm.entries().iter().map(|en| if en.normal.y > 0.5 { Vec3::ONE } else { Vec3::ZERO }).collect();
        // The whole indirect light, as the runtime makes it: clusters straddling the floor's
        // edge have uneven light, which their weights leave to the near and far fields.
        at_texels(&set, &cpu::lightmap(&prm, &e))
    };
    let ours = [("gather", estimate(Estimator::Gather)), ("mis", estimate(Estimator::Mis))];

    // Twin: paper 004's virtual lights from independent entries, unclamped, brute-force
    // visibility, no clustering; sixteen independent batches give its standard error.
    let bvh = Bvh::build(&scene);
    let batches = 16;
    let mut runs = Vec::new();
    for b in 0..batches {
        let entries = sample_entries(&scene, 256, 1000 + b);
        let mut img = vec![Vec3::ZERO; set.len()];
        for en in entries.iter().filter(|en| en.normal.y > 0.5) {
            // One walk per entry: the entry's own light (l = 0), then its bounces.
            let mut lights = vec![(en.position, en.normal, en.albedo * en.area)];
            let mut rng = prm::sampling::stream(b, 9, lights.len() as u64 + (en.position.x.to_bits() as u64));
            let (mut x, mut n, mut phi) = (en.position, en.normal, en.albedo * en.area);
            loop {
                use rand::Rng;
                let d = prm::sampling::cosine_direction(n, rng.random(), rng.random());
                let Some(h) = bvh.closest_hit_brute_force(x + n * 1e-5, d, f32::INFINITY) else { break };
                let t = h.triangle as usize;
                let nh = scene.face_normal(t);
                if nh.dot(d) > 0.0 {
                    break;
                }
                let a = scene.albedo(t, h.bary());
                phi *= a;
                let y = scene.point(t, h.bary());
                lights.push((y, nh, phi));
                let q = prm::luminance(a);
                if rng.random::<f32>() >= q {
                    break;
                }
                phi /= q;
                (x, n) = (y, nh);
            }
            for (k, tx) in set.texels.iter().enumerate() {
                for &(z, nz, f) in &lights {
                    let d = tx.position - z;
                    let r2 = d.length_squared();
                    let (cz, cx) = (nz.dot(d) / r2.sqrt(), -tx.normal.dot(d) / r2.sqrt());
                    if cz <= 0.0 || cx <= 0.0 {
                        continue;
                    }
                    let o = z + nz * 1e-5;
                    let dist = (tx.position + tx.normal * 1e-5 - o).length();
                    let dir = (tx.position + tx.normal * 1e-5 - o) / dist;
                    if bvh.closest_hit_brute_force(o, dir, dist).is_some() {
                        continue;
                    }
                    img[k] += f * (cz * cx / (std::f32::consts::PI * r2));
                }
            }
        }
        runs.push(img);
    }
    // Compare per wall (the floor's own indirect light is its second bounce off the walls).
    for wall in [2u32, 4] {
        let ks: Vec<usize> = (0..set.len()).filter(|&k| set.texels[k].triangle / 2 == wall / 2).collect();
        let mean_of = |img: &[Vec3]| ks.iter().map(|&k| img[k].x).sum::<f32>() / ks.len() as f32;
        let batch_means: Vec<f32> = runs.iter().map(|r| mean_of(r)).collect();
        let twin = batch_means.iter().sum::<f32>() / batches as f32;
        let var = batch_means.iter().map(|m| (m - twin).powi(2)).sum::<f32>() / (batches - 1) as f32;
        let se = (var / batches as f32).sqrt();
        for (name, fast) in &ours {
            let m = mean_of(fast);
            assert!(
                (m - twin).abs() <= 3.0 * se + 0.02 * twin,
                "wall {wall}: {name} {m} vs twin {twin} (se {se})"
            );
        }
        assert!(twin > 0.01);
    }
}

fn write_read(dir: &Path, name: &str, bytes: &[u8], scene: Option<&Scene>) -> Result<Prm, PrmError> {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    Prm::read(&p, scene)
}

#[test]
fn bad_prm_files_get_their_errors() {
    let scene = closed_box(0.5);
    let prm = bake(&scene, &params(64, 4, 8, 16));
    let bytes = prm.to_bytes();
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(write_read(dir.path(), "ok.prm", &bytes, Some(&scene)).unwrap(), prm);
    assert!(matches!(
        write_read(dir.path(), "trunc.prm", &bytes[..bytes.len() / 2], None),
        Err(PrmError::Checksum { .. } | PrmError::Truncated { .. })
    ));
    assert!(matches!(write_read(dir.path(), "tiny.prm", &bytes[..5], None), Err(PrmError::Truncated { .. })));
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    assert!(matches!(write_read(dir.path(), "flip.prm", &flipped, None), Err(PrmError::Checksum { .. })));
    let mut version = bytes.clone();
    version[8] = 99;
    assert!(matches!(
        write_read(dir.path(), "v99.prm", &version, None),
        Err(PrmError::Version { found: 99, .. })
    ));
    assert!(matches!(
        write_read(dir.path(), "magic.prm", b"glTF and then some bytes", None),
        Err(PrmError::Magic { .. })
    ));
    let other = closed_box(0.6);
    let err = write_read(dir.path(), "other.prm", &bytes, Some(&other)).unwrap_err();
    assert!(matches!(err, PrmError::WrongScene { .. }) && err.to_string().contains("another scene"), "{err}");
    // A corrupt but correctly checksummed body is still caught by the bounds checks.
    let mut evil = prm.clone().into_parts();
    evil.tiles[0].cluster = 99;
    assert!(matches!(
        Prm::from_bytes(Path::new("evil.prm"), &evil.to_bytes()),
        Err(PrmError::Corrupt { .. })
    ));
    let mut evil = prm.clone().into_parts();
    evil.clusters[0].members.push(10_000);
    assert!(matches!(
        Prm::from_bytes(Path::new("evil.prm"), &evil.to_bytes()),
        Err(PrmError::Corrupt { .. })
    ));
    assert!(matches!(Prm::read(&dir.path().join("absent.prm"), None), Err(PrmError::Io { .. })));
}

/// `bytes` (a v17 file without crease points) as version 12 wrote the same map but for its
/// bounce gains, hidden triangles and far texels' areas: no `GAIN` section (v14's), `SEEN`
/// (v15's), `CRSE` (v16's) nor `TXAR` (v17's), a `DIPO` section between `DATA` and `FARF` whose counts are `dipoles`, 0
/// tiles and block 1, and the checksum made again. With `dipoles` > 0 the section holds that
/// many zeroed 88-byte records.
fn as_version_12(bytes: &[u8], dipoles: u32) -> Vec<u8> {
    let header = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    // Without the sections v14, v15, v16 and v17 added (the map has no crease points).
    let without = |bytes: &[u8], tag: &[u8; 4]| -> Vec<u8> {
        let section =
            |at: usize| 12 + u64::from_le_bytes(bytes[at + 4..at + 12].try_into().unwrap()) as usize;
        let mut at = 16 + header;
        while &bytes[at..at + 4] != tag {
            at += section(at);
        }
        [&bytes[..at], &bytes[at + section(at)..]].concat()
    };
    let bytes = without(&without(&without(&without(bytes, b"GAIN"), b"SEEN"), b"CRSE"), b"TXAR");
    let section = |at: usize| 12 + u64::from_le_bytes(bytes[at + 4..at + 12].try_into().unwrap()) as usize;
    let mut at = 16 + header;
    while &bytes[at..at + 4] != b"FARF" {
        at += section(at);
    }
    let mut payload: Vec<u8> = [dipoles, 0, 1].iter().flat_map(|x| x.to_le_bytes()).collect();
    payload.resize(payload.len() + 88 * dipoles as usize, 0);
    let mut out = bytes[..at].to_vec();
    out[8..12].copy_from_slice(&12u32.to_le_bytes());
    out.extend_from_slice(b"DIPO");
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&payload);
    out.extend_from_slice(&bytes[at..bytes.len() - 8]);
    let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &out);
    out.extend_from_slice(&sum.to_le_bytes());
    out
}

/// Version 13 dropped the dipole panes: a version 12 file without any (every file the default
/// preset wrote) reads as the same map (without v14's bounce gains, v15's hidden triangles,
/// v16's crease points and v17's far texel areas), and one with some is
/// refused, naming them.
#[test]
fn a_version_12_file_reads_without_dipole_panes_and_is_refused_with_them() {
    let scene = closed_box(0.5);
    let prm = bake(&scene, &params(64, 4, 8, 16)).without_creases().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let old = as_version_12(&prm.to_bytes(), 0);
    let mut parts = prm.clone().into_parts();
    for l in &mut parts.near {
        l.hidden = 0;
    }
    parts.far.areas.clear();
    let without_gains = Prm::new(PrmParts { gains: Vec::new(), ..parts }).unwrap();
    assert_eq!(write_read(dir.path(), "v12.prm", &old, Some(&scene)).unwrap(), without_gains);
    // An empty section that declares tiles is corrupt, not skipped.
    let mut odd = old[..old.len() - 8].to_vec();
    let at = (16..odd.len()).find(|&k| &odd[k..k + 4] == b"DIPO").unwrap();
    odd[at + 16..at + 20].copy_from_slice(&1u32.to_le_bytes());
    let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &odd);
    odd.extend_from_slice(&sum.to_le_bytes());
    let err = write_read(dir.path(), "odd.prm", &odd, None).unwrap_err();
    assert!(matches!(err, PrmError::Corrupt { .. }) && err.to_string().contains("dipole"), "{err}");
    let with = as_version_12(&prm.to_bytes(), 4);
    let err = write_read(dir.path(), "dipoles.prm", &with, Some(&scene)).unwrap_err();
    assert!(matches!(err, PrmError::Retired { .. }), "{err}");
    let m = err.to_string();
    assert!(m.contains("dipole panes for 4 clusters") && m.contains("precompute again"), "{m}");
}

#[test]
fn same_bytes_at_one_and_two_threads() {
    let scene = closed_box(0.7);
    for est in [Estimator::Gather, Estimator::Mis, Estimator::Scatter { clamp: 0.5 }] {
        let p = PrecomputeParams { estimator: est, ..params(128, 8, 10, 16) };
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| bake(&scene, &p).to_bytes())
        };
        assert!(run(1) == run(2), "{est}: output differs between 1 and 2 threads");
    }
}

/// The panes are walked and encoded a band of tile rows at a time (`panes` module doc): bands
/// of any height give the bytes of one band over the whole atlas (what the precompute did
/// before it streamed), with smoothing, near links and groups on, and with bands
/// (2 texel rows) shorter than the margin the smoothing needs, so a band's walks span several.
#[test]
fn same_bytes_at_any_band_height() {
    let scene = open_box();
    let p = PrecomputeParams { tile_size: 2, groups: 4, smooth_radius: 3.0, ..params(256, 8, 12, 40) };
    let whole = bake(&scene, &PrecomputeParams { band_tile_rows: 1000, ..p.clone() });
    assert!(!whole.tiles().is_empty() && whole.header().groups == 4);
    let bvh = Bvh::build(&scene);
    let set = TexelSet::build_visible(&scene, &bvh, 40, 40);
    let spacing = (scene.total_area() / 256.0).sqrt() as f32;
    let margin = set.smoothing(&scene, p.smooth_radius * spacing).row_reach() + 1;
    assert!(margin > 2, "the test wants a margin wider than a band: {margin}");
    for rows in [1, 3] {
        let banded = bake(&scene, &PrecomputeParams { band_tile_rows: rows, ..p.clone() });
        assert!(banded.to_bytes() == whole.to_bytes(), "bands of {rows} tile rows");
    }
}

#[test]
fn absurd_parameters_are_refused_naming_the_parameter() {
    let preview = PrecomputeParams::preview;
    for (p, name, value) in [
        (PrecomputeParams { entries: 0, ..preview() }, "entries", "0"),
        (PrecomputeParams { clusters: 0, ..preview() }, "clusters", "0"),
        (PrecomputeParams { atlas: prm::density::Atlas::single(100_000), ..preview() }, "atlas", "100000"),
        (PrecomputeParams { drop_threshold: 0.9, ..preview() }, "drop threshold", "0.9"),
        (PrecomputeParams { estimator: Estimator::Scatter { clamp: f32::NAN }, ..preview() }, "clamp", "NaN"),
        (PrecomputeParams { near_radius: f32::NAN, ..preview() }, "near radius", "NaN"),
        (PrecomputeParams { near_radius: -1.0, ..preview() }, "near radius", "-1"),
        (PrecomputeParams { near_radius: 100.0, ..preview() }, "near radius", "100"),
        (PrecomputeParams { band_tile_rows: 0, ..preview() }, "band tile rows", "0"),
        (PrecomputeParams { next_cutoff: f32::NAN, ..preview() }, "next cutoff", "NaN"),
        (PrecomputeParams { next_cutoff: 0.5, ..preview() }, "next cutoff", "0.5"),
        (PrecomputeParams { next_cutoff: -32.0, ..preview() }, "next cutoff", "-32"),
    ] {
        let e = p.validate().unwrap_err();
        assert_eq!((e.name, e.value.as_str()), (name, value), "{e}");
        // The precompute itself refuses them too, before any work.
        let scene = closed_box(0.5);
        let bvh = Bvh::build(&scene);
        let err = precompute(&scene, &bvh, &p, &|_, _, _| {}, &AtomicBool::new(false)).unwrap_err();
        assert!(matches!(err, PrecomputeError::Params(ref got) if *got == e), "{err}");
    }
    assert!(PrecomputeParams::production().validate().is_ok());
    let gt = prm_precompute::ground_truth::GtParams { spp: 0, ..Default::default() };
    assert_eq!(gt.validate().unwrap_err().to_string(), "spp 0 must be 1 to 16777216");
}

#[test]
fn scatter_furnace_is_unbiased_without_clamp_and_low_with_it() {
    // Paper 004's estimator in the same furnace: the expectation of the virtual-light sum is
    // a/(1-a) too (the l = 0 term is the first bounce), but single texels see 1/r² spikes, so
    // only the mean over the box is checked (10 %); a clamp can only lower it.
    let a = 0.5f32;
    let scene = closed_box(a);
    let mean_of = |clamp: f32| {
        let p = PrecomputeParams {
            estimator: Estimator::Scatter { clamp },
            smooth_radius: 0.0,
            ..params(2048, 8, 16, 16)
        };
        let prm = bake(&scene, &p);
        let set = TexelSet::build(&scene, 16, 16);
        let vals = at_texels(&set, &cpu::compose(&prm, &vec![Vec3::ONE; prm.clusters().len()]));
        vals.iter().map(|v| v.x as f64).sum::<f64>() / vals.len() as f64
    };
    let want = (a / (1.0 - a)) as f64;
    let free = mean_of(0.0);
    assert!((free - want).abs() <= 0.1 * want, "unclamped scatter mean {free} vs {want}");
    let clamped = mean_of(2.0);
    assert!(clamped < free && clamped > 0.5 * want, "clamped {clamped} vs unclamped {free}");
}

#[test]
fn a_cancelled_precompute_returns_nothing() {
    let scene = closed_box(0.5);
    let bvh = Bvh::build(&scene);
    let result = precompute(&scene, &bvh, &params(64, 4, 8, 16), &|_, _, _| {}, &AtomicBool::new(true));
    assert!(matches!(result, Err(PrecomputeError::Cancelled(_))), "{:?}", result.err());
}

#[test]
fn entries_inside_a_solid_are_recognised() {
    // A floor with a closed box standing on it: floor points under the box are enclosed.
    let mut qs = vec![[v(-2., 0., -2.), v(-2., 0., 2.), v(2., 0., 2.), v(2., 0., -2.)]];
    let (lo, hi) = (v(-0.5, 0.0, -0.5), v(0.5, 1.0, 0.5));
    let c = |x: bool, y: bool, z: bool| {
        v(if x { hi.x } else { lo.x }, if y { hi.y } else { lo.y }, if z { hi.z } else { lo.z })
    };
    qs.push([c(false, false, false), c(false, false, true), c(false, true, true), c(false, true, false)]);
    qs.push([c(true, false, false), c(true, true, false), c(true, true, true), c(true, false, true)]);
    qs.push([c(false, true, false), c(false, true, true), c(true, true, true), c(true, true, false)]);
    qs.push([c(false, false, false), c(false, true, false), c(true, true, false), c(true, false, false)]);
    qs.push([c(false, false, true), c(true, false, true), c(true, true, true), c(false, true, true)]);
    let scene = quads(&qs, 0.5);
    let bvh = Bvh::build(&scene);
    let entry = |p: Vec3| prm::prm_file::Entry {
        position: p,
        normal: Vec3::Y,
        albedo: Vec3::splat(0.5),
        area: 1.0,
        triangle: 0,
    };
    assert!(prm_precompute::entries::is_enclosed(&scene, &bvh, &entry(v(0.1, 0.0, -0.2)), 0, 0));
    assert!(!prm_precompute::entries::is_enclosed(&scene, &bvh, &entry(v(1.5, 0.0, 1.5)), 0, 1));
    // An enclosed entry moves to a point of its own triangle outside the solid.
    let under = prm::prm_file::Entry { triangle: 0, ..entry(v(0.1, 0.0, -0.2)) };
    let moved = prm_precompute::entries::relocate(&scene, &bvh, &under, 0, 0)
        .expect("the floor around the box is open");
    assert_eq!(moved.triangle, 0);
    assert!(moved.position.y.abs() < 1e-5 && (moved.position.x.abs() > 0.5 || moved.position.z.abs() > 0.5));
    // The precompute moves every one of those (the floor's triangles reach past the box): all
    // 512 stay, and none of them lies under the box.
    let prm = bake(&scene, &params(512, 4, 8, 16));
    assert_eq!(prm.entries().len(), 512);
    assert!(prm
        .entries()
        .iter()
        .all(|e| !(e.position.y < 1e-4 && e.position.x.abs() < 0.49 && e.position.z.abs() < 0.49)));
}

#[test]
fn mutated_prm_files_are_loaded_or_refused_never_a_panic() {
    // Byte flips, truncations and splices, each re-checksummed so the parser behind the
    // checksum is exercised too. Every outcome must be Ok or an error.
    use rand::{Rng, SeedableRng};
    let scene = closed_box(0.5);
    let bytes = bake(&scene, &params(64, 4, 8, 16)).to_bytes();
    let body_len = bytes.len() - 8;
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(77);
    let mut refused = 0;
    for _ in 0..3000 {
        let mut b = bytes[..body_len].to_vec();
        match rng.random_range(0..3) {
            0 => {
                for _ in 0..rng.random_range(1..8) {
                    let i = rng.random_range(0..b.len());
                    b[i] = rng.random();
                }
            }
            1 => b.truncate(rng.random_range(0..b.len())),
            _ => {
                let i = rng.random_range(0..b.len());
                let j = rng.random_range(0..b.len());
                let chunk: Vec<u8> = b[j..(j + 16).min(b.len())].to_vec();
                b.splice(i..i, chunk);
            }
        }
        let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &b);
        b.extend_from_slice(&sum.to_le_bytes());
        let r = std::panic::catch_unwind(|| {
            Prm::from_bytes(Path::new("m.prm"), &b)
                .map(|p| cpu::compose(&p, &vec![Vec3::ONE; p.clusters().len()]))
        });
        match r {
            Ok(Ok(img)) => assert!(
                img.iter().all(|v| v.is_finite() && v.min_element() >= 0.0),
                "a loaded file composes to bad values"
            ),
            Ok(Err(_)) => refused += 1,
            Err(_) => panic!("a mutated file made the loader or compose panic"),
        }
    }
    assert!(refused > 1000, "most mutations are refused ({refused})");
}

#[test]
fn groups_carry_the_light_of_the_clusters_a_top_k_leaves_out() {
    // Grey weights: the group panes' energy stands in exactly (up to dropped tiles and half
    // floats) for the left-out clusters' energy, so top-K + groups has the full sum's total.
    let scene = common::quads(&common::unit_box_faces(), 0.6);
    let p = PrecomputeParams {
        entries: 512,
        paths: 8,
        clusters: 48,
        atlas: prm::density::Atlas::single(32),
        groups: 6,
        ..Default::default()
    };
    let prm = bake(&scene, &p);
    assert_eq!(prm.groups().len(), 6);
    assert_eq!(prm.group_of().len(), prm.clusters().len());
    let layout = prm.layout();
    let w: Vec<Vec3> = (0..prm.clusters().len()).map(|c| Vec3::splat(0.5 + (c % 7) as f32)).collect();
    let full = cpu::compose(&prm, &w);
    let energy = |img: &[Vec3]| img.iter().map(|v| prm::luminance(*v) as f64).sum::<f64>();
    let chosen: Vec<bool> = (0..prm.clusters().len()).map(|c| c % 4 == 0).collect();
    let with = cpu::compose_selected(&prm, &w, &chosen, true, &layout);
    let without = cpu::compose_selected(&prm, &w, &chosen, false, &layout);
    let (ef, ew, eo) = (energy(&full), energy(&with), energy(&without));
    assert!((ew / ef - 1.0).abs() < 0.01, "top-K + groups {ew} vs full {ef}");
    assert!(eo < 0.5 * ef, "a quarter of the clusters should carry well under the full light: {eo} vs {ef}");
    // Everything selected: the groups add nothing.
    let all = vec![true; prm.clusters().len()];
    assert_eq!(cpu::compose_selected(&prm, &w, &all, true, &layout), full);
    // And the file keeps the groups.
    let back = Prm::from_bytes(std::path::Path::new("g.prm"), &prm.to_bytes()).unwrap();
    assert_eq!(back, prm);
}

/// The near links' first bounce, left out of the gather's first hits and put back exactly
/// (`transport::LinkedCells`): the same light in expectation, with less noise. In the open box
/// with links reaching across it (8 spacings: every cell linked to every texel) and uneven
/// light over the clusters, 16 walks a texel come closer to 1024 walks (without links) than 16
/// walks without links do, and at 1024 walks the light is the same either way.
#[test]
fn linked_cells_keep_the_light_and_lose_noise() {
    let scene = open_box();
    let set = TexelSet::build(&scene, 64, 64);
    let lit = |near_radius: f32, paths: u32| -> Vec<f32> {
        let prm =
            bake(&scene, &PrecomputeParams { smooth_radius: 0.0, near_radius, ..params(256, paths, 12, 64) });
        let w: Vec<Vec3> = (0..prm.clusters().len()).map(|c| Vec3::splat((c % 3) as f32)).collect();
        at_texels(&set, &cpu::compose(&prm, &w)).iter().map(|v| prm::luminance(*v)).collect()
    };
    let truth = lit(0.0, 1024);
    let (with, without) = (lit(8.0, 16), lit(0.0, 16));
    // Unbiased: at 1024 walks the light is the same with the links as without, to 0.5 %
    // (measured 0.03 %; at 16 walks the rest of the walks' noise moves the mean by ~2 %).
    let converged = lit(8.0, 1024);
    let mean = |x: &[f32]| x.iter().map(|&v| v as f64).sum::<f64>() / x.len() as f64;
    let off = |a: &[f32]| {
        (a.iter().zip(&truth).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
            / mean(&truth)
    };
    let energy = mean(&converged) / mean(&truth);
    assert!((energy - 1.0).abs() < 0.005, "energy with links / without, 1024 walks: {energy}");
    let (e_with, e_without) = (off(&with), off(&without));
    // Measured 0.276 against 0.292: the open box's texels are mostly far from the cells they
    // see, and the deeper bounces keep their noise; on the chamber the texels at a wall's foot
    // are where it counts (0.0-1.0 against 0.3-0.5 W/m² before, at the ground truth after).
    assert!(e_with < 0.97 * e_without, "16 walks off by {e_with} with linked cells, {e_without} without");
}

/// The walks' next-bounce table (`transport::NextBounce`) against the walks' own hits, both
/// with the near links and the far field, on an open box lit unevenly (a third of the clusters
/// dark): the same light at 1024 walks, and at 16 walks far less noise (the same entries and
/// clusters throughout: one seed). Measured: energy 1.0017; at 1024 walks 2.5 % RMS apart,
/// within the hits' own noise there (29.2 % / sqrt(64) = 3.7 %); at 16 walks 10.9 % off with
/// the table against 29.2 % without.
#[test]
fn next_bounce_table_keeps_the_light_and_loses_noise() {
    let scene = open_box();
    let set = TexelSet::build(&scene, 64, 64);
    let lit = |next_bounce: bool, paths: u32| -> Vec<f32> {
        let p = PrecomputeParams { smooth_radius: 0.0, next_bounce, ..params(256, paths, 12, 64) };
        let prm = bake(&scene, &p);
        let w: Vec<Vec3> = (0..prm.clusters().len()).map(|c| Vec3::splat((c % 3) as f32)).collect();
        at_texels(&set, &cpu::compose(&prm, &w)).iter().map(|v| prm::luminance(*v)).collect()
    };
    let truth = lit(false, 1024);
    let mean = |x: &[f32]| x.iter().map(|&v| v as f64).sum::<f64>() / x.len() as f64;
    let off = |a: &[f32]| {
        (a.iter().zip(&truth).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
            / mean(&truth)
    };
    let converged = lit(true, 1024);
    let energy = mean(&converged) / mean(&truth);
    let (e_with, e_without) = (off(&lit(true, 16)), off(&lit(false, 16)));
    assert!((energy - 1.0).abs() < 0.02, "energy with the table / without, 1024 walks: {energy}");
    assert!(off(&converged) < 0.05, "1024 walks with the table off by {}", off(&converged));
    assert!(e_with < 0.5 * e_without, "16 walks off by {e_with} with the table, {e_without} without");
}

/// `max_bounces` caps the table's bounce too: a row read at a walk's vertex is the bounce after
/// that vertex's, so at the cap it is not read. With one and with two bounces, the open box
/// gets the same light with the table as from the walks' own hits (1024 walks, to 2 %). Before
/// the table kept the cap, one bounce read 1.5x the hits' light (the second bounce came in).
#[test]
fn next_bounce_table_keeps_the_bounce_cap() {
    let scene = open_box();
    let set = TexelSet::build(&scene, 64, 64);
    let energy = |next_bounce: bool, max_bounces: u32| -> f64 {
        let p =
            PrecomputeParams { smooth_radius: 0.0, next_bounce, max_bounces, ..params(256, 1024, 12, 64) };
        let prm = bake(&scene, &p);
        let w: Vec<Vec3> = (0..prm.clusters().len()).map(|c| Vec3::splat((c % 3) as f32)).collect();
        let lit = at_texels(&set, &cpu::compose(&prm, &w));
        lit.iter().map(|v| prm::luminance(*v) as f64).sum::<f64>() / lit.len() as f64
    };
    let mut last = 0.0;
    for bounces in [1, 2] {
        let (with, without) = (energy(true, bounces), energy(false, bounces));
        assert!(
            (with / without - 1.0).abs() < 0.02,
            "{bounces} bounce(s): {with} with the table, {without} without"
        );
        // Each bounce adds light: the cap is what the two agree on, not a cut of both.
        assert!(without > 1.05 * last, "{bounces} bounce(s) bring {without}, one fewer {last}");
        last = without;
    }
    assert!(energy(false, 1000) > 1.05 * last, "all bounces bring no more than two");
}

/// Each pane's power, `sum over texels of luminance x the area the texel stands for`.
fn pane_powers(prm: &Prm, set: &TexelSet, areas: &[f32]) -> Vec<f64> {
    let layout = prm.layout();
    (0..prm.clusters().len() + prm.groups().len())
        .map(|pane| {
            let mut power = 0.0f64;
            for t in prm.pane_tiles(pane, &layout) {
                for (&texel, &code) in t.texels.iter().zip(t.data) {
                    let k = set.index[texel as usize];
                    if k != TexelSet::EMPTY {
                        let e = prm::luminance(t.tile.scale * prm::prm_file::intensity(code));
                        power += e as f64 * areas[k as usize] as f64;
                    }
                }
            }
            power
        })
        .collect()
}

/// A pane answers unit irradiance on its cluster's cells; under it the cells send
/// `sum A_j luminance(rho_j g_j)` to the level over every bounce. With `match_power` (the
/// default) every pane of the open box (a red floor, light lost through the opening) delivers
/// exactly that; the same walks without it leave the panes off by their noise, and the
/// matched map is the unmatched one with each pane, and its energy, scaled by one number.
#[test]
fn each_pane_delivers_the_power_its_cells_send_to_the_level() {
    let mut scene = open_box();
    let red = prm::Material { albedo: v(0.7, 0.1, 0.1), ..scene.materials[0].clone() };
    scene.materials.push(red);
    scene.triangles[0].material = 1;
    scene.triangles[1].material = 1;
    let p = params(512, 16, 24, 32);
    let matched = bake(&scene, &p);
    let raw = bake(&scene, &PrecomputeParams { match_power: false, ..p.clone() });
    assert_eq!(raw.header().provenance["match_power"].as_bool(), Some(false));
    let set = TexelSet::build(&scene, 32, 32);
    let areas = set.covered_areas(&scene);
    let mut want: Vec<f64> = matched
        .clusters()
        .iter()
        .map(|c| {
            c.members
                .iter()
                .map(|&m| {
                    let m = m as usize;
                    let reflect = matched.gain(m) * matched.entries()[m].albedo;
                    matched.cells().area(m) as f64 * prm::luminance(reflect) as f64
                })
                .sum()
        })
        .collect();
    let mut groups = vec![0.0; matched.groups().len()];
    for (c, &g) in matched.group_of().iter().enumerate() {
        groups[g as usize] += want[c];
    }
    want.extend(groups);
    let (got, before) = (pane_powers(&matched, &set, &areas), pane_powers(&raw, &set, &areas));
    let mut off = 0;
    for (pane, w) in want.iter().enumerate() {
        assert!((got[pane] - w).abs() <= 1e-4 * w, "pane {pane}: {} against {w}", got[pane]);
        off += ((before[pane] - w).abs() > 0.01 * w) as usize;
        // The same tiles, every one scaled by the pane's one number.
        let s = (w / before[pane]) as f32;
        let layout = matched.layout();
        for (a, b) in matched.pane_tiles(pane, &layout).zip(raw.pane_tiles(pane, &layout)) {
            assert_eq!((a.tile.index, a.data), (b.tile.index, b.data));
            assert!(
                (a.tile.scale - b.tile.scale * s).abs().max_element() <= 1e-5 * a.tile.scale.max_element()
            );
        }
        let energy = |m: &Prm| match pane.checked_sub(m.clusters().len()) {
            None => m.clusters()[pane].energy,
            Some(g) => m.groups()[g].energy,
        };
        assert!(
            (energy(&matched) - energy(&raw) * s).abs() <= 1e-5 * energy(&matched),
            "pane {pane}'s energy"
        );
    }
    assert!(off > 0, "no pane's power was off before: this checks nothing");
    let range = matched.header().provenance["power_scale"].as_array().map(|r| r.len());
    assert_eq!(range, Some(2), "the map states the scales' range");
}
