//! The texel EXR and lightmap layers read back to exactly what was written.

use glam::{Vec2, Vec3};
use prm::exr_io::{texel_channels, Channels};
use prm::{Scene, TexelSet};

#[test]
fn texel_exr_round_trips_exactly() {
    let pos = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.0, 0.1, 2.0),
        Vec3::new(3.0, 0.2, 0.0),
        Vec3::new(-1e4, 5.0, 1e-3),
    ];
    let uv = vec![Vec2::new(0.05, 0.05), Vec2::new(0.05, 0.9), Vec2::new(0.9, 0.05), Vec2::new(0.95, 0.95)];
    let scene = Scene::from_mesh(pos, uv, &[0, 1, 2, 2, 1, 3]);
    let set = TexelSet::build(&scene, 37, 23);
    let written = texel_channels(&set);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("texels.exr");
    written.write(&path).unwrap();
    let read = Channels::read(&path).unwrap();
    assert_eq!((read.width, read.height), (37, 23));
    assert_eq!(read.channels.keys().collect::<Vec<_>>(), ["N.x", "N.y", "N.z", "P.x", "P.y", "P.z", "mask"]);
    assert_eq!(read, written);
    // Row 0 of the file is atlas row j = 0.
    let t = &set.texels[0];
    assert_eq!(read.get("P.x").unwrap()[(t.j * 37 + t.i) as usize], t.position.x);
    assert!(!dir.path().read_dir().unwrap().any(|e| e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .contains(".tmp")));
}

#[test]
fn lightmap_layers_round_trip() {
    let (w, h) = (5, 3);
    let rgb: Vec<Vec3> = (0..w * h).map(|k| Vec3::new(k as f32, 1e-7 * k as f32, 3e8)).collect();
    let mut ch = Channels::new(w, h);
    ch.insert_rgb("indirect", &rgb);
    ch.insert_rgb("direct", &rgb);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lm.exr");
    ch.write(&path).unwrap();
    let back = Channels::read(&path).unwrap();
    assert_eq!(back.rgb("indirect").unwrap(), rgb);
    assert!(back.rgb("stderr").is_none());
    assert!(back.require(&path, "stderr.R").unwrap_err().to_string().contains("indirect.R"));
}

#[test]
fn an_atlas_of_pages_is_a_layer_set_per_page_and_reads_back_stacked() {
    // Three 4 x 4 pages stacked down a 4 x 12 image, two layers.
    let (w, side, pages) = (4, 4, 3);
    let h = side * pages;
    let rgb: Vec<Vec3> = (0..w * h).map(|k| Vec3::new(k as f32, -(k as f32), 0.5)).collect();
    let mut ch = Channels::paged(w, h, pages);
    ch.insert_rgb("", &rgb);
    ch.insert_rgb("direct", &rgb.iter().map(|v| *v * 2.0).collect::<Vec<_>>());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pages.exr");
    ch.write(&path).unwrap();
    // The file holds one layer per page, named page0.., each a page's side square, with the
    // page's rows: what another tool sees.
    let image = exr::prelude::read_all_flat_layers_from_file(&path).unwrap();
    let names: Vec<String> =
        image.layer_data.iter().map(|l| l.attributes.layer_name.as_ref().unwrap().to_string()).collect();
    assert_eq!(names, ["page0", "page1", "page2"]);
    for (p, layer) in image.layer_data.iter().enumerate() {
        assert_eq!((layer.size.width(), layer.size.height()), (side, side));
        let r = layer.channel_data.list.iter().find(|c| c.name.to_string() == "R").unwrap();
        let first: f32 = r.sample_data.values_as_f32().next().unwrap();
        assert_eq!(first, (p * side * w) as f32, "page {p} starts at its first row");
    }
    // Read back: the stacked image, exactly.
    let read = Channels::read(&path).unwrap();
    assert_eq!(read, ch);
    assert_eq!(read.rgb("").unwrap(), rgb);
}
