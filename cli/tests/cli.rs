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
    let opts =
        prm::gltf_load::LoadOptions { unwrap_resolution: Some(atlas.clamp(16, 8192)), ..Default::default() };
    prm::gltf_load::load_scene(asset(name), &opts).unwrap()
}

/// The punctual direct light at every texel of `scene` (shadow rays, `prm::bvh::direct_irradiance`),
/// as the CLI's images store it: a full atlas, dilated.
fn direct_image(scene: &prm::Scene, atlas: u32) -> Vec<Vec3> {
    let bvh = prm::Bvh::build(scene);
    let set = prm::TexelSet::build_visible(scene, &bvh, atlas, atlas);
    let v: Vec<Vec3> = set
        .texels
        .iter()
        .map(|t| prm::bvh::direct_irradiance(&bvh, &scene.lights, t.position, t.normal))
        .collect();
    set.to_image(&v, Vec3::ZERO)
}

/// `a` equals `b` texel by texel to `rel` of the brightest texel of `b`.
/// Write a generated hall to `dir/hall.glb` and bake it quickly (preview, 256 entries, 4 paths)
/// with `lightmap` options: the level, the map and what precompute printed.
fn bake_hall(dir: &Path, level: &prm::glb::GlbScene, lightmap: &[&str]) -> (PathBuf, PathBuf, String) {
    let glb = dir.join("hall.glb");
    std::fs::write(&glb, level.to_glb()).unwrap();
    let map = dir.join("hall.prm");
    let mut args = vec!["precompute", s(&glb), "--preset", "preview", "--entries", "256", "--paths", "4"];
    args.extend_from_slice(lightmap);
    args.extend_from_slice(&["-o", s(&map)]);
    let (ok, stdout, err) = prm(&args);
    assert!(ok, "{err}");
    (glb, map, stdout)
}

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
    // An infinite reference texel outside the mask is not looked at; inside it, the reference
    // is refused (it read 0.00 %).
    for (at, refused) in [(3, false), (1, true)] {
        let mut v = vec![Vec3::splat(1.0), Vec3::splat(2.0), Vec3::splat(4.0), Vec3::splat(100.0)];
        v[at] = Vec3::splat(f32::INFINITY);
        let mut b = Channels::new(2, 2);
        b.insert_rgb("indirect", &v);
        b.insert("mask", vec![1.0, 1.0, 1.0, 0.0]);
        b.write(&pb).unwrap();
        let (ok, _, err) = prm(&["compare", s(&pa), s(&pb)]);
        assert_eq!(ok, !refused, "{err}");
        assert_eq!(err.contains("1 non-finite texels"), refused, "{err}");
    }
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
    // An independent estimate of the same image: at 4 x 4 points per pixel, the first hit's
    // emission + albedo / pi (shadow-ray direct light + the indirect light looked up in the
    // texel path tracer's lightmap). The camera tracer samples that same integrand.
    let gt = dir.path().join("gt.exr");
    let (ok, _, err) =
        prm(&["ground-truth", &asset("cornell.glb"), "--atlas", "16", "--spp", "16", "-o", s(&gt)]);
    assert!(ok, "{err}");
    let lightmap = Channels::read(&gt).unwrap().rgb("indirect").unwrap();
    let scene = level("cornell.glb", 16);
    let bvh = prm::Bvh::build(&scene);
    let cam = scene.cameras.iter().find(|c| c.name == "camera").unwrap();
    let n = 4;
    let (mut direct, mut indirect) = (vec![Vec3::ZERO; 24 * 24], vec![Vec3::ZERO; 24 * 24]);
    for k in 0..24 * 24 {
        for q in 0..n * n {
            let x = (k % 24) as f32 + ((q % n) as f32 + 0.5) / n as f32;
            let y = (k / 24) as f32 + ((q / n) as f32 + 0.5) / n as f32;
            let (origin, d) = cam.ray(x, y, 24, 24);
            let Some(hit) = bvh.closest_hit(origin, d, f32::INFINITY) else { continue };
            let (t, b) = (hit.triangle as usize, hit.bary());
            let Some(nrm) = scene.facing_normal(t, d) else { continue };
            let [u0, u1, u2] = scene.uv1_corners(t);
            let uv = u0 * b.x + u1 * b.y + u2 * b.z;
            let (u, v) = (uv.x * 16.0 - 0.5, uv.y * 16.0 - 0.5);
            let at =
                |i: f32, j: f32| lightmap[j.clamp(0.0, 15.0) as usize * 16 + i.clamp(0.0, 15.0) as usize];
            let (u0, v0) = (u.floor(), v.floor());
            let e = at(u0, v0)
                .lerp(at(u0 + 1.0, v0), u - u0)
                .lerp(at(u0, v0 + 1.0).lerp(at(u0 + 1.0, v0 + 1.0), u - u0), v - v0);
            let f = scene.albedo(t, b) / std::f32::consts::PI / (n * n) as f32;
            direct[k] += scene.material(t).emissive / (n * n) as f32
                + f * prm::bvh::direct_irradiance(&bvh, &scene.lights, scene.point(t, b), nrm);
            indirect[k] += f * e;
        }
    }
    // Means of luminance: at 2 paths per pixel single pixels are too noisy to hold to
    // anything, the image mean is not. Over seeds 0-6 the image mean was 0.3 to 7.2 % (mean
    // 3.9 %, sd 2.2 %) below the estimate: camera noise plus the 16² lightmap's own noise and
    // bilinear blur. 12 % allows that offset and ~3.5 sd; the indirect term is 47 % of the
    // estimate, so an image without it (or with it twice, or without albedo / pi) fails.
    let mean = |v: &[Vec3]| v.iter().map(|x| prm::luminance(*x) as f64).sum::<f64>() / v.len() as f64;
    let want = mean(&direct) + mean(&indirect);
    assert!(mean(&indirect) > 0.4 * want, "the estimate's indirect share is too small to test");
    let got = mean(&rgb);
    assert!((got - want).abs() <= 0.12 * want, "camera image mean {got} vs the estimate {want}");
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
    for grid in ["0x3", "4", "2x17", "ax2"] {
        let (ok, _, err) = prm(&["gen-assets", "--halls", grid, "-o", s(dir.path())]);
        assert!(!ok && err.contains(&format!("--halls {grid}")), "{err}");
    }
    let (ok, _, err) = prm(&["precompute", &asset("cornell.glb"), "--texel-size", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("texel size 0"), "{err}");
    let (ok, _, err) =
        prm(&["evaluate", &asset("cornell.glb"), "--prm", s(&junk), "--top-k", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("--top-k must be at least 1"), "{err}");
    let (ok, _, err) = prm(&["precompute", &asset("cornell.glb"), "--threads", "0", "-o", s(&out)]);
    assert!(!ok && err.contains("--threads 0 is out of range"), "{err}");
    let (ok, _, err) =
        prm(&["bake", &asset("cornell.glb"), "--atlas", "64", "--tolerance", "NaN", "-o", s(&out)]);
    assert!(!ok && err.contains("--tolerance NaN"), "{err}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only the junk input remains: no partial outputs"
    );
}

/// An output whose folder does not exist, or that names a folder, is refused before any work,
/// with the folder named, and nothing is written.
#[test]
fn an_output_with_no_folder_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no/such");
    let cornell = asset("cornell.glb");
    let file = |name: &str| missing.join(name).display().to_string();
    let runs: [Vec<String>; 5] = [
        vec!["precompute".into(), cornell.clone(), "-o".into(), file("c.prm")],
        vec!["ground-truth".into(), cornell.clone(), "--spp".into(), "1".into(), "-o".into(), file("gt.exr")],
        vec!["texels".into(), cornell.clone(), "-o".into(), file("t.exr")],
        vec!["bake-reference".into(), cornell.clone(), "-o".into(), file("r.exr")],
        vec!["bake".into(), cornell.clone(), "--atlas".into(), "64".into(), "-o".into(), file("b.exr")],
    ];
    for args in &runs {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, _, err) = prm(&args);
        assert!(
            !ok && err.contains("does not exist") && err.contains(&missing.display().to_string()),
            "{args:?}: {err}"
        );
    }
    let (ok, _, err) = prm(&["texels", &cornell, "-o", s(dir.path())]);
    assert!(!ok && err.contains("is a folder"), "{err}");
    assert!(!missing.exists() && std::fs::read_dir(dir.path()).unwrap().count() == 0, "nothing written");
}

#[test]
fn gen_assets_makes_a_folder_it_is_given() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("levels/large");
    let (ok, out, err) = prm(&["gen-assets", "--chambers", "1x1", "-o", s(&folder)]);
    assert!(ok, "{err}");
    assert!(out.contains("chambers_1x1.glb"), "{out}");
    let opts = prm::gltf_load::LoadOptions { unwrap_resolution: Some(256), ..Default::default() };
    let level = prm::gltf_load::load_scene(folder.join("chambers_1x1.glb"), &opts).unwrap();
    assert!(level.triangles.len() > 1000, "{} triangles", level.triangles.len());
}

#[test]
fn bench_rays_measures_a_level_whose_charts_need_pages() {
    // 16 closed chambers without lightmap UVs: their charts need 3 pages at 256^2, which the
    // rays do not need (it refused the level before).
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = prm(&["gen-assets", "--chambers", "4x4", "-o", s(dir.path())]);
    assert!(ok, "{err}");
    let level = dir.path().join("chambers_4x4.glb");
    let (ok, out, err) = prm(&["bench-rays", s(&level), "--rays", "4000", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let (ok, info, err) = prm(&["info", &asset("chamber.glb"), "--json"]);
    assert!(ok, "{err}");
    let chamber: serde_json::Value = serde_json::from_str(&info).unwrap();
    assert_eq!(v["triangles"].as_u64(), chamber["triangles"].as_u64().map(|t| 16 * t), "{v}");
    assert_eq!(v["rays"], 4000);
    // Rays leave the chambers' inner surfaces: every one hits. Two points join only within a
    // chamber (1/16 of the pairs, equal rooms), and not every such pair sees the other:
    // 4,000 pairs put the visible share under 1/16 plus 2 standard errors (0.8 points).
    assert_eq!(v["closest_hit_fraction_hit"], 1.0, "{v}");
    let visible = v["occlusion_fraction_visible"].as_f64().unwrap();
    assert!(visible > 0.0 && visible < 1.0 / 16.0 + 0.008, "{visible}");
    assert!(v["closest_hit_rays_per_s"].as_f64().unwrap() > 0.0);
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
    // The torch rig's corner keyframe (5 cm from three surfaces), so that hot cells are seen.
    let torches = asset("cornell_torches.json");
    let (ok, _, err) = prm(&[
        "evaluate",
        &asset("cornell.glb"),
        "--prm",
        s(&prm_path),
        "--rig",
        &torches,
        "--frames",
        "6",
        "--frame",
        "4",
        "-o",
        s(&lm),
    ]);
    assert!(ok, "{err}");
    let c = Channels::read(&lm).unwrap();
    // Every pane (no --top-k): the lightmap is the slow compose of the pane weights (balanced,
    // then lifted by the near field; from the ray-traced entry irradiance) plus the near field,
    // hot cells as their texels see them. The
    // same f32 operations in the same order, so equal up to 1e-6 of the brightest texel.
    let scene = level("cornell.glb", 32);
    let bvh = prm::Bvh::build(&scene);
    let lights = prm::rig::Rig::load(std::path::Path::new(&torches), &scene.lights).unwrap().frame(4, 6);
    let e = prm_runtime::cpu::entry_irradiance(&file, &bvh, &lights);
    let tables = prm_runtime::cpu::NearTables::new(&file);
    let hot = prm_runtime::cpu::link_light(&file, &bvh, &tables, &e, &lights);
    assert!(hot.hot.iter().any(|&h| h), "the corner torch makes no cell hot: this checks less");
    let (w, near) = prm_runtime::cpu::pane_weights_with(&file, &tables, &hot, &e);
    let mut want = prm_runtime::cpu::compose(&file, &w);
    prm_runtime::cpu::add_and_clamp(&mut want, &near);
    assert_images_close(&c.rgb("").unwrap(), &want, 1e-6, "evaluate vs cpu::compose");
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
    // Counts the bake could not keep are refused, not cut.
    let args = ["--entries", "64", "--clusters", "65"];
    let (ok, _, err) = prm(&[&["precompute", &asset("cornell.glb"), "-o", s(&bad)][..], &args].concat());
    assert!(!ok && err.contains("--clusters 65 is more than the entries (64)"), "{err}");
    let args = ["--entries", "64", "--clusters", "8", "--groups", "9"];
    let (ok, _, err) = prm(&[&["precompute", &asset("cornell.glb"), "-o", s(&bad)][..], &args].concat());
    assert!(!ok && err.contains("--groups 9 is more than the clusters (8)"), "{err}");
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
    let prm_path = cornell_preview_map(dir.path());
    let cornell = asset("cornell.glb");
    let evaluate = |rig: Option<&Path>, frame: &str, out: &Path| {
        let mut args = vec!["evaluate", &cornell, "--prm", s(&prm_path), "--top-k", "16"];
        let rig_args = rig.map(|r| ["--rig", s(r), "--frame", frame, "--frames", "10"]);
        args.extend(rig_args.iter().flatten());
        args.extend(["-o", s(out)]);
        let (ok, _, err) = prm(&args);
        assert!(ok, "{err}");
        Channels::read(out).unwrap().rgb("").unwrap()
    };
    // The level's light stays put and its intensity keyframes go 8 -> 4 over frames 0..=9 of
    // 10 (frame 9 samples t = duration = 1 s, the last keyframe; src/rig.rs). The glTF light
    // is (8, 6.8, 5.2) W/sr, colour x 8, so frame 0 restates it. The lightmap is linear in the
    // lights: entry irradiance, cluster means, the top-K order and the compose all scale, and
    // halving is exact in f32, so frame 9 is exactly half of frame 0, and frame 0 is exactly
    // the lightmap without a rig.
    let rig = dir.path().join("dim.json");
    std::fs::write(
        &rig,
        r#"{"lights": [{"name": "ceiling_light", "keyframes": [
        {"time": 0, "intensity": 8}, {"time": 1, "intensity": 4}]}]}"#,
    )
    .unwrap();
    let plain = evaluate(None, "0", &dir.path().join("plain.exr"));
    let first = evaluate(Some(&rig), "0", &dir.path().join("f0.exr"));
    let last = evaluate(Some(&rig), "9", &dir.path().join("f9.exr"));
    assert!(plain.iter().any(|v| v.max_element() > 0.0), "the lightmap is black");
    assert_eq!(first, plain, "a keyframe restating the glTF light changes the lightmap");
    let half: Vec<Vec3> = first.iter().map(|v| *v * 0.5).collect();
    assert_eq!(last, half, "intensity 8 -> 4 does not halve the lightmap");

    // A light moved and dimmed by the rig: the ground truth's direct layer (next-event
    // estimation of one point light, noiseless) is the shared shadow-ray direct light with the
    // rig's frame-9 lights at every texel; round-off only (1e-6, as in
    // texels_and_ground_truth_on_a_bundled_scene).
    std::fs::write(&rig, r#"{"lights": [{"name": "ceiling_light", "keyframes": [
        {"time": 0, "position": [0.15, 0.45, 0.28]}, {"time": 1, "position": [0.4, 0.45, 0.28], "intensity": 4}]}]}"#).unwrap();
    let gt = dir.path().join("gt.exr");
    let (ok, _, err) = prm(&[
        "ground-truth",
        &asset("cornell.glb"),
        "--atlas",
        "16",
        "--spp",
        "1",
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
    let mut scene = level("cornell.glb", 16);
    let still = direct_image(&scene, 16);
    scene.lights = prm::rig::Rig::load(&rig, &scene.lights).unwrap().frame(9, 10);
    assert_eq!(scene.lights[0].position, Vec3::new(0.4, 0.45, 0.28));
    let moved = direct_image(&scene, 16);
    let direct = Channels::read(&gt).unwrap().rgb("direct").unwrap();
    assert_images_close(&direct, &moved, 1e-6, "ground-truth direct under the rig");
    // ... and that is not the glTF light's (the comparison above can tell them apart).
    assert!(prm::metric::compare(&still, &moved, None).error > 0.1, "the rig hardly changed the light");
    // A rig naming a light the level lacks is refused.
    std::fs::write(&rig, r#"{"lights": [{"name": "sun"}]}"#).unwrap();
    let (ok, _, err) = prm(&[
        "evaluate",
        &asset("cornell.glb"),
        "--prm",
        s(&prm_path),
        "--rig",
        s(&rig),
        "-o",
        s(&dir.path().join("x.exr")),
    ]);
    assert!(!ok && err.contains("'sun'") && err.contains("no such light"), "{err}");
}

/// A preview .prm of cornell at 32² in `dir`.
fn cornell_preview_map(dir: &Path) -> PathBuf {
    let prm_path = dir.join("c.prm");
    let args =
        ["precompute", &asset("cornell.glb"), "--preset", "preview", "--atlas", "32", "-o", s(&prm_path)];
    let (ok, _, err) = prm(&args);
    assert!(ok, "{err}");
    prm_path
}

/// A preview .prm of cornell at 32² and a rig moving its light sideways, in a temp folder.
fn cornell_map_and_moving_rig() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let prm_path = cornell_preview_map(dir.path());
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
        // Without a rig the lights do not move: one compose for all frames, and equal frames.
        let still = dir.path().join(format!("{backend}-still"));
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
            s(&still),
        ]);
        assert!(ok && stdout.contains("3 frames, 1 composes"), "{backend}: {stdout}");
        let frame = |i: usize| std::fs::read(still.join(format!("frame_{i:04}.exr"))).unwrap();
        assert_eq!(frame(0), frame(2), "{backend}: unmoving lights, different frames");
    }
    let read = |b: &str, f: &str| Channels::read(&dir.path().join(b).join(f)).unwrap().rgb("").unwrap();
    // The CPU backend's lightmap of frame 1 is `prm evaluate` of rig frame 1 of 3 at the same
    // top-K (render's default, 32, with groups): one CPU twin, the same lights, deterministic,
    // so bit for bit.
    let eval = dir.path().join("eval.exr");
    let (ok, _, err) = prm(&[
        "evaluate",
        &asset("cornell.glb"),
        "--prm",
        s(&prm_path),
        "--rig",
        s(&rig),
        "--frame",
        "1",
        "--frames",
        "3",
        "--top-k",
        "32",
        "-o",
        s(&eval),
    ]);
    assert!(ok, "{err}");
    let lightmap = read("cpu", "lightmap_0001.exr");
    assert_eq!(lightmap, Channels::read(&eval).unwrap().rgb("").unwrap(), "CPU render vs evaluate");
    // The CPU frame is `L = emission + albedo / pi (E_direct + E_indirect)` at each pixel
    // centre's first hit, with the rig's frame-1 lights' shadow-ray direct light and the
    // lightmap looked up bilinearly at the hit's lightmap UV (render.rs's doc). The same f32
    // operations: 1e-5 of the brightest pixel is round-off.
    let scene = level("cornell.glb", 32);
    let bvh = prm::Bvh::build(&scene);
    let lights = prm::rig::Rig::load(&rig, &scene.lights).unwrap().frame(1, 3);
    let cam = &scene.cameras[0];
    let (aw, ah) = (32usize, 32usize);
    let (iw, ih) = cam.image_size(24);
    let want: Vec<Vec3> = (0..iw * ih)
        .map(|k| {
            let (origin, d) = cam.ray((k % iw) as f32 + 0.5, (k / iw) as f32 + 0.5, iw, ih);
            let Some(hit) = bvh.closest_hit(origin, d, f32::INFINITY) else { return Vec3::ZERO };
            let (t, b) = (hit.triangle as usize, hit.bary());
            let Some(n) = scene.facing_normal(t, d) else { return Vec3::ZERO };
            let [u0, u1, u2] = scene.uv1_corners(t);
            let uv = u0 * b.x + u1 * b.y + u2 * b.z;
            let (x, y) = (uv.x * aw as f32 - 0.5, uv.y * ah as f32 - 0.5);
            let (fx, fy) = (x - x.floor(), y - y.floor());
            let at = |i: f32, j: f32| {
                lightmap[j.clamp(0.0, ah as f32 - 1.0) as usize * aw + i.clamp(0.0, aw as f32 - 1.0) as usize]
            };
            let (x0, y0) = (x.floor(), y.floor());
            let indirect = at(x0, y0)
                .lerp(at(x0 + 1.0, y0), fx)
                .lerp(at(x0, y0 + 1.0).lerp(at(x0 + 1.0, y0 + 1.0), fx), fy);
            let direct = prm::bvh::direct_irradiance(&bvh, &lights, scene.point(t, b), n);
            scene.material(t).emissive + scene.albedo(t, b) / std::f32::consts::PI * (direct + indirect)
        })
        .collect();
    let cpu = read("cpu", "frame_0001.exr");
    assert_images_close(&cpu, &want, 1e-5, "CPU frame vs the shading formula");
    // The GPU lightmap (shadow-mapped entry visibility) agrees with the CPU twin's (shadow rays).
    let m = prm::metric::compare(&read("gpu", "lightmap_0001.exr"), &lightmap, None);
    assert!(m.error < 0.01, "GPU vs CPU lightmap error {}", m.error);
    // The GPU frame (rasterised, shadow-mapped direct light, the GPU lightmap) against the CPU
    // frame (ray cast, shadow rays): they differ only where a 1024² shadow map and a shadow ray
    // disagree (shadow edges, acne) and in the lightmap's 1 %; 1e-4 measured on llvmpipe, 1 %
    // (error and bias) bounds a few edge pixels wrong while a missing direct or indirect term,
    // or another rig frame's lights, is far outside it.
    let m = prm::metric::compare(&read("gpu", "frame_0001.exr"), &cpu, None);
    assert!(m.error < 0.01 && m.bias.abs() < 0.01, "GPU vs CPU frame: error {} bias {}", m.error, m.bias);
}

#[test]
fn a_level_without_a_camera_or_uvs_is_framed_and_rendered() {
    // One of the generated halls, its camera taken out: no camera and no TEXCOORD_1.
    let dir = tempfile::tempdir().unwrap();
    let mut level = prm_precompute::scenes::halls(1, 1, 8, 2);
    for node in &mut level.nodes {
        node.camera = None;
    }
    let (glb, map, stdout) = bake_hall(dir.path(), &level, &["--atlas", "64"]);
    // Counts not given follow the density: one cluster per 16 entries, the preview's 64 at
    // least.
    assert!(stdout.contains("256 entries") && stdout.contains("64 clusters"), "{stdout}");
    let out = dir.path().join("frames");
    let (ok, stdout, err) = prm(&[
        "render",
        s(&glb),
        "--prm",
        s(&map),
        "--frames",
        "1",
        "--width",
        "32",
        "--backend",
        "cpu",
        "-o",
        s(&out),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("the level has no camera; viewing it from"), "{err}");
    assert!(stdout.contains("1 frames"), "{stdout}");
    let img = Channels::read(&out.join("frame_0000.exr")).unwrap().rgb("").unwrap();
    // The default view is inside the hall, from its lamp: most pixels see a lit surface.
    let lit = img.iter().filter(|v| v.max_element() > 0.0).count();
    assert!(
        img.iter().all(|v| v.is_finite()) && lit > img.len() * 9 / 10,
        "{lit} of {} pixels lit",
        img.len()
    );
}

#[test]
fn bench_with_still_lights_still_measures_the_compose() {
    let dir = tempfile::tempdir().unwrap();
    let prm_path = cornell_preview_map(dir.path());
    let (ok, stdout, err) = prm(&[
        "bench",
        &asset("cornell.glb"),
        "--prm",
        s(&prm_path),
        "--frames",
        "3",
        "--rounds",
        "2",
        "--width",
        "16",
        "--shadow-size",
        "64",
        "--json",
    ]);
    assert!(ok, "{err}");
    let j: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    // The level's own lights never move: each of the 2 x 3 full frames is made to recompose.
    assert_eq!(j["composes_forced"], true, "{stdout}");
    assert_eq!(j["composes"], 6, "{stdout}");
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
    assert_eq!(j["composes_forced"], false, "the rig moves: {stdout}");
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
    // Top-32 picked at each vertex of the tile grid: a tile sums what its four corners pick, at
    // most 4 x 32 panes and the groups.
    let most = part("most_per_tile");
    assert!(
        most > 0 && most <= (4 * 32 + file.groups().len()) as u64,
        "{most} panes in one tile at top-k 32"
    );
    assert!(part("records") >= most);
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

/// The body rows of the markdown table whose header row starts with `header`, as cells.
fn table(md: &str, header: &str) -> Vec<Vec<String>> {
    let mut lines = md.lines().skip_while(|l| !l.starts_with(header)).skip(2);
    let mut rows = Vec::new();
    for l in lines.by_ref().take_while(|l| l.starts_with('|')) {
        rows.push(l.trim_matches('|').split('|').map(|c| c.trim().to_string()).collect());
    }
    assert!(!rows.is_empty(), "no table '{header}' in:\n{md}");
    rows
}

/// A "12.34 %" or "+1.23 %" cell as a number (percent).
fn percent(cell: &str) -> f64 {
    cell.strip_suffix(" %")
        .and_then(|v| v.trim_start_matches('+').parse().ok())
        .unwrap_or_else(|| panic!("'{cell}'"))
}

#[test]
fn report_writes_figures_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let (ok, _, err) = prm(&["report", &asset("cornell.glb"), "--smoke", "-o", s(&out)]);
    assert!(ok, "{err}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in ["Machine:", "GPU device:", "Seeds: 0"] {
        assert!(md.contains(section), "report.md lacks {section}:\n{md}");
    }
    let scene = level("cornell.glb", 32);
    let facts =
        format!("Level: {} triangles, {} lights; atlas 32²", scene.triangles.len(), scene.lights.len());
    assert!(md.contains(&facts), "report.md lacks '{facts}':\n{md}");
    // The tables, their rows (--smoke: two precompute budgets, K = 4 and all, one reference,
    // three rig frames). Errors and noise are normalised RMSEs of non-negative lightmaps: in
    // [0, 100) % at these budgets; a bias of a non-negative lightmap is above -100 %.
    let pre = table(&md, "| entries N");
    let run = table(&md, "| top-K");
    let rf = table(&md, "| photons");
    let rig = table(&md, "| frame");
    assert_eq!([pre.len(), run.len(), rf.len(), rig.len()], [2, 2, 1, 3], "{md}");
    let error_ok = |c: &str| (0.0..100.0).contains(&percent(c));
    let bias_ok = |c: &str| percent(c) > -100.0;
    for r in pre.iter().chain(&rf) {
        assert!(error_ok(&r[2]) && bias_ok(&r[3]), "{r:?}");
    }
    for r in &run {
        assert!(error_ok(&r[2]) && bias_ok(&r[3]) && error_ok(&r[4]) && bias_ok(&r[5]), "{r:?}");
    }
    for (f, r) in rig.iter().enumerate() {
        assert_eq!(r[0], f.to_string());
        let figures = if f == 0 { &r[1..5] } else { &r[1..] };
        assert!(figures.iter().all(|c| error_ok(c)), "{r:?}");
        // The production map has C = 32 clusters, so top-32 composes all of them: the top-32
        // and all columns (error and flicker) are one lightmap's.
        assert_eq!((&r[2], &r[5]), (&r[3], &r[6]), "top-32 vs all at C = 32: {r:?}");
    }
    assert!(md.contains("runtime budget (N=512 M=8 C=32"), "{md}");
    // Light placement: cornell_torches.json's six keyframes, then the smoke sweep (2 cm and
    // 0.5 above the floor), each with its distance to the nearest surface.
    let place = table(&md, "| placement");
    assert_eq!(place.len(), 8, "{md}");
    let distance = |r: &[String]| r[1].parse::<f32>().unwrap();
    assert!((distance(&place[3]) - 0.02).abs() < 1e-3, "2 cm over the floor: {:?}", place[3]);
    assert_eq!(place[6][0], "0.02 above the surface");
    assert!((distance(&place[6]) - 0.02).abs() < 1e-3, "{:?}", place[6]);
    for r in &place {
        let noise = percent(&r[2]);
        assert!(error_ok(&r[2]), "{r:?}");
        // "clean % (raw % raw)", clean = sqrt(raw² - noise²) to the printed decimals, or
        // "within the noise (raw % raw)" where raw <= noise.
        // Error, bias for PRM all, PRM top-32 and the reference.
        assert_eq!(r.len(), 9, "{r:?}");
        assert!([&r[4], &r[6], &r[8]].iter().all(|c| bias_ok(c)), "{r:?}");
        for c in [&r[3], &r[5], &r[7]] {
            let (head, raw) = c.strip_suffix(" raw)").and_then(|c| c.split_once(" (")).unwrap();
            let raw = percent(raw);
            assert!(error_ok(&format!("{raw} %")), "{r:?}");
            if head == "within the noise" {
                assert!(raw <= noise, "{r:?}");
            } else {
                let clean = percent(head);
                // Each printed to 0.005: the squares to 0.01 x the figure.
                let slack = 0.01 * (raw + noise + clean) + 1e-9;
                assert!(raw > noise && (clean * clean - (raw * raw - noise * noise)).abs() <= slack, "{r:?}");
            }
        }
    }
    assert!(out.join("placement.png").is_file());
    // Editing: cornell_edits.json beside the level moves the red wall, recolours the green one
    // and moves the lamp, one after the other. After each, the incremental baker converges to a
    // full re-bake of the edited level with the same frame (the same lightmap to 1e-4 of the
    // mean, precompute/tests/incremental.rs): the same error to the printed decimals.
    let edits = table(&md, "| edit | VPLs");
    assert_eq!(edits.len(), 3, "{md}");
    let after = |c: &str| percent(c.rsplit(": ").next().unwrap());
    for r in &edits {
        assert!(error_ok(&r[2]) && percent(&r[3]).is_finite() && percent(&r[3]) >= 0.0, "{r:?}");
        assert!((after(&r[7]) - after(&r[9])).abs() <= 0.011, "converged vs re-bake: {r:?}");
        // Within a re-bake's noise no later than every update is done (then it is the
        // re-bake, to 1e-4), and that noise is a bake's: above zero, a few percent.
        let seconds = |c: &str| c.split(" s").next().unwrap().parse::<f64>().unwrap();
        assert!(seconds(&r[6]) <= seconds(&r[7]) + 0.005, "{r:?}");
        let noise = percent(r[6].rsplit('(').next().unwrap().trim_end_matches(')'));
        assert!(noise > 0.0 && noise < 30.0, "{r:?}");
        assert!(error_ok(r[5].rsplit(": ").next().unwrap()), "{r:?}");
    }
    // The PRM's updates: the moved wall reaches some tiles; a light edit none, since the map
    // does not depend on the lights.
    let upd = table(&md, "| edit | tiles hit");
    assert_eq!(upd.len(), 3, "{md}");
    assert!(!upd[0][1].starts_with("0 of"), "{:?}", upd[0]);
    assert!(upd[2][1].starts_with("0 of") && upd[2][2].starts_with("0 of"), "{:?}", upd[2]);
    for r in &upd {
        assert!(error_ok(&r[8]) && error_ok(&r[9]), "{r:?}");
        // Update over a full precompute, plain and keeping its cache: shares of a time.
        assert!(percent(&r[5]) >= 0.0 && percent(&r[7]) >= 0.0, "{r:?}");
    }
    // With every pane composed no cluster is left out, so groups add nothing.
    assert_eq!(run[1][0], "all");
    assert_eq!(run[1][2..4], run[1][4..6], "all panes with and without groups");
    // The report says each figure can be re-made alone; re-make the production budget's row
    // and the ground truth's noise with the CLI. Same seeds and parameters, so the same
    // numbers: equal to the printed 2 decimals (0.005 of rounding, 0.006 with f64 slack).
    let gt = dir.path().join("gt.exr");
    let (ok, gt_json, err) = prm(&[
        "ground-truth",
        &asset("cornell.glb"),
        "--atlas",
        "32",
        "--spp",
        "16",
        "--seed",
        "0",
        "--json",
        "-o",
        s(&gt),
    ]);
    assert!(ok, "{err}");
    let noise = serde_json::from_str::<serde_json::Value>(&gt_json).unwrap()["indirect_noise_normalised"]
        .as_f64()
        .unwrap();
    assert!(md.contains(&format!("whose own noise is **{:.2} %**", noise * 100.0)), "noise {noise}:\n{md}");
    let map = dir.path().join("s.prm");
    let (ok, _, err) = prm(&[
        "precompute",
        &asset("cornell.glb"),
        "--atlas",
        "32",
        "--entries",
        "512",
        "--paths",
        "8",
        "--clusters",
        "32",
        "--seed",
        "0",
        "-o",
        s(&map),
    ]);
    assert!(ok, "{err}");
    let lm = dir.path().join("e.exr");
    let (ok, _, err) = prm(&["evaluate", &asset("cornell.glb"), "--prm", s(&map), "-o", s(&lm)]);
    assert!(ok, "{err}");
    let (ok, cmp, err) = prm(&["compare", s(&lm), s(&gt), "--json"]);
    assert!(ok, "{err}");
    let cmp: serde_json::Value = serde_json::from_str(&cmp).unwrap();
    let (error, bias) = (cmp["error"].as_f64().unwrap() * 100.0, cmp["bias"].as_f64().unwrap() * 100.0);
    assert_eq!(pre[1][0], "N=512 M=8 C=32");
    let near = |cell: &str, want: f64, tol: f64| (percent(cell) - want).abs() <= tol;
    assert!(
        near(&pre[1][2], error, 0.006) && near(&pre[1][3], bias, 0.006),
        "{:?} vs {error} {bias}",
        pre[1]
    );
    // The runtime's all-panes row is that lightmap too: exactly on the CPU twin; with a GPU,
    // shadow-mapped entry visibility moves it by the GPU-vs-CPU lightmap difference (under 1 %
    // of the lightmap, render_writes_frames_that_follow_the_rig), and by the triangle
    // inequality the error and bias against the same ground truth by about as much: 1 point.
    let tol = if md.contains("GPU device: none found") { 0.006 } else { 1.0 };
    assert!(near(&run[1][2], error, tol) && near(&run[1][3], bias, tol), "{:?} vs {error} {bias}", run[1]);
    // Plots need a font; CI installs one (fonts-dejavu-core).
    if md.contains("precompute.png") {
        for png in ["precompute.png", "runtime.png", "rig.png", "editing.png"] {
            assert!(std::fs::metadata(out.join(png)).unwrap().len() > 10_000, "{png} is empty");
        }
    } else {
        assert!(err.contains("fonts-dejavu-core"), "{err}");
    }
}

#[test]
fn report_scale_section_measures_each_size_as_a_user_would() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    // No level: only the scale section. --smoke: one and two halls at 1 m texels in 64^2 pages.
    let (ok, _, err) = prm(&["report", "--scale", "--smoke", "-o", s(&out)]);
    assert!(ok, "{err}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.starts_with("# Accuracy and cost against the level's size"), "{md}");
    assert!(!md.contains("## PRM: precompute budget"), "a level's part without a level:\n{md}");
    let cost = table(&md, "| halls | triangles");
    let accuracy = table(&md, "| halls | GT noise");
    let per_hall = table(&md, "| halls | precompute");
    assert_eq!([cost.len(), accuracy.len(), per_hall.len()], [2, 2, 2], "{md}");
    assert_eq!([&cost[0][0], &cost[1][0]], ["1", "2"]);
    // One hall fits one page; two halls' charts need several pages (the density estimated
    // one: they get pages at the texel size asked for), and their map loads the level again
    // with the same UVs for the ground truth and the runtime.
    assert!(cost[0][3].ends_with("(1 x 64²)"), "{:?}", cost[0]);
    assert!(!cost[1][3].contains("(1 x"), "{:?}", cost[1]);
    let args = ["--seed", "0", "--texel-size", "1", "--page-size", "64", "--entries", "256", "--paths", "8"];
    assert!(md.contains(&args[..].join(" ")), "the report states the precompute arguments:\n{md}");
    for (row, name) in cost.iter().zip(["halls_1x1", "halls_2x1"]) {
        // The map is kept; its size is the table's.
        let kept = out.join("scale").join(format!("{name}.prm"));
        let bytes = std::fs::read(&kept).unwrap();
        assert_eq!(row[8], format!("{:.1} MB", bytes.len() as f64 / 1e6), "{row:?}");
        // A user's `prm precompute` with the stated arguments makes the same bytes.
        let glb = out.join("scale").join(format!("{name}.glb"));
        let again = dir.path().join(format!("{name}.prm"));
        let mut cmd = vec!["precompute", s(&glb), "-o", s(&again), "--clusters", "16"];
        cmd.extend(args);
        let (ok, _, err) = prm(&cmd);
        assert!(ok, "{err}");
        assert!(std::fs::read(&again).unwrap() == bytes, "{name}: the report's map is not a user's");
        // The precompute holds the whole map before it writes it: its peak is above the size
        // (where the system tells the peak: Linux's VmHWM).
        if let Ok(peak) = row[7].trim_end_matches(" MB").parse::<f64>() {
            assert!(peak * 1e6 >= bytes.len() as f64, "{row:?}");
        }
    }
    // The ground truth's noise is `prm ground-truth`'s on the same level, texels and seed.
    let glb = out.join("scale").join("halls_2x1.glb");
    let gt = dir.path().join("gt.exr");
    let (ok, gt_json, err) = prm(&[
        "ground-truth",
        s(&glb),
        "--texel-size",
        "1",
        "--page-size",
        "64",
        "--spp",
        "8",
        "--seed",
        "0",
        "--json",
        "-o",
        s(&gt),
    ]);
    assert!(ok, "{err}");
    let noise = serde_json::from_str::<serde_json::Value>(&gt_json).unwrap()["indirect_noise_normalised"]
        .as_f64()
        .unwrap();
    assert_eq!(accuracy[1][1], format!("{:.2} %", noise * 100.0), "{:?}", accuracy[1]);
    for r in &accuracy {
        assert!(r[1..4].iter().all(|c| (0.0..100.0).contains(&percent(c))), "{r:?}");
        assert!(percent(&r[4]) > -100.0, "{r:?}");
    }
    // Per hall over the first level's: the first row is the unit.
    assert!(per_hall[0][1..5].iter().all(|c| c == "1.00" || c == "-"), "{:?}", per_hall[0]);
    assert_eq!(per_hall[0][1], "1.00", "{:?}", per_hall[0]);
    if md.contains("scale.png") {
        assert!(std::fs::metadata(out.join("scale.png")).unwrap().len() > 10_000, "scale.png is empty");
    }
}

#[test]
fn a_level_in_several_lightmap_pages_bakes_evaluates_and_renders_on_both_backends() {
    // One of the generated halls (no TEXCOORD_1) at 0.3 m texels needs about 100^2 texels: in
    // pages of 64^2, several pages.
    let dir = tempfile::tempdir().unwrap();
    let level = prm_precompute::scenes::halls(1, 1, 8, 2);
    let (glb, map, stdout) = bake_hall(dir.path(), &level, &["--texel-size", "0.3", "--page-size", "64"]);
    assert!(stdout.contains("pages of 64^2"), "{stdout}");
    let header = prm::prm_file::Prm::read(&map, None).unwrap().header().clone();
    let pages = header.pages;
    assert!(pages >= 2 && header.atlas_width == 64 && header.atlas_height == 64 * pages, "{header:?}");
    assert_eq!(header.page_texel_size, 0.3);
    // `prm info --prm` describes the map's atlas and states the GPU memory the runtime needs:
    // the tables `GpuMemory::estimate` lists (held to the allocations in the runtime's tests)
    // and the level's lights' shadow maps.
    let (ok, stdout, err) = prm(&["info", s(&glb), "--prm", s(&map), "--json"]);
    assert!(ok, "{err}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(info["texels"]["pages"], pages);
    let m = &info["gpu_memory"];
    let read = prm::prm_file::Prm::read(&map, None).unwrap();
    let stated = prm_runtime::GpuMemory::estimate(&read).total();
    // And the stay shares, as the map holds them.
    let shares: Vec<f32> = (0..read.entries().len()).map(|j| read.stay(j)).collect();
    let st = &info["stay_shares"];
    assert_eq!(st["entries"], shares.len());
    assert_eq!(st["losing"], shares.iter().filter(|&&s| s < 0.95).count());
    assert_eq!(st["lowest"].as_f64().unwrap() as f32, shares.iter().copied().fold(1.0, f32::min));
    // The bounce gains' range: each at least its stay share, and none more than a closed room
    // of the level's brightest albedo sends back, 1 / (1 - albedo).
    let gains: Vec<f32> = (0..read.entries().len()).map(|j| prm::luminance(read.gain(j))).collect();
    assert_eq!(st["gain_highest"].as_f64().unwrap() as f32, gains.iter().copied().fold(0.0, f32::max));
    let brightest = read.entries().iter().map(|e| e.albedo.max_element()).fold(0.0, f32::max);
    let most = 1.0001 / (1.0 - brightest);
    // (A gain equal to its share reads a part in a million under it through the luminance.)
    let at_least = |(g, s): (&f32, &f32)| *g >= s * (1.0 - 1e-6);
    assert!(gains.iter().zip(&shares).all(at_least) && gains.iter().all(|&g| g <= most), "{gains:?}");
    // The panes' power scales, as the map's header states them, within their bounds.
    let scale = &info["power_scale"];
    assert_eq!(scale, &read.header().provenance["power_scale"]);
    let (lo, hi) = (scale[0].as_f64().unwrap(), scale[1].as_f64().unwrap());
    assert!(0.5 <= lo && lo <= hi && hi <= 2.0, "{scale}");
    assert_eq!(m["tables_bytes"], stated);
    assert_eq!(m["total_bytes"].as_u64().unwrap(), stated + m["shadow_maps_bytes"].as_u64().unwrap());
    assert!(m["shadow_maps_bytes"].as_u64().unwrap() > 0, "{m}");
    // The map loads the level again with the same UVs (its header says how), for every
    // command; the CPU render's lightmap is `prm evaluate`'s, bit for bit.
    let eval = dir.path().join("eval.exr");
    let (ok, _, err) = prm(&["evaluate", s(&glb), "--prm", s(&map), "--top-k", "32", "-o", s(&eval)]);
    assert!(ok, "{err}");
    let evaluated = Channels::read(&eval).unwrap();
    assert_eq!(evaluated.pages, pages as usize, "the EXR has a layer set per page");
    assert_eq!((evaluated.width, evaluated.height), (64, 64 * pages as usize));
    for backend in ["cpu", "gpu"] {
        let out = dir.path().join(backend);
        let (ok, stdout, err) = prm(&[
            "render",
            s(&glb),
            "--prm",
            s(&map),
            "--frames",
            "1",
            "--width",
            "48",
            "--backend",
            backend,
            "--lightmap-out",
            "-o",
            s(&out),
        ]);
        assert!(ok, "{err}");
        assert_eq!(stdout.contains("device:"), backend == "gpu", "{backend}: {stdout}");
    }
    let read = |b: &str, f: &str| Channels::read(&dir.path().join(b).join(f)).unwrap().rgb("").unwrap();
    let cpu_lightmap = read("cpu", "lightmap_0000.exr");
    assert_eq!(cpu_lightmap, evaluated.rgb("").unwrap(), "CPU render vs evaluate");
    assert!(cpu_lightmap.iter().any(|v| v.max_element() > 0.0), "an empty lightmap");
    // The GPU composes into a texture array, a layer per page, and reads it back stacked: the
    // same lightmap as the CPU twin's, and frames shaded from it that agree with the CPU's.
    // Shadow maps against shadow rays differ more in a hall of pillars than in cornell: measured
    // on this hall, lightmap 0.9 % and frame 1.3-1.6 % paged, 2.1 % and 1.1 % in one 256^2 page;
    // a lookup in the wrong page or row is 30 % and more (checked by breaking the shader's).
    let m = prm::metric::compare(&read("gpu", "lightmap_0000.exr"), &cpu_lightmap, None);
    assert!(m.error < 0.03, "GPU vs CPU lightmap over {pages} pages: error {}", m.error);
    let (gpu_frame, cpu_frame) = (read("gpu", "frame_0000.exr"), read("cpu", "frame_0000.exr"));
    let lit = cpu_frame.iter().filter(|v| v.max_element() > 0.0).count();
    assert!(lit > cpu_frame.len() / 2, "{lit} of {} pixels lit", cpu_frame.len());
    let m = prm::metric::compare(&gpu_frame, &cpu_frame, None);
    assert!(m.error < 0.03 && m.bias.abs() < 0.01, "GPU vs CPU frame: error {} bias {}", m.error, m.bias);
}

#[test]
fn a_gpu_budget_leaves_out_what_the_camera_does_not_see_on_both_backends() {
    // Two halls in a row; the camera stands in the first. A budget a third short of the
    // tables leaves out tiles out of view, and the frame the camera sees hardly changes.
    let dir = tempfile::tempdir().unwrap();
    let level = prm_precompute::scenes::halls(2, 1, 8, 2);
    let (glb, map, _) = bake_hall(dir.path(), &level, &["--texel-size", "0.3"]);
    let info = |extra: &[&str]| {
        let mut args = vec!["info", s(&glb), "--prm", s(&map), "--shadow-size", "256", "--json"];
        args.extend_from_slice(extra);
        let (ok, stdout, err) = prm(&args);
        assert!(ok, "{err}");
        serde_json::from_str::<serde_json::Value>(&stdout).unwrap()["gpu_memory"].clone()
    };
    let whole = info(&[]);
    let (tables, total) = (whole["tables_bytes"].as_u64().unwrap(), whole["total_bytes"].as_u64().unwrap());
    let budget_mb = format!("{}", (total - tables / 3) as f64 / 1e6);
    let b = info(&["--gpu-budget", &budget_mb])["budget"].clone();
    assert!(b["atlas_tiles_left_out"].as_u64().unwrap() > 0, "{b}");
    assert!(b["after_bytes"].as_u64().unwrap() <= b["budget_bytes"].as_u64().unwrap(), "{b}");
    assert_eq!((b["in_view"].as_u64(), b["shadow_size"].as_u64()), (Some(0), Some(256)), "{b}");
    assert!(b["text"].as_str().unwrap().contains("none in the camera's view"), "{b}");
    // Too small for anything: refused, saying what it needs; nonsense: refused, naming it.
    let (ok, _, err) = prm(&["info", s(&glb), "--prm", s(&map), "--gpu-budget", "0.001"]);
    assert!(!ok && err.contains("give at least"), "{err}");
    let (ok, _, err) = prm(&["info", s(&glb), "--prm", s(&map), "--gpu-budget", "NaN"]);
    assert!(!ok && err.contains("--gpu-budget"), "{err}");

    let render = |backend: &str, budget: Option<&str>| {
        let out = dir.path().join(format!("{backend}-{}", budget.is_some()));
        let mut args = vec![
            "render",
            s(&glb),
            "--prm",
            s(&map),
            "--frames",
            "1",
            "--width",
            "48",
            "--shadow-size",
            "256",
            "--backend",
            backend,
            "--lightmap-out",
            "-o",
            s(&out),
        ];
        if let Some(mb) = budget {
            args.extend_from_slice(&["--gpu-budget", mb]);
        }
        let (ok, stdout, err) = prm(&args);
        assert!(ok, "{err}");
        assert_eq!(stdout.contains("left out"), budget.is_some(), "{stdout}");
        assert_eq!(stdout.contains("device:"), backend == "gpu", "{backend}: {stdout}");
        let read = |f: &str| Channels::read(&out.join(f)).unwrap().rgb("").unwrap();
        (read("frame_0000.exr"), read("lightmap_0000.exr"))
    };
    let (cpu_frame, cpu_lightmap) = render("cpu", Some(&budget_mb));
    let (whole_frame, whole_lightmap) = render("cpu", None);
    // Texels left out are black; the ones kept are the whole map's but at the cut.
    let gone = cpu_lightmap
        .iter()
        .zip(&whole_lightmap)
        .filter(|(a, b)| a.max_element() == 0.0 && b.max_element() > 0.0);
    assert!(gone.count() > 0, "no texel left out");
    // What the camera sees: within 2 % of the whole map's frame (measured 1.0 %; 0.10 % while
    // the lift read one texel per cell: a cell the cut splits now reads the near field's mean
    // over its kept texels, and at 30 cm texels a cell has a handful; GPU vs CPU under the
    // budget: lightmap 0.49 %, frame 1.5 %).
    let m = prm::metric::compare(&cpu_frame, &whole_frame, None);
    assert!(m.error < 0.02, "the budget changed the camera's frame by {}", m.error);
    // The GPU runs the same reduced map: its lightmap and frame agree with the CPU twin's as
    // on the whole map (see the paged test for the tolerances).
    let (gpu_frame, gpu_lightmap) = render("gpu", Some(&budget_mb));
    let m = prm::metric::compare(&gpu_lightmap, &cpu_lightmap, None);
    assert!(m.error < 0.03, "GPU vs CPU lightmap under a budget: error {}", m.error);
    let m = prm::metric::compare(&gpu_frame, &cpu_frame, None);
    assert!(m.error < 0.03 && m.bias.abs() < 0.01, "GPU vs CPU frame: error {} bias {}", m.error, m.bias);
}

#[test]
fn bake_applies_an_edit_script_and_refuses_a_bad_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let out = dir.join("b.exr");
    let script = dir.join("edits.json");
    // The Cornell box baked with `edits` as its script into `out`, at `atlas` and `paths`.
    let bake = |edits: &str, out: &Path, atlas: &str, paths: &str| {
        std::fs::write(&script, edits).unwrap();
        let cornell = asset("cornell.glb");
        let args = [
            "bake",
            &cornell,
            "--atlas",
            atlas,
            "--paths",
            paths,
            "--edits",
            s(&script),
            "-o",
            s(out),
            "--json",
        ];
        prm(&args)
    };
    let edits = r#"[{"move": {"node": "red", "by": [0.02, 0.0, 0.0]}}, {"albedo": {"material": 0, "rgb": [0.5, 0.5, 0.5]}}]"#;
    let (ok, stdout, stderr) = bake(edits, &out, "32", "2000");
    assert!(ok, "{stderr}");
    let j: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(j["edits"].as_array().unwrap().len(), 2);
    assert!(j["edits"][0]["paths_changed"].as_u64().unwrap() > 0);
    // The direct layer is the direct light of the edited level: the wall moved 2 cm.
    let ch = Channels::read(&out).unwrap();
    assert!(ch.rgb("indirect").unwrap().iter().any(|x| x.x > 0.0));
    // The lamp sent far out of the level: all its light is taken out again, and what is left
    // (round-off) is written as no light, not as a negative one.
    let (ok, _, stderr) = bake(r#"[{"light": {"id": 0, "position": [1e6, 0.0, 0.0]}}]"#, &out, "32", "2000");
    assert!(ok, "{stderr}");
    let ch = Channels::read(&out).unwrap();
    for layer in ["direct", "indirect"] {
        let v = ch.rgb(layer).unwrap();
        assert!(v.iter().all(|x| x.min_element() >= 0.0 && x.max_element() < 1e-6), "{layer}");
    }
    // A light added 1e7 times the lamp's flux takes the bake's paths, not 1e7 times them (it
    // took memory until the machine ran out).
    let (ok, _, stderr) = bake(
        r#"[{"add_light": {"position": [0.2, 0.2, 0.2], "intensity": [1e8, 1e8, 1e8]}}]"#,
        &out,
        "16",
        "100",
    );
    assert!(ok, "{stderr}");
    for (bad, says) in [
        (r#"[{"move": {"node": "no_such_node", "by": [1, 0, 0]}}]"#, "no node named"),
        (r#"[{"light": {"id": 0, "intensity": [1e38, 1e38, 1e38]}}]"#, "beyond 1e9"),
        (r#"[{"light": {"id": 0, "position": [2e7, 0, 0]}}]"#, "beyond 1e7 m"),
        (r#"[{"teleport": {}}]"#, "unknown edit"),
        (r#"[{"albedo": {"material": 0, "rgb": [2, 0, 0]}}]"#, "outside [0, 1]"),
        (r#"{"move": 1}"#, "a JSON list"),
    ] {
        let out = dir.join("bad.exr");
        let (ok, _, stderr) = bake(bad, &out, "16", "100");
        assert!(!ok && stderr.contains(says), "{bad}: {stderr}");
        assert!(!out.exists(), "{bad}: no output on error");
    }
}

fn level_at(path: &Path, atlas: u32) -> prm::Scene {
    let opts =
        prm::gltf_load::LoadOptions { unwrap_resolution: Some(atlas.clamp(16, 8192)), ..Default::default() };
    prm::gltf_load::load_scene(path, &opts).unwrap()
}

/// The glb at `path` with its JSON chunk changed by `edit`.
fn edited_glb(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let b = std::fs::read(path).unwrap();
    let json_len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    let mut doc: serde_json::Value = serde_json::from_slice(&b[20..20 + json_len]).unwrap();
    let bin_at = 20 + json_len;
    let bin_len = u32::from_le_bytes(b[bin_at..bin_at + 4].try_into().unwrap()) as usize;
    let bin = &b[bin_at + 8..bin_at + 8 + bin_len];
    edit(&mut doc);
    prm::glb::glb_bytes(&doc, bin)
}

/// The glb at `path` with node `name` translated by `by`.
fn moved_glb(path: &Path, name: &str, by: [f32; 3]) -> Vec<u8> {
    edited_glb(path, |doc| {
        let node = doc["nodes"].as_array_mut().unwrap().iter_mut().find(|n| n["name"] == name).unwrap();
        node["translation"] = serde_json::json!(by);
    })
}

/// `prm info` shows each light's aperture and warns of a sphere light that reaches into the
/// level: the chamber's spot (0.2 m under the 7 m ceiling) given a 0.25 m radius, its lamp
/// (5 m up) 0.1 m: the spot has the ceiling 0.20-0.21 m from its centre, the lamp nothing.
#[test]
fn info_warns_of_a_sphere_light_inside_geometry() {
    let tmp = tempfile::tempdir().unwrap();
    let level = tmp.path().join("bulbs.glb");
    let bytes = edited_glb(Path::new(&asset("chamber.glb")), |doc| {
        let lights = doc["extensions"]["KHR_lights_punctual"]["lights"].as_array_mut().unwrap();
        lights[0]["extras"] = serde_json::json!({"prm_radius": 0.1});
        lights[1]["extras"] = serde_json::json!({"prm_radius": 0.25});
    });
    std::fs::write(&level, bytes).unwrap();
    let (ok, out, err) = prm(&["info", s(&level), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let lights = v["lights"].as_array().unwrap();
    assert_eq!(lights[0]["aperture"], "sphere of radius 0.1000 m");
    assert!(lights[0]["geometry_inside"].is_null(), "{}", lights[0]);
    let t = lights[1]["geometry_inside"].as_f64().unwrap();
    assert!((0.199..=0.21).contains(&t), "the ceiling {t} m from the spot's centre");
    let (ok, out, err) = prm(&["info", s(&level)]);
    assert!(ok, "{err}");
    assert_eq!(out.matches("warning: geometry").count(), 1, "{out}");
}

#[test]
fn bake_watch_follows_a_level_saved_again() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let level = dir.join("level.glb");
    std::fs::copy(asset("cornell.glb"), &level).unwrap();
    let out = dir.join("w.exr");
    let child = Command::new(env!("CARGO_BIN_EXE_prm"))
        .args(["bake", s(&level), "--atlas", "32", "--paths", "2000", "--watch", "--watch-limit", "1"])
        .args(["--watch-interval", "0.05", "-o", s(&out)])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for the first bake's output, then save the level with the red wall moved 3 cm.
    let start = std::time::Instant::now();
    while !out.exists() && start.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let before = Channels::read(&out).unwrap().rgb("direct").unwrap();
    let moved = moved_glb(&level, "red", [0.03, 0.0, 0.0]);
    std::thread::sleep(std::time::Duration::from_millis(1100)); // a distinct modification time
    std::fs::write(dir.join("tmp.glb"), moved).unwrap();
    std::fs::rename(dir.join("tmp.glb"), &level).unwrap();
    let o = child.wait_with_output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.contains("reload 1: 1 edits (1 node transforms)"), "{stdout}\n{stderr}");
    assert!(stdout.contains("converged"), "{stdout}");
    // The output now shows the edited level: its direct light is a fresh bake's of it.
    let after = Channels::read(&out).unwrap().rgb("direct").unwrap();
    let want = direct_image(&level_at(&level, 32), 32);
    assert_ne!(before, after, "the lightmap followed the edit");
    assert_images_close(&after, &want, 1e-3, "direct light after the watched edit");
}

#[test]
fn precompute_update_reuses_the_cache_and_refuses_what_it_cannot_do() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let level = dir.join("level.glb");
    std::fs::copy(asset("cornell.glb"), &level).unwrap();
    let opts = ["--preset", "preview", "--atlas", "32", "--paths", "4"];
    let (old, new) = (dir.join("old.prm"), dir.join("new.prm"));
    let (ok, _, err) = prm(&[&["precompute", s(&level), "-o", s(&old), "--cache"][..], &opts].concat());
    assert!(ok, "{err}");
    let cache = dir.join("old.prm.cache");
    assert!(cache.exists());
    // The level unchanged: the same file, nothing walked again.
    let (ok, out, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&new)][..], &opts].concat());
    assert!(ok, "{err}");
    assert!(
        out.contains("the edit reached 0 room(s) and 0 of 4 atlas tiles") && out.contains("0 of"),
        "{out}"
    );
    assert_eq!(std::fs::read(&old).unwrap(), std::fs::read(&new).unwrap());
    assert_eq!(std::fs::read(&cache).unwrap(), std::fs::read(dir.join("new.prm.cache")).unwrap());
    // The red wall, the box's side at its largest x, moved out: the level's bounds move, and
    // every ray's offsets with them: said, and a full precompute instead.
    let original = std::fs::read(&level).unwrap();
    std::fs::write(&level, moved_glb(&level, "red", [0.03, 0.0, 0.0])).unwrap();
    let (ok, _, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&new)][..], &opts].concat());
    assert!(ok && err.contains("cannot update: the edit moved the level's bounds"), "{err}");
    // Moved in: the update writes a map for the moved level (another fingerprint).
    std::fs::write(&level, &original).unwrap();
    std::fs::write(&level, moved_glb(&level, "red", [-0.03, 0.0, 0.0])).unwrap();
    let (ok, out, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&new), "--json"][..], &opts].concat());
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["update"]["refused"].is_null(), "{out}");
    assert!(v["update"]["tiles_hit"].as_u64().unwrap() > 0, "{out}");
    prm::prm_file::Prm::read(&new, Some(&level_at(&level, 32))).unwrap();
    // Other options than the old bake's: said, and a full precompute instead.
    let mut other = opts.to_vec();
    other[5] = "8";
    let (ok, _, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&new)][..], &other].concat());
    assert!(ok && err.contains("cannot update: the parameters differ"), "{err}");
    // No cache, or a damaged one: an error naming it, and nothing written.
    let gone = dir.join("gone.prm");
    std::fs::remove_file(&cache).unwrap();
    let (ok, _, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&gone)][..], &opts].concat());
    assert!(!ok && err.contains("has no update cache") && err.contains("--cache"), "{err}");
    std::fs::write(&cache, b"PRMUPDT\n not really").unwrap();
    let (ok, _, err) =
        prm(&[&["precompute", s(&level), "--update", s(&old), "-o", s(&gone)][..], &opts].concat());
    assert!(!ok && err.contains("damaged"), "{err}");
    assert!(!gone.exists());
}

#[test]
fn a_precompute_in_parts_merges_to_one_machines_bytes() {
    // One of the generated halls (no TEXCOORD_1) in several lightmap pages: the plan generates
    // its UVs, the shards load it without them, and the merge writes the bytes one
    // `prm precompute` does.
    let dir = tempfile::tempdir().unwrap();
    let level = prm_precompute::scenes::halls(1, 1, 8, 2);
    let lightmap = ["--texel-size", "0.3", "--page-size", "64"];
    let (glb, map, _) = bake_hall(dir.path(), &level, &lightmap);
    let plan = dir.path().join("hall.plan");
    let mut args = vec!["precompute", s(&glb), "--preset", "preview", "--entries", "256", "--paths", "4"];
    args.extend_from_slice(&lightmap);
    args.extend_from_slice(&["--prepare", "-o", s(&plan)]);
    let (ok, stdout, err) = prm(&args);
    assert!(ok && stdout.contains("the plan of a precompute in parts"), "{err}");
    let parts: Vec<PathBuf> = (0..3).map(|i| dir.path().join(format!("part{i}"))).collect();
    for (i, part) in parts.iter().enumerate() {
        let shard = format!("{i}/3");
        let (ok, _, err) =
            prm(&["precompute", s(&glb), "--shard", &shard, "--plan", s(&plan), "-o", s(part)]);
        assert!(ok, "{err}");
    }
    let merged = dir.path().join("merged.prm");
    let (ok, _, err) =
        prm(&["merge", "--plan", s(&plan), s(&parts[2]), s(&parts[0]), s(&parts[1]), "-o", s(&merged)]);
    assert!(ok, "{err}");
    assert!(std::fs::read(&merged).unwrap() == std::fs::read(&map).unwrap(), "merged file differs");

    // Bad shard arguments, and a part missing: clear errors, nothing written.
    let out = dir.path().join("never");
    for (shard, extra, says) in [
        ("3/3", None, "--shard 3/3"),
        ("1/0", None, "--shard 1/0"),
        ("one/3", None, "--shard one/3"),
        ("1/3", Some("--seed"), "--seed with --shard"),
    ] {
        let mut args = vec!["precompute", s(&glb), "--shard", shard, "--plan", s(&plan), "-o", s(&out)];
        if let Some(flag) = extra {
            args.extend_from_slice(&[flag, "4"]);
        }
        let (ok, _, err) = prm(&args);
        assert!(!ok && err.contains(says), "{shard}: {err}");
    }
    let (ok, _, err) = prm(&["precompute", s(&glb), "--shard", "1/3", "-o", s(&out)]);
    assert!(!ok && err.contains("--plan"), "{err}");
    let (ok, _, err) = prm(&[
        "precompute",
        s(&glb),
        "--shard",
        "1/3",
        "--plan",
        s(&plan),
        "--preset",
        "preview",
        "-o",
        s(&out),
    ]);
    assert!(!ok && err.contains("--preset") && err.contains("--shard"), "{err}");
    let (ok, _, err) = prm(&["merge", "--plan", s(&plan), s(&parts[0]), s(&parts[1]), "-o", s(&out)]);
    assert!(!ok && err.contains("shard 2 of 3 missing") && err.contains("not written"), "{err}");
    assert!(!out.exists());
}

#[test]
fn moving_objects_render_with_precomputed_visibility() {
    // The doorway level at a 32² atlas: `prm visibility`, then `prm render --mode cssm` over
    // the door/block rig with its lightmaps, its ground-truth error and the PRM baseline.
    let dir = tempfile::tempdir().unwrap();
    let level = asset("doorway.glb");
    let rig = asset("doorway_rig.json");
    let vis = dir.path().join("doorway.vis");
    let (ok, out, err) = prm(&["visibility", &level, "--atlas", "32", "--res", "8", "-o", s(&vis)]);
    assert!(ok && out.contains("2 movable"), "{err}");
    let map = dir.path().join("doorway.prm");
    let (ok, _, err) = prm(&[
        "precompute",
        &level,
        "--atlas",
        "32",
        "--preset",
        "preview",
        "--entries",
        "256",
        "--paths",
        "4",
        "-o",
        s(&map),
    ]);
    assert!(ok, "{err}");
    let frames = dir.path().join("frames");
    let (ok, out, err) = prm(&[
        "render",
        &level,
        "--mode",
        "cssm",
        "--vis",
        s(&vis),
        "--rig",
        &rig,
        "--frames",
        "2",
        "--width",
        "32",
        "--backend",
        "cpu",
        "--lightmap-out",
        "--ground-truth-spp",
        "16",
        "--baseline-prm",
        s(&map),
        "-o",
        s(&frames),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("indirect error") && out.contains("baseline PRM"), "{out}");
    for f in ["frame_0001.png", "frame_0001.exr", "lightmap_0001.exr"] {
        assert!(frames.join(f).exists(), "{f} missing");
    }
    // The door open at the last frame: room B's lightmap gains light over the first frame's.
    let read = |p: &std::path::Path| prm::exr_io::Channels::read(p).unwrap().rgb("").unwrap();
    let (first, last) = (read(&frames.join("lightmap_0000.exr")), read(&frames.join("lightmap_0001.exr")));
    let sum = |v: &[glam::Vec3]| v.iter().map(|c| prm::luminance(*c) as f64).sum::<f64>();
    assert!(sum(&last) > sum(&first), "opening the door added no indirect light");
    // The bench: CPU twin beside the GPU pass, side by side.
    let (ok, out, err) = prm(&[
        "bench",
        &level,
        "--mode",
        "cssm",
        "--vis",
        s(&vis),
        "--rig",
        &rig,
        "--frames",
        "2",
        "--rounds",
        "1",
        "--json",
    ]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(report["radiosity_cpu"]["median_ms"].as_f64().unwrap() > 0.0, "{out}");
    assert!(report["texels"].as_u64().unwrap() > 0);
    // With an adapter, the GPU's whole frame: shadow-mapped direct light, then the radiosity.
    if report["device"] != "none" {
        for k in ["direct_gpu", "radiosity_gpu", "frame_gpu"] {
            assert!(report[k]["median_ms"].as_f64().unwrap() > 0.0, "{k}: {out}");
        }
    }
    // Bad input: no --vis, a --prm in cssm mode, a damaged or missing visibility file.
    let base = [
        "render",
        level.as_str(),
        "--mode",
        "cssm",
        "--rig",
        rig.as_str(),
        "--frames",
        "1",
        "-o",
        s(&frames),
    ];
    let run = |extra: &[&str]| {
        let mut args: Vec<&str> = base.to_vec();
        args.extend_from_slice(extra);
        prm(&args)
    };
    let (ok, _, err) = run(&[]);
    assert!(!ok && err.contains("needs the level's visibility"), "{err}");
    let (ok, _, err) = run(&["--vis", s(&vis), "--prm", s(&map)]);
    assert!(!ok && err.contains("--prm is for --mode prm"), "{err}");
    let bad = dir.path().join("bad.vis");
    let mut bytes = std::fs::read(&vis).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0x40;
    std::fs::write(&bad, &bytes).unwrap();
    let (ok, _, err) = run(&["--vis", s(&bad)]);
    assert!(!ok && err.contains("bad.vis") && err.contains("checksum"), "{err}");
    let (ok, _, err) = run(&["--vis", s(&dir.path().join("none.vis"))]);
    assert!(!ok && err.contains("none.vis"), "{err}");
    let (ok, _, err) = prm(&["visibility", &level, "--atlas", "32", "--res", "0", "-o", s(&bad)]);
    assert!(!ok && err.contains("cube resolution"), "{err}");
}

#[test]
fn the_report_has_a_moving_objects_section_on_a_level_with_movables() {
    // The doorway level with its objects rig beside it (--smoke: 32² atlas, 3 frames).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let (ok, _, err) = prm(&["report", &asset("doorway.glb"), "--smoke", "-o", s(&out)]);
    assert!(ok, "{err}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let section = md.split("## Moving objects").nth(1).expect("no moving-objects section");
    let section = section.split("\n## ").next().unwrap();
    let rows: Vec<&str> = section
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| t ") && !l.starts_with("| ---"))
        .collect();
    assert_eq!(rows.len(), 3, "{section}");
    // Every row gives both errors as finite percentages.
    for r in rows {
        let cells: Vec<&str> = r.split('|').map(str::trim).collect();
        for c in [cells[2], cells[4]] {
            let v: f64 = c.trim_end_matches(" %").parse().unwrap_or(f64::NAN);
            assert!(v.is_finite() && v >= 0.0, "{r}");
        }
    }
    // doorway_edits.json beside it: the editing part. At this scale (516 entries) the moved
    // block changes how many entries lie clear of solids, so the map cannot be updated: the
    // report says why and times a full precompute in its place, as `prm precompute --update`.
    let upd = table(&md, "| edit | tiles hit");
    assert_eq!(upd.len(), 3, "{md}");
    assert!(upd[0][1].starts_with("refused (") && upd[0][1].contains("entries"), "{:?}", upd[0]);
    let (walked, of) = upd[0][2].split_once(" of ").unwrap();
    assert_eq!(walked, of, "every texel walked: {:?}", upd[0]);
    for r in &upd {
        assert!(percent(&r[8]).is_finite() && percent(&r[9]).is_finite(), "{r:?}");
    }
}
