//! The `prm` binary end to end: known figures from `compare`, outputs that read back, and bad
//! input that gets a clear error and leaves no file behind.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::Vec3;
use prm::exr_io::Channels;

fn prm(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_prm")).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn asset(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets").join(name).display().to_string()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A bundled level loaded as the CLI loads it at `atlas` (generated UVs are packed for it).
fn level(name: &str, atlas: u32) -> prm::Scene {
    let opts = prm::gltf_load::LoadOptions { unwrap_resolution: atlas.clamp(16, 4096), ..Default::default() };
    prm::gltf_load::load_scene(asset(name), &opts).unwrap()
}

/// The punctual direct light at every texel of `scene` (shadow rays, `prm::bvh::direct_irradiance`),
/// as the CLI's images store it: a full atlas, dilated.
fn direct_image(scene: &prm::Scene, atlas: u32) -> Vec<Vec3> {
    let bvh = prm::Bvh::build(scene);
    let set = prm::TexelSet::build(scene, atlas, atlas);
    let v: Vec<Vec3> = set
        .texels
        .iter()
        .map(|t| prm::bvh::direct_irradiance(&bvh, &scene.lights, t.position, t.normal))
        .collect();
    set.to_image(&v, Vec3::ZERO)
}

/// `a` equals `b` texel by texel to `rel` of the brightest texel of `b`.
fn assert_images_close(a: &[Vec3], b: &[Vec3], rel: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: sizes");
    let scale = b.iter().map(|v| v.max_element()).fold(0.0f32, f32::max);
    assert!(scale > 0.0, "{what}: the expected image is black");
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((*x - *y).abs().max_element() <= rel * scale, "{what}: texel {k}: {x} vs {y}");
    }
}

#[test]
fn compare_gives_the_hand_computed_figures() {
    let dir = tempfile::tempdir().unwrap();
    // Reference: grey 1, 2, 4 on three texels and a fourth outside the mask.
    let mut b = Channels::new(2, 2);
    b.insert_rgb("indirect", &[Vec3::splat(1.0), Vec3::splat(2.0), Vec3::splat(4.0), Vec3::splat(100.0)]);
    b.insert("mask", vec![1.0, 1.0, 1.0, 0.0]);
    let mut a = Channels::new(2, 2);
    a.insert_rgb("", &[Vec3::splat(1.0), Vec3::splat(3.0), Vec3::splat(4.0), Vec3::splat(-5.0)]);
    let (pa, pb) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
    a.write(&pa).unwrap();
    b.write(&pb).unwrap();
    let png = dir.path().join("diff.png");
    let (ok, out, err) = prm(&["compare", s(&pa), s(&pb), "--json", "--diff-png", s(&png)]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // Luminance of grey g is g: error sqrt(1 / (1 + 4 + 16)), bias 8/7 - 1, max |dY| 1.
    assert_eq!(v["count"], 3);
    assert!((v["error"].as_f64().unwrap() - (1.0f64 / 21.0).sqrt()).abs() < 1e-6);
    assert!((v["bias"].as_f64().unwrap() - (8.0 / 7.0 - 1.0)).abs() < 1e-6);
    assert!((v["max_abs"].as_f64().unwrap() - 1.0).abs() < 1e-6);
    assert_eq!(v["negative"], 0, "the negative texel is outside the mask");
    assert!(png.exists());
}

#[test]
fn texels_and_ground_truth_on_a_bundled_scene() {
    let dir = tempfile::tempdir().unwrap();
    let t = dir.path().join("t.exr");
    let (ok, _, err) = prm(&["texels", &asset("cornell.glb"), "--atlas", "32", "-o", s(&t)]);
    assert!(ok, "{err}");
    let tex = Channels::read(&t).unwrap();
    let gt = dir.path().join("gt.exr");
    let (ok, out, err) =
        prm(&["ground-truth", &asset("cornell.glb"), "--atlas", "32", "--spp", "8", "--json", "-o", s(&gt)]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["paths_truncated_at_max_bounces"], 0);
    let g = Channels::read(&gt).unwrap();
    assert_eq!(g.get("mask"), tex.get("mask"), "ground truth covers exactly the texel set");
    for layer in ["indirect", "direct", "stderr"] {
        let rgb = g.rgb(layer).unwrap();
        assert!(rgb.iter().all(|c| c.is_finite() && c.min_element() >= 0.0), "{layer} has bad values");
    }
    let covered: Vec<bool> = tex.get("mask").unwrap().iter().map(|&m| m > 0.5).collect();
    let ind = g.rgb("indirect").unwrap();
    // At 8 paths, a texel whose hemisphere is half open front may see no bounce; most do.
    let lit = ind.iter().zip(&covered).filter(|(v, &c)| c && v.max_element() > 0.0).count();
    let total = covered.iter().filter(|&&c| c).count();
    assert!(lit * 100 >= total * 95, "{lit} of {total} texels receive indirect light");
    // Cornell is lit by one point light and has no emitters: the direct layer is next-event
    // estimation only, noiseless, and must be the shared shadow-ray direct light at every
    // texel (the tracer keeps its own copy of that loop; both are f32 sums in light order, so
    // 1e-6 of the brightest texel is round-off only).
    let scene = level("cornell.glb", 32);
    assert!(scene.materials.iter().all(|m| m.emissive == Vec3::ZERO) && !scene.lights.is_empty());
    assert_images_close(&g.rgb("direct").unwrap(), &direct_image(&scene, 32), 1e-6, "ground-truth direct");
    assert!(g.rgb("stderr_direct").unwrap().iter().all(|e| *e == Vec3::ZERO), "a noiseless layer has error");
    // The summary describes the image: texel count and mean indirect light (f32 sums: 1e-4).
    assert_eq!(v["texels"].as_u64().unwrap() as usize, total);
    let mean: Vec3 =
        ind.iter().zip(&covered).filter(|(_, &c)| c).map(|(v, _)| *v).sum::<Vec3>() / total as f32;
    for (k, m) in v["mean_indirect"].as_array().unwrap().iter().enumerate() {
        let m = m.as_f64().unwrap() as f32;
        assert!((m - mean[k]).abs() <= 1e-4 * mean[k], "mean_indirect[{k}] {m} vs the image's {}", mean[k]);
    }
    // The error of the ground truth against itself is zero.
    let (ok, out, _) = prm(&["compare", s(&gt), s(&gt), "--json"]);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["error"].as_f64().unwrap(), 0.0);
}

#[test]
fn camera_view_renders() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("cam.exr");
    let (ok, _, err) = prm(&[
        "ground-truth",
        &asset("cornell.glb"),
        "--camera",
        "camera",
        "--width",
        "24",
        "--spp",
        "2",
        "-o",
        s(&img),
    ]);
    assert!(ok, "{err}");
    let c = Channels::read(&img).unwrap();
    let rgb = c.rgb("").unwrap();
    assert_eq!((c.width, c.height), (24, 24));
    assert!(rgb.iter().all(|v| v.is_finite() && v.min_element() >= 0.0));
    assert!(
        rgb.iter().filter(|v| v.max_element() > 0.0).count() > 24 * 24 / 2,
        "most pixels see the lit box"
    );
    let (ok, _, err) = prm(&["ground-truth", &asset("cornell.glb"), "--camera", "nope", "-o", s(&img)]);
    assert!(!ok && err.contains("no camera named 'nope'") && err.contains("camera"), "{err}");
}

#[test]
fn bad_input_is_a_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let (ok, _, err) = prm(&["texels", s(&dir.path().join("missing.glb")), "-o", s(&out)]);
    assert!(!ok && err.contains("missing.glb") && err.contains("cannot read"), "{err}");
    let junk = dir.path().join("junk.glb");
    std::fs::write(&junk, b"glTF\x02\x00\x00\x00garbage").unwrap();
    let (ok, _, err) = prm(&["info", s(&junk)]);
    assert!(!ok && err.contains("junk.glb"), "{err}");
    let (ok, _, err) = prm(&["texels", &asset("cornell.glb"), "--atlas", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("--atlas 0"), "{err}");
    let (ok, _, err) = prm(&["ground-truth", &asset("cornell.glb"), "--spp", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("spp 0 must be 1 to 16777216"), "{err}");
    let (ok, _, err) = prm(&["compare", s(&junk), s(&junk)]);
    assert!(!ok && err.contains("junk.glb"), "{err}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only the junk input remains: no partial outputs"
    );
}

#[test]
fn info_reports_the_chamber() {
    let (ok, out, err) = prm(&["info", &asset("chamber.glb"), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let tris = v["triangles"].as_u64().unwrap();
    assert!((3000..=5000).contains(&tris));
    assert_eq!(v["lights"].as_array().unwrap().len(), 2);
    assert_eq!(v["uv"]["overlapping_pairs"], 0);
    assert!(v["texels"]["covered"].as_u64().unwrap() > 10_000);
}

#[test]
fn precompute_evaluate_and_export_panes() {
    let dir = tempfile::tempdir().unwrap();
    let prm_path = dir.path().join("c.prm");
    let (ok, out, err) = prm(&[
        "precompute",
        &asset("cornell.glb"),
        "--preset",
        "preview",
        "--atlas",
        "32",
        "--json",
        "-o",
        s(&prm_path),
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["entries"], 1024);
    assert!(v["file_bytes"].as_u64().unwrap() == std::fs::metadata(&prm_path).unwrap().len());
    for key in [
        "seconds_entries",
        "seconds_clustering",
        "seconds_transport",
        "seconds_panes",
        "rays_per_second",
        "tiles_kept",
        "tiles_dropped",
    ] {
        assert!(v[key].is_number(), "summary lacks {key}");
    }
    // The summary's tile counts are the file's.
    let file = prm::prm_file::Prm::read(&prm_path, None).unwrap();
    assert_eq!(v["tiles_kept"].as_u64().unwrap(), file.header().tiles as u64);
    assert_eq!(v["tiles_dropped"].as_u64().unwrap(), file.header().tiles_dropped as u64);
    let lm = dir.path().join("lm.exr");
    let (ok, _, err) = prm(&["evaluate", &asset("cornell.glb"), "--prm", s(&prm_path), "-o", s(&lm)]);
    assert!(ok, "{err}");
    let c = Channels::read(&lm).unwrap();
    // Every pane (no --top-k): the lightmap is the slow compose of the cluster weights, the
    // member means of the ray-traced entry irradiance. The same f32 operations in the same
    // order, so equal up to 1e-6 of the brightest texel (round-off only).
    let scene = level("cornell.glb", 32);
    let bvh = prm::Bvh::build(&scene);
    let e = prm_runtime::cpu::entry_irradiance(&file, &bvh, &scene.lights);
    let want = prm_runtime::cpu::compose(&file, &prm_runtime::cpu::cluster_weights(&file, &e));
    assert_images_close(&c.rgb("").unwrap(), &want, 1e-6, "evaluate vs Prm::compose");
    let mask = c.get("mask").unwrap();
    let rgb = c.rgb("").unwrap();
    assert!(rgb.iter().all(|v| v.is_finite() && v.min_element() >= 0.0));
    let lit = rgb.iter().zip(mask).filter(|(v, &m)| m > 0.5 && v.max_element() > 0.0).count();
    assert!(lit * 10 >= mask.iter().filter(|&&m| m > 0.5).count() * 9, "most texels get indirect light");
    let panes = dir.path().join("panes");
    let (ok, out, err) = prm(&["export-panes", s(&prm_path), "-o", s(&panes)]);
    assert!(ok && out.contains("64 panes"), "{out}{err}");
    assert_eq!(std::fs::read_dir(&panes).unwrap().count(), 4);
    // A map baked for one scene is refused for another.
    let (ok, _, err) = prm(&[
        "evaluate",
        &asset("two_rooms.glb"),
        "--prm",
        s(&prm_path),
        "-o",
        s(&dir.path().join("x.exr")),
    ]);
    assert!(!ok && err.contains("another scene"), "{err}");
    // Absurd parameters are refused before any work, and nothing is written.
    let bad = dir.path().join("bad.prm");
    let (ok, _, err) = prm(&["precompute", &asset("cornell.glb"), "--entries", "0", "-o", s(&bad)]);
    assert!(!ok && err.contains("entries 0"), "{err}");
    assert!(!bad.exists());
}

#[test]
fn bake_reference_writes_layers_and_debug_lights() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ref.exr");
    let obj = dir.path().join("lights.obj");
    let (ok, stdout, err) = prm(&[
        "bake-reference",
        &asset("cornell.glb"),
        "--atlas",
        "32",
        "--vpls",
        "4000",
        "--json",
        "--debug-lights",
        s(&obj),
        "-o",
        s(&out),
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(v["polygon_lights"].as_u64().unwrap() > 10);
    let c = Channels::read(&out).unwrap();
    let (total, direct, indirect) =
        (c.rgb("").unwrap(), c.rgb("direct").unwrap(), c.rgb("indirect").unwrap());
    for k in 0..total.len() {
        assert!(
            (total[k] - direct[k] - indirect[k]).abs().max_element()
                <= 1e-4 * total[k].max_element().max(1.0)
        );
        assert!(total[k].is_finite() && total[k].min_element() >= 0.0);
    }
    // The reference baker's direct layer is the shared shadow-ray direct light (cornell: one
    // point light), the same function at the same texels: round-off only.
    assert_images_close(&direct, &direct_image(&level("cornell.glb", 32), 32), 1e-6, "bake-reference direct");
    let text = std::fs::read_to_string(&obj).unwrap();
    assert!(text.contains("g polygons") && text.lines().filter(|l| l.starts_with("f ")).count() > 10);
    let (ok, _, err) = prm(&["bake-reference", &asset("cornell.glb"), "--vpls", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("vpls 0"), "{err}");
}

#[test]
fn rigs_drive_evaluate_and_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.json");
    std::fs::write(&rig, r#"{"lights": [{"name": "ceiling_light", "keyframes": [
        {"time": 0, "position": [0.15, 0.45, 0.28]}, {"time": 1, "position": [0.4, 0.45, 0.28], "intensity": 4}]}]}"#).unwrap();
    let prm_path = dir.path().join("c.prm");
    let (ok, _, err) = prm(&[
        "precompute",
        &asset("cornell.glb"),
        "--preset",
        "preview",
        "--atlas",
        "32",
        "-o",
        s(&prm_path),
    ]);
    assert!(ok, "{err}");
    let read = |p: &Path| Channels::read(p).unwrap().rgb("").unwrap();
    let (f0, f1) = (dir.path().join("f0.exr"), dir.path().join("f1.exr"));
    for (frame, out) in [("0", &f0), ("9", &f1)] {
        let (ok, _, err) = prm(&[
            "evaluate",
            &asset("cornell.glb"),
            "--prm",
            s(&prm_path),
            "--rig",
            s(&rig),
            "--frame",
            frame,
            "--frames",
            "10",
            "--top-k",
            "16",
            "-o",
            s(out),
        ]);
        assert!(ok, "{err}");
    }
    let (a, b) = (read(&f0), read(&f1));
    assert_ne!(a, b, "the light moved and dimmed");
    let sum = |v: &[Vec3]| v.iter().map(|x| x.x as f64).sum::<f64>();
    assert!(sum(&b) < sum(&a), "intensity 8 -> 4 lowers the indirect light");
    let gt = dir.path().join("gt.exr");
    let (ok, _, err) = prm(&[
        "ground-truth",
        &asset("cornell.glb"),
        "--atlas",
        "16",
        "--spp",
        "4",
        "--rig",
        s(&rig),
        "--frame",
        "9",
        "--frames",
        "10",
        "-o",
        s(&gt),
    ]);
    assert!(ok, "{err}");
    // A rig naming a light the level lacks is refused.
    std::fs::write(&rig, r#"{"lights": [{"name": "sun"}]}"#).unwrap();
    let (ok, _, err) =
        prm(&["evaluate", &asset("cornell.glb"), "--prm", s(&prm_path), "--rig", s(&rig), "-o", s(&f0)]);
    assert!(!ok && err.contains("'sun'") && err.contains("no such light"), "{err}");
}

/// A preview .prm of cornell at 32² and a rig moving its light sideways, in a temp folder.
fn cornell_map_and_moving_rig() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let prm_path = dir.path().join("c.prm");
    let (ok, _, err) = prm(&[
        "precompute",
        &asset("cornell.glb"),
        "--preset",
        "preview",
        "--atlas",
        "32",
        "-o",
        s(&prm_path),
    ]);
    assert!(ok, "{err}");
    let rig = dir.path().join("rig.json");
    std::fs::write(
        &rig,
        r#"{"lights": [{"name": "ceiling_light", "keyframes": [
        {"time": 0, "position": [0.1, 0.45, 0.28]}, {"time": 1, "position": [0.45, 0.45, 0.28]}]}]}"#,
    )
    .unwrap();
    (dir, prm_path, rig)
}

#[test]
fn render_writes_frames_that_follow_the_rig() {
    let (dir, prm_path, rig) = cornell_map_and_moving_rig();
    for backend in ["cpu", "gpu"] {
        let out = dir.path().join(backend);
        let (ok, stdout, err) = prm(&[
            "render",
            &asset("cornell.glb"),
            "--prm",
            s(&prm_path),
            "--rig",
            s(&rig),
            "--frames",
            "3",
            "--width",
            "24",
            "--backend",
            backend,
            "--lightmap-out",
            "-o",
            s(&out),
        ]);
        assert!(ok, "{err}");
        assert!(stdout.contains("3 frames, 3 composes"), "{backend}: {stdout}");
        // The GPU backend must really have run on a device (it falls back to the CPU, saying
        // so, only without an adapter; the tests need one).
        assert_eq!(stdout.contains("device:"), backend == "gpu", "{backend}: {stdout}");
        let frame =
            |i: usize| Channels::read(&out.join(format!("frame_{i:04}.exr"))).unwrap().rgb("").unwrap();
        let (f0, f2) = (frame(0), frame(2));
        assert!(f0.iter().chain(&f2).all(|v| v.is_finite() && v.min_element() >= 0.0));
        assert!(f0.iter().filter(|v| v.max_element() > 0.0).count() > 24 * 24 / 2);
        assert_ne!(f0, f2, "{backend}: the light moved");
        assert!(out.join("frame_0001.png").exists() && out.join("lightmap_0002.exr").exists());
        // Without a rig the lights do not move: one compose for all frames.
        let (ok, stdout, _) = prm(&[
            "render",
            &asset("cornell.glb"),
            "--prm",
            s(&prm_path),
            "--frames",
            "3",
            "--width",
            "8",
            "--backend",
            backend,
            "-o",
            s(&out),
        ]);
        assert!(ok && stdout.contains("3 frames, 1 composes"), "{backend}: {stdout}");
    }
    // The GPU lightmap (shadow-mapped entry visibility) agrees with the CPU twin's (shadow rays).
    let lm =
        |b: &str| Channels::read(&dir.path().join(b).join("lightmap_0001.exr")).unwrap().rgb("").unwrap();
    let m = prm::metric::compare(&lm("gpu"), &lm("cpu"), None);
    assert!(m.error < 0.01, "GPU vs CPU lightmap error {}", m.error);
}

#[test]
fn bench_reports_both_frame_kinds_and_the_compose() {
    let (_dir, prm_path, rig) = cornell_map_and_moving_rig();
    let (ok, stdout, err) = prm(&[
        "bench",
        &asset("cornell.glb"),
        "--prm",
        s(&prm_path),
        "--rig",
        s(&rig),
        "--frames",
        "4",
        "--rounds",
        "1",
        "--width",
        "32",
        "--shadow-size",
        "128",
        "--json",
    ]);
    assert!(ok, "{err}");
    let j: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(j["composes"], 4, "{stdout}");
    let f = |k: &str| j[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {stdout}"));
    // The figures hang together (bench.rs): the ratio is of the two medians; the compose bytes
    // are the sum of their parts; the bandwidth estimate is bytes over measured bandwidth.
    // 1e-12 relative: JSON round trips of f64.
    let close = |a: f64, b: f64, what: &str| assert!((a - b).abs() <= 1e-12 * b.abs(), "{what}: {a} vs {b}");
    let (full, direct) = (&j["full_frame"], &j["direct_frame"]);
    let med = |s: &serde_json::Value| s["median_ms"].as_f64().unwrap();
    assert!(med(direct) > 0.0 && med(full) > 0.0, "{stdout}");
    close(f("ratio_median"), med(full) / med(direct), "ratio_median");
    for st in [full, direct] {
        assert!(st["p95_ms"].as_f64().unwrap() >= med(st), "p95 below the median: {stdout}");
    }
    let d = &j["compose_bytes_detail"];
    let part = |k: &str| d[k].as_u64().unwrap_or_else(|| panic!("{k} missing: {stdout}"));
    assert_eq!(
        j["compose_bytes"].as_u64().unwrap(),
        part("pane_data") + part("headers") + part("tables") + part("written")
    );
    // Against the file: an RGBA32F atlas written, a 4-byte slot per texel and 16 bytes per
    // cluster and group selected-or-not, at most all of the f16 pane data read.
    let file = prm::prm_file::Prm::read(&prm_path, None).unwrap();
    let texels = (file.header().atlas_width * file.header().atlas_height) as u64;
    assert_eq!(part("written"), texels * 16);
    assert_eq!(part("tables"), texels * 4 + (file.clusters().len() + file.groups().len()) as u64 * 16);
    assert!(part("pane_data") > 0 && part("pane_data") <= file.data().len() as u64 * 2);
    let selected = part("selected_clusters");
    assert!(
        selected > 0 && selected <= (32 + file.groups().len()) as u64,
        "{selected} panes selected at top-k 32"
    );
    assert!(f("copy_bandwidth_gb_s") > 0.0 && f("compose_ms_wall") > 0.0);
    close(
        f("compose_at_bandwidth_ms"),
        f("compose_bytes") / (f("copy_bandwidth_gb_s") * 1e9) * 1e3,
        "compose_at_bandwidth_ms",
    );
    // A rig naming a light the level does not have, without a type, is refused.
    std::fs::write(&rig, r#"{"lights": [{"name": "nowhere", "position": [0, 1, 0]}]}"#).unwrap();
    let (ok, _, err) = prm(&["bench", &asset("cornell.glb"), "--prm", s(&prm_path), "--rig", s(&rig)]);
    assert!(!ok && err.contains("nowhere"), "{err}");
}

#[test]
fn report_writes_figures_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let (ok, _, err) = prm(&["report", &asset("cornell.glb"), "--smoke", "-o", s(&out)]);
    assert!(ok, "{err}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## PRM: precompute budget",
        "## PRM: runtime budget",
        "## Reference baker",
        "## Moving-light rig",
        "Machine:",
        "GPU device:",
        "Seeds:",
    ] {
        assert!(md.contains(section), "report.md lacks {section}:\n{md}");
    }
    // Every error figure is a finite percentage.
    let figures: Vec<f64> = md
        .split('|')
        .filter_map(|c| c.trim().strip_suffix(" %"))
        .filter_map(|v| v.trim_start_matches('+').parse().ok())
        .collect();
    assert!(figures.len() > 20 && figures.iter().all(|f| f.is_finite()), "{figures:?}");
    // Plots need a font; CI installs one (fonts-dejavu-core).
    if md.contains("precompute.png") {
        for png in ["precompute.png", "runtime.png", "rig.png"] {
            assert!(std::fs::metadata(out.join(png)).unwrap().len() > 10_000, "{png} is empty");
        }
    } else {
        assert!(err.contains("fonts-dejavu-core"), "{err}");
    }
}
