//! The glTF loader: what it reads, and the error each kind of bad input gets. Fixture files are
//! written by the test with `prm::glb`.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};
use prm::glb::{glb_bytes, GlbLight, GlbMaterial, GlbMesh, GlbNode, GlbScene};
use prm::{load_scene, LightKind, LoadOptions, SceneError};

fn material(albedo: [f32; 3]) -> GlbMaterial {
    GlbMaterial {
        name: "m".into(),
        base_color: [albedo[0], albedo[1], albedo[2], 1.0],
        emissive: [0.0; 3],
        double_sided: false,
    }
}

/// A unit quad in the xz plane facing +y, with lightmap UVs filling [0.1, 0.9]^2.
fn quad_mesh() -> GlbMesh {
    GlbMesh {
        name: "quad".into(),
        positions: vec![[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
        normals: None,
        uv1: Some(vec![[0.1, 0.1], [0.1, 0.9], [0.9, 0.9], [0.9, 0.1]]),
        indices: Some(vec![0, 1, 2, 0, 2, 3]),
        material: Some(0),
    }
}

fn one_quad() -> GlbScene {
    let mut s = GlbScene { materials: vec![material([0.5, 0.5, 0.5])], ..Default::default() };
    s.add_mesh(quad_mesh());
    s
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn load(path: &Path) -> Result<prm::Scene, SceneError> {
    load_scene(path, &LoadOptions::default())
}

#[test]
fn reads_hierarchy_lights_cameras_and_generates_normals() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.meshes[0].normals = None;
    // Parent: TRS translate (10, 0, 0) and rotate 90 degrees about y; child: matrix scale 2.
    let child = s.add_node(GlbNode {
        name: "child".into(),
        matrix: Some([2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 1.0, 0.0, 1.0]),
        mesh: Some(0),
        ..Default::default()
    });
    s.add_node(GlbNode {
        name: "parent".into(),
        translation: Some([10.0, 0.0, 0.0]),
        rotation: Some(Quat::from_rotation_y(std::f32::consts::FRAC_PI_2).to_array()),
        children: vec![child],
        ..Default::default()
    });
    s.add_light(
        GlbLight {
            name: "p".into(),
            kind: "point",
            color: [1.0, 0.5, 0.25],
            intensity: 8.0,
            inner: 0.0,
            outer: 0.0,
            range: None,
            extras: None,
        },
        Vec3::new(0.5, 2.0, 0.5),
        -Vec3::Y,
    );
    s.add_light(
        GlbLight {
            name: "s".into(),
            kind: "spot",
            color: [1.0; 3],
            intensity: 3.0,
            inner: 0.2,
            outer: 0.5,
            range: Some(9.0),
            extras: None,
        },
        Vec3::new(0.0, 3.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
    );
    s.add_light(
        GlbLight {
            name: "sun".into(),
            kind: "directional",
            color: [1.0; 3],
            intensity: 2.0,
            inner: 0.0,
            outer: 0.0,
            range: None,
            extras: None,
        },
        Vec3::ZERO,
        Vec3::new(0.0, -1.0, 1.0),
    );
    s.add_node(GlbNode {
        name: "cam".into(),
        translation: Some([0.0, 1.0, 5.0]),
        camera: Some((0.8, 1.5)),
        ..Default::default()
    });
    let path = write(dir.path(), "h.glb", &s.to_glb());
    // Mesh 0 is placed twice, so its lightmap UVs overlap themselves.
    let scene = load_scene(&path, &LoadOptions { allow_overlap: true, ..Default::default() }).unwrap();

    // Mesh 0 appears twice: at the root (identity) and under parent/child.
    assert_eq!(scene.triangles.len(), 4);
    let rot = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
    let want = Vec3::new(10.0, 0.0, 0.0) + rot * (Vec3::new(0.0, 1.0, 0.0) + 2.0 * Vec3::new(1.0, 0.0, 1.0));
    assert!(scene.positions.iter().any(|p| (*p - want).length() < 1e-5), "transformed corner {want} missing");
    for n in &scene.normals {
        assert!((*n - Vec3::Y).length() < 1e-5, "generated normal {n}");
    }
    assert_eq!(scene.report.normals_generated, 2);

    assert_eq!(scene.lights.len(), 3);
    let p = &scene.lights[0];
    assert_eq!(p.kind, LightKind::Point);
    assert!((p.intensity - Vec3::new(8.0, 4.0, 2.0)).length() < 1e-6, "W/sr = colour x intensity");
    assert!((p.position - Vec3::new(0.5, 2.0, 0.5)).length() < 1e-6);
    let sp = &scene.lights[1];
    assert!(
        matches!(sp.kind, LightKind::Spot { inner, outer } if (inner - 0.2).abs() < 1e-6 && (outer - 0.5).abs() < 1e-6)
    );
    assert!((sp.direction - Vec3::new(1.0, -1.0, 0.0).normalize()).length() < 1e-5);
    assert_eq!(sp.range, Some(9.0));
    let sun = &scene.lights[2];
    assert_eq!(sun.kind, LightKind::Directional);
    assert!((sun.direction - Vec3::new(0.0, -1.0, 1.0).normalize()).length() < 1e-5);
    assert_eq!(scene.cameras.len(), 1);
    assert!((scene.cameras[0].yfov - 0.8).abs() < 1e-6);
    assert_eq!(scene.report.uv_overlapping_pairs, 2);
}

#[test]
fn the_instanced_quad_overlaps_itself_in_uv_space() {
    // Two instances of one mesh share lightmap UVs: that is overlap, an error by default.
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.add_node(GlbNode {
        name: "again".into(),
        translation: Some([3.0, 0.0, 0.0]),
        mesh: Some(0),
        ..Default::default()
    });
    let path = write(dir.path(), "inst.glb", &s.to_glb());
    let err = load(&path).unwrap_err();
    assert!(matches!(err, SceneError::UvOverlap { pairs, .. } if pairs > 0), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("inst.glb")
            && msg.contains("mesh 0 primitive 0 triangle")
            && msg.contains("node 1")
            && msg.contains("--allow-overlap"),
        "{msg}"
    );
    let scene = load_scene(&path, &LoadOptions { allow_overlap: true, ..Default::default() }).unwrap();
    assert!(scene.report.uv_overlapping_pairs >= 2);
}

#[test]
fn missing_and_unreadable_files() {
    let dir = tempfile::tempdir().unwrap();
    let err = load(&dir.path().join("nope.glb")).unwrap_err();
    assert!(matches!(err, SceneError::Io { .. }) && err.to_string().contains("nope.glb"), "{err}");
    let garbage = write(dir.path(), "garbage.glb", b"this is not a glTF file at all");
    let err = load(&garbage).unwrap_err();
    assert!(matches!(err, SceneError::Gltf { .. }) && err.to_string().contains("garbage.glb"), "{err}");
    let mut truncated = one_quad().to_glb();
    truncated.truncate(truncated.len() - 40);
    let path = write(dir.path(), "truncated.glb", &truncated);
    assert!(load(&path).is_err());
}

#[test]
fn non_finite_position_names_mesh_primitive_and_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.meshes[0].positions[2][1] = f32::NAN;
    let path = write(dir.path(), "nan.glb", &s.to_glb());
    let err = load(&path).unwrap_err();
    match &err {
        SceneError::NonFinite { place, attribute, vertex, .. } => {
            assert_eq!((place.mesh, place.primitive, *vertex, *attribute), (0, 0, 2, "POSITION"));
        }
        other => panic!("wrong error: {other}"),
    }
    assert!(err.to_string().contains("nan.glb") && err.to_string().contains("vertex 2"), "{err}");
}

#[test]
fn out_of_range_index_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.meshes[0].indices = Some(vec![0, 1, 2, 0, 2, 7]);
    let path = write(dir.path(), "idx.glb", &s.to_glb());
    let err = load(&path).unwrap_err();
    assert!(
        matches!(err, SceneError::IndexOutOfRange { position: 5, value: 7, vertex_count: 4, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("index 5 is 7"), "{err}");
}

#[test]
fn albedo_outside_unit_range_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.materials[0].base_color = [1.5, 0.2, 0.2, 1.0];
    let path = write(dir.path(), "albedo.glb", &s.to_glb());
    let err = load(&path).unwrap_err();
    assert!(matches!(err, SceneError::AlbedoOutOfRange { material: 0, .. }), "{err}");
    assert!(err.to_string().contains("[1.5, 0.2, 0.2]"), "{err}");
}

/// The quad with a white point light of `intensity` above it.
fn with_point_light(intensity: f32) -> GlbScene {
    let mut s = one_quad();
    let light = GlbLight {
        name: "lamp".into(),
        kind: "point",
        color: [1.0; 3],
        intensity,
        inner: 0.0,
        outer: 0.0,
        range: None,
        extras: None,
    };
    s.add_light(light, Vec3::Y, -Vec3::Y);
    s
}

#[test]
fn negative_light_intensity_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "light.glb", &with_point_light(-2.0).to_glb());
    let err = load(&path).unwrap_err();
    assert!(
        matches!(err, SceneError::BadLight { light: 0, .. }) && err.to_string().contains("intensity -2"),
        "{err}"
    );
}

fn extra_light(name: &str, extras: serde_json::Value) -> GlbLight {
    GlbLight {
        name: name.into(),
        kind: "point",
        color: [1.0, 0.5, 0.5],
        intensity: 2.0,
        inner: 0.0,
        outer: 0.0,
        range: None,
        extras: Some(extras),
    }
}

/// An axially symmetric IES downlight, I = cos gamma.
const COSINE_IES: &str =
    "IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 1 2 0 0 0\n1 1 10\n0 60 90\n0\n100 50 0\n";

/// A light's `prm_radius`, `prm_size` and `prm_profile` extras give it a sphere, a rectangle
/// (facing the node's -Z, radiance = colour x intensity) and a photometric profile read from a
/// file beside the level; a profile that does not parse, or is not there, is an error naming
/// the light and the file.
#[test]
fn light_extras_give_apertures_and_profiles() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("down.ies"), COSINE_IES).unwrap();
    let mut s = one_quad();
    s.add_light(extra_light("bulb", serde_json::json!({"prm_radius": 0.1})), Vec3::Y, -Vec3::Y);
    s.add_light(
        extra_light("panel", serde_json::json!({"prm_size": [0.4, 0.2]})),
        Vec3::new(0.5, 2.0, 0.5),
        -Vec3::Y,
    );
    s.add_light(extra_light("ies", serde_json::json!({"prm_profile": "down.ies"})), Vec3::Y, -Vec3::Y);
    let path = write(dir.path(), "extras.glb", &s.to_glb());
    let scene = load(&path).unwrap();
    let prm::light::Aperture::Sphere { radius } = scene.lights[0].aperture else { panic!("a sphere") };
    assert!((radius - 0.1).abs() < 1e-6, "{radius}");
    let panel = &scene.lights[1];
    let prm::light::Aperture::Polygon { corners } = &panel.aperture else { panic!("{:?}", panel.aperture) };
    assert_eq!(corners.len(), 4);
    assert!((panel.direction - -Vec3::Y).length() < 1e-5, "faces down: {}", panel.direction);
    assert!((panel.position - Vec3::new(0.5, 2.0, 0.5)).length() < 1e-5);
    // I_n = L x area, L = colour x intensity.
    assert!((panel.intensity - Vec3::new(2.0, 1.0, 1.0) * 0.08).length() < 1e-6, "{}", panel.intensity);
    let ies = &scene.lights[2];
    assert!(ies.profile.is_some() && ies.check().is_ok());
    let half = ies.intensity_towards(Vec3::new(0.0, -0.5, 3f32.sqrt() / 2.0)).x;
    assert!((half - 1.0).abs() < 1e-5, "60 degrees off the axis: half the peak of 2, got {half}");

    std::fs::write(dir.path().join("bad.ies"), "IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 2 2 0 0 0\n")
        .unwrap();
    for (file, want) in [("bad.ies", "bad.ies"), ("gone.ldt", "gone.ldt")] {
        let mut s = one_quad();
        s.add_light(extra_light("lamp", serde_json::json!({"prm_profile": file})), Vec3::Y, -Vec3::Y);
        let path = write(dir.path(), "badlight.glb", &s.to_glb());
        let err = load(&path).unwrap_err();
        assert!(matches!(err, SceneError::BadLight { light: 0, .. }), "{err}");
        assert!(err.to_string().contains(want) && err.to_string().contains("'lamp'"), "{err}");
    }
    let mut s = one_quad();
    s.add_light(extra_light("thin", serde_json::json!({"prm_size": [0.4, 0.0]})), Vec3::Y, -Vec3::Y);
    let err = load(&write(dir.path(), "thin.glb", &s.to_glb())).unwrap_err();
    assert!(err.to_string().contains("no area"), "{err}");
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    // A third triangle with two identical corners.
    s.meshes[0].indices = Some(vec![0, 1, 2, 0, 2, 3, 1, 1, 2]);
    let path = write(dir.path(), "degen.glb", &s.to_glb());
    let scene = load(&path).unwrap();
    assert_eq!(scene.triangles.len(), 2);
    assert_eq!(scene.report.degenerate_dropped, 1);
}

#[test]
fn missing_uv1_is_generated_or_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = GlbScene { materials: vec![material([0.5; 3])], ..Default::default() };
    // A closed box: generated charts must not overlap and must stay in [0, 1].
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    let v = |x: f32, y: f32, z: f32| [x, y, z];
    let faces = [
        [v(0., 0., 0.), v(0., 0., 1.), v(0., 1., 1.), v(0., 1., 0.)],
        [v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)],
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
        [v(0., 1., 0.), v(0., 1., 1.), v(1., 1., 1.), v(1., 1., 0.)],
        [v(0., 0., 0.), v(0., 1., 0.), v(1., 1., 0.), v(1., 0., 0.)],
        [v(0., 0., 1.), v(1., 0., 1.), v(1., 1., 1.), v(0., 1., 1.)],
    ];
    for f in faces {
        let k = pos.len() as u32;
        pos.extend_from_slice(&f);
        idx.extend_from_slice(&[k, k + 1, k + 2, k, k + 2, k + 3]);
    }
    s.add_mesh(GlbMesh {
        name: "box".into(),
        positions: pos,
        normals: None,
        uv1: None,
        indices: Some(idx),
        material: Some(0),
    });
    let path = write(dir.path(), "nouv.glb", &s.to_glb());
    let err = load_scene(&path, &LoadOptions { require_uv1: true, ..Default::default() }).unwrap_err();
    assert!(
        matches!(err, SceneError::MissingUv1 { .. }) && err.to_string().contains("--require-uv1"),
        "{err}"
    );
    let scene = load(&path).unwrap();
    assert!(scene.report.uv1_generated);
    assert!(scene.report.notes.iter().any(|n| n.contains("generated")));
    assert_eq!(scene.triangles.len(), 12);
    assert_eq!(scene.report.uv_out_of_range, 0);
    assert!(prm::uv::find_overlaps(&scene).is_empty());
    let set = prm::TexelSet::build(&scene, 64, 64);
    assert!(set.len() > 500, "generated charts should cover the atlas ({})", set.len());
}

#[test]
fn uv_outside_unit_square_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.meshes[0].uv1 = Some(vec![[0.1, 0.1], [0.1, 1.4], [0.9, 1.4], [0.9, 0.1]]);
    let path = write(dir.path(), "range.glb", &s.to_glb());
    let scene = load(&path).unwrap();
    assert_eq!(scene.report.uv_out_of_range, 2);
    assert!(scene.report.notes.iter().any(|n| n.contains("outside [0, 1]")));
}

#[test]
fn a_malformed_buffer_reference_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = one_quad().to_json_and_bin();
    // Point the index accessor past the end of its buffer view.
    doc["accessors"][2]["count"] = serde_json::json!(600);
    let path = write(dir.path(), "oob.glb", &glb_bytes(&doc, &bin));
    let err = load(&path).unwrap_err();
    assert!(err.to_string().contains("oob.glb"), "{err}");
}

#[test]
fn a_node_reached_twice_is_an_error_not_a_walk_without_end() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = one_quad().to_json_and_bin();
    // Forty pairs of nodes, each a parent of both nodes of the pair below, over the quad's
    // node: 2^40 ways down to it (a few KB that took memory until the machine ran out).
    let quad = doc["nodes"].as_array().unwrap().len() - 1;
    let mut below = vec![quad, quad];
    for _ in 0..40 {
        let nodes = doc["nodes"].as_array_mut().unwrap();
        let first = nodes.len();
        for _ in 0..2 {
            nodes.push(serde_json::json!({"children": [below[0], below[1]]}));
        }
        below = vec![first, first + 1];
    }
    doc["scenes"][0]["nodes"] = serde_json::json!(below);
    let path = write(dir.path(), "diamond.glb", &glb_bytes(&doc, &bin));
    let err = load(&path).unwrap_err();
    assert!(
        matches!(err, SceneError::Malformed { .. }) && err.to_string().contains("reached twice"),
        "{err}"
    );
}

#[test]
fn indices_that_are_not_unsigned_integers_are_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = one_quad().to_json_and_bin();
    let mesh = &doc["meshes"][0]["primitives"][0];
    let at = mesh["indices"].as_u64().unwrap() as usize;
    doc["accessors"][at]["componentType"] = serde_json::json!(5126);
    let path = write(dir.path(), "float_indices.glb", &glb_bytes(&doc, &bin));
    let err = load(&path).unwrap_err();
    assert!(err.to_string().contains("indices accessor") && err.to_string().contains("F32"), "{err}");
}

#[test]
fn accessors_the_reader_cannot_take_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let (doc, bin) = one_quad().to_json_and_bin();
    let attribute =
        |name: &str| doc["meshes"][0]["primitives"][0]["attributes"][name].as_u64().unwrap() as usize;
    let (uv1, position) = (attribute("TEXCOORD_1"), attribute("POSITION"));
    let view = doc["accessors"][position]["bufferView"].as_u64().unwrap() as usize;
    // Each edit, and what its error must say. Before, the first reached `unreachable!` inside
    // the gltf crate (caught, but its message went to stderr too) and the last two an overflow
    // or a debug assertion there.
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: [(&str, Edit, &str); 4] = [
        (
            "uv_u32",
            Box::new(move |d| d["accessors"][uv1]["componentType"] = serde_json::json!(5125)),
            "TEXCOORD_1 accessor",
        ),
        (
            "pos_vec2",
            Box::new(move |d| d["accessors"][position]["type"] = serde_json::json!("VEC2")),
            "POSITION accessor",
        ),
        (
            "pos_empty",
            Box::new(move |d| d["accessors"][position]["count"] = serde_json::json!(0)),
            "no elements",
        ),
        (
            "pos_stride",
            Box::new(move |d| d["bufferViews"][view]["byteStride"] = serde_json::json!(4)),
            "stride of 4",
        ),
    ];
    for (name, edit, says) in cases {
        let mut d = doc.clone();
        edit(&mut d);
        let path = write(dir.path(), &format!("{name}.glb"), &glb_bytes(&d, &bin));
        let err = load(&path).unwrap_err();
        assert!(
            matches!(err, SceneError::Malformed { .. }) && err.to_string().contains(says),
            "{name}: {err}"
        );
        assert!(!err.to_string().contains("panic"), "{name}: {err}");
    }
}

#[test]
fn points_and_lines_are_left_out_and_said() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = one_quad().to_json_and_bin();
    let prims = doc["meshes"][0]["primitives"].as_array_mut().unwrap();
    let mut points = prims[0].clone();
    points["mode"] = serde_json::json!(0);
    prims.push(points);
    let path = write(dir.path(), "points.glb", &glb_bytes(&doc, &bin));
    let scene = load(&path).unwrap();
    assert_eq!((scene.report.non_triangle_primitives, scene.triangles.len()), (1, 2));
    assert!(scene.report.notes.iter().any(|n| n.contains("1 primitive(s) of points or lines left out")));
}

#[test]
fn a_light_or_an_emission_beyond_the_brightest_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = load(&write(dir.path(), "bright.glb", &with_point_light(3e38).to_glb())).unwrap_err();
    assert!(matches!(err, SceneError::BadLight { .. }) && err.to_string().contains("beyond 1e9"), "{err}");
    let mut s = one_quad();
    s.materials[0].emissive = [3e38, 0.0, 0.0];
    let err = load(&write(dir.path(), "glow.glb", &s.to_glb())).unwrap_err();
    assert!(matches!(err, SceneError::BadEmissive { .. }) && err.to_string().contains("beyond 1e9"), "{err}");
}

#[cfg(unix)]
#[test]
fn a_buffer_that_is_a_device_is_an_error_not_a_read_without_end() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = one_quad().to_json_and_bin();
    // As the gltf crate reads a URI: a path, a file: URI, or percent-encoded.
    for uri in ["/dev/zero", "file:///dev/zero", "file:/dev/zero", "%2Fdev%2Fzero"] {
        doc["buffers"][0]["uri"] = serde_json::json!(uri);
        let path = write(dir.path(), "zero.glb", &glb_bytes(&doc, &bin));
        let err = load(&path).unwrap_err();
        assert!(err.to_string().contains("/dev/zero is not a regular file"), "{uri}: {err}");
    }
    // The level itself a folder: the same.
    let err = load(dir.path()).unwrap_err();
    assert!(err.to_string().contains("not a regular file"), "{err}");
}

#[test]
fn geometry_beyond_the_farthest_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = one_quad();
    s.meshes[0].positions[2] = [1e8, 0.0, 1.0];
    let err = load(&write(dir.path(), "far.glb", &s.to_glb())).unwrap_err();
    assert!(
        matches!(err, SceneError::TooFar { vertex: 2, .. }) && err.to_string().contains("beyond 1e7 m"),
        "{err}"
    );
}
