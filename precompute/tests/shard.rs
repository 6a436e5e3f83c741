//! A precompute in parts (issue 16, `prm_precompute::shard`): the plan, N shards and the
//! merge give the bytes a one-machine precompute writes, for any N, any order of the parts and
//! any thread count; missing, duplicated, foreign and damaged parts are refused with a message
//! naming them; a shard stopped half way leaves no file behind.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use prm::{Bvh, Scene};
use prm_precompute::precompute::{precompute, PrecomputeParams};
use prm_precompute::shard::{merge, plan, run_shard, shard_texels, Plan, ShardError};
use prm_precompute::transport::Estimator;

fn cornell() -> Scene {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    prm::gltf_load::load_scene(root.join("assets/cornell.glb"), &Default::default()).unwrap()
}

/// Small, but with every part of the preamble: near, echo and far fields, smoothing, groups.
fn params(seed: u64) -> PrecomputeParams {
    PrecomputeParams {
        entries: 384,
        paths: 8,
        clusters: 24,
        groups: 4,
        seed,
        atlas: prm::density::Atlas::single(80),
        ..PrecomputeParams::production()
    }
}

fn quiet(_: prm_precompute::precompute::Phase, _: usize, _: usize) {}

fn never() -> AtomicBool {
    AtomicBool::new(false)
}

/// The plan of `params` written to and read back from `dir/name.plan`.
fn make_plan(scene: &Scene, bvh: &Bvh, p: &PrecomputeParams, dir: &Path, name: &str) -> (Plan, PathBuf) {
    let (mut made, _) = plan(scene, bvh, p, &quiet, &never()).unwrap();
    let path = dir.join(format!("{name}.plan"));
    made.write(&path).unwrap();
    let read = Plan::read(&path).unwrap();
    assert_eq!(read.checksum, made.checksum);
    (read, path)
}

/// All `n` parts of `plan` in `dir`, run in reverse order, at `threads` worker threads.
fn run_parts(scene: &Scene, bvh: &Bvh, plan: &Plan, n: u32, dir: &Path, threads: usize) -> Vec<PathBuf> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    (0..n)
        .rev()
        .map(|i| {
            let out = dir.join(format!("part-{i}-of-{n}-{threads}t"));
            pool.install(|| run_shard(scene, bvh, plan, i, n, &out, &quiet, &never())).unwrap();
            out
        })
        .collect()
}

#[test]
fn shards_merge_to_the_bytes_of_one_machine() {
    let scene = cornell();
    let bvh = Bvh::build(&scene);
    let p = params(3);
    let (one, _) = precompute(&scene, &bvh, &p, &quiet, &never()).unwrap();
    let one = one.to_bytes();
    let dir = tempfile::tempdir().unwrap();
    let (made, plan_path) = make_plan(&scene, &bvh, &p, dir.path(), "level");
    let texels = made.texels();
    // The shards read the plan's first section only.
    let made = Plan::read_walks(&plan_path).unwrap();
    assert_eq!(made.texels(), texels);
    for n in [1u32, 3, 8] {
        // Given to the merge in the reverse of their order.
        let parts = run_parts(&scene, &bvh, &made, n, dir.path(), 2);
        let (prm, report) = merge(Plan::read(&plan_path).unwrap(), &parts, &quiet, &never()).unwrap();
        assert!(prm.to_bytes() == one, "{n} shards: the merged file differs from one machine's");
        assert_eq!(report.texels, texels);
    }
    // A part is the same bytes at any thread count.
    let one_thread = run_parts(&scene, &bvh, &made, 3, dir.path(), 1);
    let two_threads: Vec<PathBuf> =
        (0..3).rev().map(|i| dir.path().join(format!("part-{i}-of-3-2t"))).collect();
    for (a, b) in one_thread.iter().zip(&two_threads) {
        assert!(
            std::fs::read(a).unwrap() == std::fs::read(b).unwrap(),
            "{} differs at 1 thread",
            a.display()
        );
    }
    // The runs cover the texels once each, for a count that does not divide them too.
    for n in [1u32, 7, 64] {
        let runs: Vec<_> = (0..n).map(|i| shard_texels(texels, i, n)).collect();
        assert_eq!(runs[0].start, 0);
        assert_eq!(runs[n as usize - 1].end, texels);
        assert!(runs.windows(2).all(|w| w[0].end == w[1].start));
        let (lo, hi) =
            (runs.iter().map(|r| r.len()).min().unwrap(), runs.iter().map(|r| r.len()).max().unwrap());
        assert!(hi - lo <= 1, "unequal runs {lo}..{hi}");
    }
}

fn message(r: Result<impl Sized, ShardError>) -> String {
    match r {
        Ok(_) => panic!("accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_parts_and_plans_are_refused_by_name() {
    let scene = cornell();
    let bvh = Bvh::build(&scene);
    let dir = tempfile::tempdir().unwrap();
    let (made, plan_path) = make_plan(&scene, &bvh, &params(3), dir.path(), "level");
    let parts = run_parts(&scene, &bvh, &made, 3, dir.path(), 2);
    let read_plan = || Plan::read(&plan_path).unwrap();
    let merged = |parts: &[PathBuf]| merge(read_plan(), parts, &quiet, &never());

    // Missing: one of three left out, and none at all.
    let m = message(merged(&parts[..2]));
    assert!(m.contains("shard 0 of 3 missing"), "{m}");
    assert!(message(merged(&[])).contains("no parts"));
    // Twice.
    let twice = [parts[0].clone(), parts[1].clone(), parts[2].clone(), parts[1].clone()];
    let m = message(merged(&twice));
    assert!(m.contains("given twice") && m.contains(&parts[1].display().to_string()), "{m}");
    // Foreign: a part of a plan with another seed.
    let (other, _) = make_plan(&scene, &bvh, &params(4), dir.path(), "other");
    let foreign = dir.path().join("foreign");
    run_shard(&scene, &bvh, &other, 1, 3, &foreign, &quiet, &never()).unwrap();
    let m = message(merged(&[parts[0].clone(), foreign.clone(), parts[2].clone()]));
    assert!(m.contains("another plan") && m.contains("foreign"), "{m}");
    // Mixed counts: a part of a 2-way split with a 3-way one.
    let two = run_parts(&scene, &bvh, &made, 2, dir.path(), 2);
    let m = message(merged(&[parts[0].clone(), two[0].clone(), parts[2].clone()]));
    assert!(m.contains("of 2") && m.contains("of 3"), "{m}");
    // Damaged: a byte flipped in the walks, and a part cut short.
    let bytes = std::fs::read(&parts[1]).unwrap();
    let flipped = dir.path().join("flipped");
    let mut b = bytes.clone();
    b[bytes.len() / 2] ^= 0x10;
    std::fs::write(&flipped, &b).unwrap();
    let m = message(merged(&[parts[0].clone(), flipped, parts[2].clone()]));
    assert!(m.contains("flipped") && m.contains("damaged"), "{m}");
    // In the last shard's counters: found when the merge reads that part's end.
    let last = std::fs::read(&parts[0]).unwrap();
    let mut b = last.clone();
    b[last.len() - 20] ^= 0x01;
    let counted = dir.path().join("counted");
    std::fs::write(&counted, &b).unwrap();
    let m = message(merged(&[counted, parts[1].clone(), parts[2].clone()]));
    assert!(m.contains("counted") && m.contains("damaged"), "{m}");
    let cut = dir.path().join("cut");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let m = message(merged(&[parts[0].clone(), cut, parts[2].clone()]));
    assert!(m.contains("cut") && m.contains("damaged"), "{m}");
    // A plan read for a shard cannot be merged from.
    let m = message(merge(Plan::read_walks(&plan_path).unwrap(), &parts, &quiet, &never()));
    assert!(m.contains("whole plan"), "{m}");
    // Not a part at all (the plan given as a part).
    let m = message(merged(&[parts[0].clone(), plan_path.clone(), parts[2].clone()]));
    assert!(m.contains("not a shard's part"), "{m}");
    // The good parts still merge (the refusals above changed nothing).
    assert!(merged(&parts).is_ok());

    // A damaged plan, and a file that is not one.
    let mut p = std::fs::read(&plan_path).unwrap();
    let k = p.len() / 3;
    p[k] ^= 1;
    let bad_plan = dir.path().join("bad.plan");
    std::fs::write(&bad_plan, &p).unwrap();
    let m = message(Plan::read(&bad_plan));
    assert!(m.contains("bad.plan") && m.contains("damaged"), "{m}");
    let m = message(Plan::read(&parts[0]));
    assert!(m.contains("not a precompute plan"), "{m}");
    // A byte flipped in the first section: the shards' reading of it refuses it too.
    let mut p = std::fs::read(&plan_path).unwrap();
    p[40] ^= 1;
    std::fs::write(&bad_plan, &p).unwrap();
    let m = message(Plan::read_walks(&bad_plan));
    assert!(m.contains("bad.plan") && m.contains("damaged"), "{m}");
    let m = message(Plan::read_walks(&dir.path().join("nowhere.plan")));
    assert!(m.contains("nowhere.plan") && m.contains("cannot be read"), "{m}");

    // A shard of another level, a shard index past the count.
    let mut moved = cornell();
    moved.triangles.truncate(moved.triangles.len() - 2);
    let moved_bvh = Bvh::build(&moved);
    let out = dir.path().join("never");
    let m = message(run_shard(&moved, &moved_bvh, &made, 0, 3, &out, &quiet, &never()));
    assert!(m.contains("not the one the plan was made of"), "{m}");
    let m = message(run_shard(&scene, &bvh, &made, 3, 3, &out, &quiet, &never()));
    assert!(m.contains("3/3"), "{m}");
    let m = message(run_shard(&scene, &bvh, &made, 0, 0, &out, &quiet, &never()));
    assert!(m.contains("0/0"), "{m}");
    assert!(!out.exists());
}

#[test]
fn a_stopped_shard_leaves_nothing() {
    let scene = cornell();
    let bvh = Bvh::build(&scene);
    let dir = tempfile::tempdir().unwrap();
    let (made, _) = make_plan(&scene, &bvh, &params(3), dir.path(), "level");
    let out = dir.path().join("part");
    let stop = AtomicBool::new(true);
    assert!(run_shard(&scene, &bvh, &made, 0, 2, &out, &quiet, &stop).is_err());
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "left behind: {left:?}");
    assert!(!out.exists());
}

#[test]
fn every_estimator_merges_to_the_same_bytes() {
    // The scatter's virtual lights are made by every shard: their walks (cut here at 2
    // bounces, so the header's count of cut walks is not 0) count once in the merged file.
    let scene = cornell();
    let bvh = Bvh::build(&scene);
    let dir = tempfile::tempdir().unwrap();
    for estimator in [Estimator::Scatter { clamp: 0.5 }, Estimator::Mis] {
        let p = PrecomputeParams { estimator, max_bounces: 2, ..params(7) };
        let (one, report) = precompute(&scene, &bvh, &p, &quiet, &never()).unwrap();
        assert!(report.walks_truncated > 0, "{estimator}: no walk was cut");
        let (_, plan_path) = make_plan(&scene, &bvh, &p, dir.path(), &format!("{estimator}"));
        let parts = run_parts(&scene, &bvh, &Plan::read_walks(&plan_path).unwrap(), 3, dir.path(), 2);
        let (prm, merged) = merge(Plan::read(&plan_path).unwrap(), &parts, &quiet, &never()).unwrap();
        assert!(prm.to_bytes() == one.to_bytes(), "{estimator}: the merged file differs");
        assert_eq!(
            (merged.walks_truncated, merged.virtual_lights),
            (report.walks_truncated, report.virtual_lights)
        );
    }
}

/// Two closed rooms a metre apart, a block in the first, a lamp in each: the second room has a
/// ray tree of its own (`Bvh::localise`), the first holds over half the triangles.
fn two_closed_rooms() -> Scene {
    use glam::Vec3;
    let mut b = prm_precompute::scenes::Builder::default();
    let wall = b.material("wall", [0.7, 0.7, 0.7]);
    let stone = b.material("stone", [0.5, 0.4, 0.3]);
    b.boxed(wall, Vec3::ZERO, Vec3::new(3.0, 2.5, 3.0), true, &[]);
    b.boxed(stone, Vec3::new(1.0, 0.0, 1.0), Vec3::new(1.6, 0.6, 1.6), false, &[2]);
    b.boxed(wall, Vec3::new(4.0, 0.0, 0.0), Vec3::new(7.0, 2.5, 3.0), true, &[]);
    let mut level = b.finish(96).unwrap();
    for (k, x) in [1.5f32, 5.5].into_iter().enumerate() {
        let lamp = prm::glb::GlbLight {
            name: format!("lamp_{k}"),
            kind: "point",
            color: [1.0, 0.9, 0.8],
            intensity: 20.0,
            inner: 0.0,
            outer: 0.0,
            range: None,
            extras: None,
        };
        level.add_light(lamp, Vec3::new(x, 2.0, 1.5), Vec3::NEG_Y);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_closed_rooms.glb");
    std::fs::write(&path, level.to_glb()).unwrap();
    prm::gltf_load::load_scene(&path, &Default::default()).unwrap()
}

#[test]
fn shards_with_bvhs_of_their_own_merge_to_the_bytes_of_one_machine_on_a_level_of_rooms() {
    // Each shard process builds its BVH afresh (`prm precompute --shard`); the one machine's
    // precompute gives its rooms trees of their own before the walks, so the shards must too.
    let scene = two_closed_rooms();
    let bvh = Bvh::build(&scene);
    let p = PrecomputeParams { atlas: prm::density::Atlas::single(96), ..params(5) };
    let (one, _) = precompute(&scene, &bvh, &p, &quiet, &never()).unwrap();
    assert_eq!(bvh.local_regions(), 1, "the second room's tree");
    let dir = tempfile::tempdir().unwrap();
    let (_, plan_path) = make_plan(&scene, &Bvh::build(&scene), &p, dir.path(), "rooms");
    let walks = Plan::read_walks(&plan_path).unwrap();
    let parts: Vec<PathBuf> = (0..3)
        .map(|i| {
            let out = dir.path().join(format!("rooms-part-{i}"));
            let fresh = Bvh::build(&scene);
            assert!(!fresh.is_localised());
            run_shard(&scene, &fresh, &walks, i, 3, &out, &quiet, &never()).unwrap();
            assert_eq!(fresh.local_regions(), 1);
            out
        })
        .collect();
    let (prm, _) = merge(Plan::read(&plan_path).unwrap(), &parts, &quiet, &never()).unwrap();
    assert!(prm.to_bytes() == one.to_bytes(), "the merged file differs from one machine's");
}
