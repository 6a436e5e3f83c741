//! Lightmap UVs (`TEXCOORD_1`): generation for levels without them, and the checks a level's
//! own UVs must pass.
//!
//! Overlap is tested exactly in UV space: two triangles overlap when their UV images share
//! positive area (separating-axis test). Triangles that only touch along an edge or at a
//! vertex (the normal case inside a chart) do not overlap. Overlap means two surfaces would
//! share texels and so share lighting, which is wrong; the loader makes it an error unless
//! `--allow-overlap` is given.

use std::collections::HashMap;

use glam::{DVec2, Vec2};

#[cfg(feature = "unwrap")]
use crate::density::{Atlas, UnwrapLayout, MAX_PAGES};
use crate::scene::Scene;

#[cfg(feature = "unwrap")]
/// A primitive whose lightmap UVs are to be generated: its arrays are rewritten, because the
/// unwrapper splits vertices along chart seams.
pub struct UnwrapPrim<'a> {
    pub positions: &'a mut Vec<glam::Vec3>,
    pub normals: &'a mut Vec<glam::Vec3>,
    pub uv_albedo: &'a mut Vec<Vec2>,
    pub indices: &'a mut Vec<u32>,
    pub uv1: &'a mut Option<Vec<Vec2>>,
}

#[cfg(feature = "unwrap")]
/// Generate lightmap UVs for all primitives together, with 2 texels of padding around each
/// chart: one square page, or pages of a fixed size at a fixed density, stacked as
/// [`crate::density::Atlas`] says (v runs over every page). The level is cut into spatial zones
/// ([`crate::zones`]), each packed into its own rectangle of one page. Returns the atlas.
pub fn unwrap_primitives(prims: &mut [UnwrapPrim<'_>], layout: UnwrapLayout) -> Result<Atlas, UnwrapError> {
    if let UnwrapLayout::OnePage(resolution) = layout {
        if resolution < 16 {
            return Err(format!("unwrap resolution {resolution} is too small (at least 16)").into());
        }
    }
    // Every triangle as (primitive, triangle), its corners, and its zone.
    let tris: Vec<(usize, usize)> = prims
        .iter()
        .enumerate()
        .flat_map(|(p, prim)| (0..prim.indices.len() / 3).map(move |t| (p, t)))
        .collect();
    let corners: Vec<[glam::Vec3; 3]> = tris
        .iter()
        .map(|&(p, t)| [0, 1, 2].map(|k| prims[p].positions[prims[p].indices[3 * t + k] as usize]))
        .collect();
    // A zone is packed whole into one page: at most a fifth of a page's area.
    let zone_area = match layout {
        UnwrapLayout::OnePage(_) => crate::zones::ZONE_AREA,
        UnwrapLayout::Pages { texel_size, page_size } => {
            crate::zones::ZONE_AREA.min(0.2 * (page_size as f64 * texel_size as f64).powi(2))
        }
    };
    let (zone, room_of_zone) = crate::zones::zones_in_rooms(&corners, zone_area);
    let zone_count = zone.iter().map(|&z| z as usize + 1).max().unwrap_or(0);
    // Each zone as one mesh: its vertices are (primitive, vertex) pairs.
    let mut meshes = vec![ZoneMesh::default(); zone_count];
    let mut slot = vec![(0u32, 0usize); tris.len()];
    for (k, &(p, t)) in tris.iter().enumerate() {
        let m = &mut meshes[zone[k] as usize];
        slot[k] = (zone[k], m.indices.len() / 3);
        for c in 0..3 {
            let v = prims[p].indices[3 * t + c];
            let next = m.source.len() as u32;
            let local = *m.local.entry((p, v)).or_insert(next);
            if local == next {
                m.source.push((p, v));
                m.positions.push(prims[p].positions[v as usize].to_array());
            }
            m.indices.push(local);
        }
    }
    let one = [1.0f32];
    let inputs: Vec<uvunwrap::MeshInput> = meshes
        .iter()
        .map(|m| uvunwrap::MeshInput {
            instance_scales: &one,
            ..uvunwrap::MeshInput::new(&m.positions, &m.indices)
        })
        .collect();
    let (atlas, v_scale, mut pages) = unwrap_meshes(&inputs, layout)?;
    let mut rects: Vec<ZoneRect> = Vec::with_capacity(atlas.meshes.len());
    for m in &atlas.meshes {
        let r = m.instances.first().ok_or("uvunwrap placed a zone nowhere")?;
        rects.push(ZoneRect { page: r.page, min: r.min, max: r.max });
    }
    if let UnwrapLayout::Pages { .. } = layout {
        pages.pages = shelve(&mut rects, &room_of_zone, pages.side, PADDING)?;
    }
    // Rebuild each primitive, its triangles in their order, from the zones' output vertices.
    let mut rebuilt: Vec<Rebuilt> = prims.iter().map(|_| Rebuilt::default()).collect();
    for (k, &(p, _)) in tris.iter().enumerate() {
        let (z, local_t) = slot[k];
        let out = &atlas.meshes[z as usize];
        let rect = &rects[z as usize];
        let r = &mut rebuilt[p];
        for c in 0..3 {
            let ov = out.indices[3 * local_t + c];
            let next = r.source.len() as u32;
            let index = *r.index.entry((z, ov)).or_insert(next);
            if index == next {
                let v = &out.vertices[ov as usize];
                let (_, src) = meshes[z as usize].source[v.xref as usize];
                let uv = [0, 1].map(|a| rect.min[a] + v.uv[a] * (rect.max[a] - rect.min[a]));
                r.source.push(src);
                r.uv1.push(Vec2::new(uv[0], (rect.page as f32 + uv[1] * v_scale) / pages.pages as f32));
            }
            r.indices.push(index);
        }
    }
    for (p, r) in prims.iter_mut().zip(rebuilt) {
        *p.positions = r.source.iter().map(|&i| p.positions[i as usize]).collect();
        *p.normals = r.source.iter().map(|&i| p.normals[i as usize]).collect();
        *p.uv_albedo = r.source.iter().map(|&i| p.uv_albedo[i as usize]).collect();
        *p.uv1 = Some(r.uv1);
        *p.indices = r.indices;
    }
    Ok(pages)
}

#[cfg(feature = "unwrap")]
/// Texels between a chart and its neighbours or a page edge (uvunwrap's padding).
const PADDING: u32 = 2;

#[cfg(feature = "unwrap")]
/// Rows a shelf of zones, and columns a room's first zone, start on a multiple of: the
/// precompute's default tile side, so that two shelves, or two rooms, never share a pane tile.
const SHELF_ROWS: u32 = 16;

#[cfg(feature = "unwrap")]
/// Where a zone's charts lie: a page and the rectangle in its [0, 1] coordinates (the charts'
/// own coordinates are relative to it).
struct ZoneRect {
    page: u32,
    min: [f32; 2],
    max: [f32; 2],
}

#[cfg(feature = "unwrap")]
/// Place the zones again in their own order, on shelves across pages of `side` texels.
///
/// uvunwrap packs rectangles largest first, so the zones of one room land all over the pages,
/// and tiles where zones of two rooms meet hold texels of both: a pane is stored in those
/// tiles for each. The zones' order is the k-d split's (`crate::zones`), so zones next in the
/// order are next to each other in the level: laid left to right on shelves in that order, a
/// room's zones are a run of one or two shelves. Each rectangle moves by whole texels (its
/// charts' rasterisation is unchanged), keeps `pad` texels of its own all round, each shelf
/// starts on a multiple of [`SHELF_ROWS`] rows, and the first zone of each room (`room`, per
/// zone: `crate::zones::zones_in_rooms`) on a multiple of as many columns. Returns the pages
/// used.
fn shelve(rects: &mut [ZoneRect], room: &[u32], side: u32, pad: u32) -> Result<u32, UnwrapError> {
    let s = side as f32;
    let (mut page, mut x, mut y, mut shelf) = (0u32, 0u32, 0u32, 0u32);
    for (k, r) in rects.iter_mut().enumerate() {
        // A room's first zone starts on a tile column: two rooms never share a tile.
        if k > 0 && room.get(k) != room.get(k - 1) {
            x = x.next_multiple_of(SHELF_ROWS);
        }
        // The rectangle's texels with its padding, and where that starts now.
        let size = [0, 1].map(|a| ((r.max[a] - r.min[a]) * s).ceil() as u32 + 2 * pad);
        let from = [0, 1].map(|a| (r.min[a] * s).round() as i64 - pad as i64);
        if size[0] > side || size[1] > side {
            return Err(
                format!("a zone of {}x{} texels does not fit a {side}^2 page", size[0], size[1]).into()
            );
        }
        if x + size[0] > side {
            (x, y, shelf) = (0, (y + shelf).next_multiple_of(SHELF_ROWS), 0);
        }
        if y + size[1] > side {
            (page, x, y, shelf) = (page + 1, 0, 0, 0);
        }
        let delta = [x as i64 - from[0], y as i64 - from[1]].map(|d| d as f32 / s);
        for (a, d) in delta.into_iter().enumerate() {
            r.min[a] += d;
            r.max[a] += d;
        }
        r.page = page;
        x += size[0];
        shelf = shelf.max(size[1]);
    }
    let pages = page + 1;
    if pages > MAX_PAGES {
        return Err(format!(
            "the charts need {pages} pages of {side}^2, over the {MAX_PAGES} limit; give a larger --page-size or \
             --texel-size"
        )
        .into());
    }
    Ok(pages)
}

#[cfg(feature = "unwrap")]
/// One zone as an unwrap input: its vertices, where each came from, its triangles.
#[derive(Clone, Default)]
struct ZoneMesh {
    positions: Vec<[f32; 3]>,
    source: Vec<(usize, u32)>,
    local: HashMap<(usize, u32), u32>,
    indices: Vec<u32>,
}

#[cfg(feature = "unwrap")]
/// A primitive's arrays being rebuilt: per new vertex, its old vertex and lightmap UV.
#[derive(Default)]
struct Rebuilt {
    source: Vec<u32>,
    uv1: Vec<Vec2>,
    index: HashMap<(u32, u32), u32>,
    indices: Vec<u32>,
}

#[cfg(feature = "unwrap")]
/// Why lightmap UVs could not be generated.
#[derive(Debug, PartialEq)]
pub enum UnwrapError {
    /// The charts need more pages than the one square page of this side the layout gave them.
    MorePages { pages: u32, side: u32 },
    /// Anything else, said in words.
    Failed(String),
}

#[cfg(feature = "unwrap")]
impl std::fmt::Display for UnwrapError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            UnwrapError::MorePages { pages, side } => {
                write!(f, "the charts need {pages} atlas pages at {side}^2; use a larger --atlas")
            }
            UnwrapError::Failed(why) => f.write_str(why),
        }
    }
}

#[cfg(feature = "unwrap")]
impl From<String> for UnwrapError {
    fn from(why: String) -> Self {
        UnwrapError::Failed(why)
    }
}

#[cfg(feature = "unwrap")]
impl From<&str> for UnwrapError {
    fn from(why: &str) -> Self {
        UnwrapError::Failed(why.to_string())
    }
}

#[cfg(feature = "unwrap")]
impl From<UnwrapError> for String {
    fn from(e: UnwrapError) -> Self {
        e.to_string()
    }
}

#[cfg(feature = "unwrap")]
/// Unwrap meshes with 2 texels of padding, as `layout` says. Returns uvunwrap's atlas, the
/// factor to multiply its page v by (uvunwrap crops a single automatic page to the rows it
/// uses, and our pages are square, so texels stay square), and our atlas.
pub fn unwrap_meshes(
    inputs: &[uvunwrap::MeshInput<'_>],
    layout: UnwrapLayout,
) -> Result<(uvunwrap::Atlas, f32, Atlas), UnwrapError> {
    let density = match layout {
        UnwrapLayout::OnePage(side) => uvunwrap::Density::Auto { page_size: side },
        UnwrapLayout::Pages { texel_size, page_size } => {
            uvunwrap::Density::Fixed { texels_per_unit: 1.0 / texel_size, page_size: Some(page_size) }
        }
    };
    let options = uvunwrap::Options { density, padding: PADDING, ..Default::default() };
    let atlas = uvunwrap::generate(inputs, &options).map_err(|e| match (e, layout) {
        (uvunwrap::Error::ChartTooLarge { width, height, .. }, UnwrapLayout::Pages { texel_size, page_size }) => {
            format!(
                "a flat part of the level needs {width}x{height} texels at {texel_size} m texels, more than one \
                 {page_size}^2 page; give a larger --page-size or --texel-size"
            )
        }
        (e, _) => e.to_string(),
    })?;
    match layout {
        UnwrapLayout::OnePage(side) => {
            if atlas.page_count != 1 {
                return Err(UnwrapError::MorePages { pages: atlas.page_count, side });
            }
            let v_scale = atlas.height as f32 / atlas.width as f32;
            Ok((atlas, v_scale, Atlas::single(side)))
        }
        UnwrapLayout::Pages { page_size, .. } => {
            if atlas.page_count > MAX_PAGES {
                return Err(format!(
                    "the charts need {} pages of {page_size}^2, over the {MAX_PAGES} limit; give a larger \
                     --page-size or --texel-size",
                    atlas.page_count
                )
                .into());
            }
            let pages = Atlas { side: page_size, pages: atlas.page_count.max(1) };
            Ok((atlas, 1.0, pages))
        }
    }
}

/// Number of triangles with a lightmap UV outside [0, 1].
pub fn count_out_of_range(scene: &Scene) -> usize {
    (0..scene.triangles.len())
        .filter(|&t| {
            scene.uv1_corners(t).iter().any(|uv| !(0.0..=1.0).contains(&uv.x) || !(0.0..=1.0).contains(&uv.y))
        })
        .count()
}

/// Twice the signed area of a UV triangle.
fn signed_area2(t: &[DVec2; 3]) -> f64 {
    (t[1] - t[0]).perp_dot(t[2] - t[0])
}

/// True when the two triangles' interiors overlap by more than `eps` along every separating
/// axis (triangle edge normals, normalised).
pub fn triangles_overlap(a: &[DVec2; 3], b: &[DVec2; 3], eps: f64) -> bool {
    for tri in [a, b] {
        for k in 0..3 {
            let e = tri[(k + 1) % 3] - tri[k];
            let len = e.length();
            if len == 0.0 {
                continue;
            }
            let axis = DVec2::new(-e.y, e.x) / len;
            let (amin, amax) = project(a, axis);
            let (bmin, bmax) = project(b, axis);
            if amax <= bmin + eps || bmax <= amin + eps {
                return false;
            }
        }
    }
    true
}

fn project(t: &[DVec2; 3], axis: DVec2) -> (f64, f64) {
    let d = [t[0].dot(axis), t[1].dot(axis), t[2].dot(axis)];
    (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
}

fn uv_f64(scene: &Scene, t: usize) -> [DVec2; 3] {
    scene.uv1_corners(t).map(|v| v.as_dvec2())
}

/// All pairs of triangles whose lightmap UVs overlap with positive area, sorted.
pub fn find_overlaps(scene: &Scene) -> Vec<(usize, usize)> {
    let n = scene.triangles.len();
    let grid = ((n as f64).sqrt() as usize).clamp(8, 512);
    let cell = |x: f64| ((x.clamp(0.0, 1.0) * grid as f64) as usize).min(grid - 1);
    let mut bins: HashMap<(usize, usize), Vec<usize>> = HashMap::new();
    let mut boxes = Vec::with_capacity(n);
    for t in 0..n {
        let uv = uv_f64(scene, t);
        let lo = uv[0].min(uv[1]).min(uv[2]);
        let hi = uv[0].max(uv[1]).max(uv[2]);
        let b = (cell(lo.x), cell(lo.y), cell(hi.x), cell(hi.y));
        boxes.push(b);
        if signed_area2(&uv).abs() <= 1e-14 {
            continue;
        }
        for j in b.1..=b.3 {
            for i in b.0..=b.2 {
                bins.entry((i, j)).or_default().push(t);
            }
        }
    }
    // Overlap needs more than round-off: 1e-9 UV units is far below a texel at any atlas size.
    let eps = 1e-9;
    let mut pairs = Vec::new();
    for (&(i, j), members) in &bins {
        for (k, &a) in members.iter().enumerate() {
            for &b in &members[k + 1..] {
                // Test each pair once: in the lowest cell both boxes share.
                let (ba, bb) = (boxes[a], boxes[b]);
                if (ba.0.max(bb.0), ba.1.max(bb.1)) != (i, j) {
                    continue;
                }
                if triangles_overlap(&uv_f64(scene, a), &uv_f64(scene, b), eps) {
                    pairs.push((a.min(b), a.max(b)));
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs
}

/// Chart id per triangle: triangles that share a lightmap-UV edge (both UV endpoints
/// bit-identical) are in one chart. Ids are dense, in order of first triangle.
pub fn charts(scene: &Scene) -> Vec<u32> {
    let key = |v: Vec2| (v.x.to_bits(), v.y.to_bits());
    edge_components(scene.triangles.len(), |t| scene.uv1_corners(t).map(key), |_, _| true)
}

/// Component id per triangle, triangles joined across edges: `corners(t)` gives triangle t's
/// three corner keys, and two triangles with an edge of equal keys (either direction) are
/// joined when `joins(t, other)` says so. Ids are dense, in order of first triangle.
pub fn edge_components<K: Copy + Ord + std::hash::Hash>(
    n: usize,
    corners: impl Fn(usize) -> [K; 3],
    joins: impl Fn(usize, usize) -> bool,
) -> Vec<u32> {
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    let mut edges: HashMap<(K, K), usize> = HashMap::new();
    for t in 0..n {
        let c = corners(t);
        for k in 0..3 {
            let (a, b) = (c[k], c[(k + 1) % 3]);
            let e = if a < b { (a, b) } else { (b, a) };
            match edges.get(&e) {
                Some(&other) if joins(t, other) => {
                    let (ra, rb) = (find(&mut parent, t), find(&mut parent, other));
                    if ra != rb {
                        parent[ra.max(rb)] = ra.min(rb);
                    }
                }
                Some(_) => {}
                None => {
                    edges.insert(e, t);
                }
            }
        }
    }
    let mut ids = vec![u32::MAX; n];
    let mut next = 0u32;
    (0..n)
        .map(|t| {
            let r = find(&mut parent, t);
            if ids[r] == u32::MAX {
                ids[r] = next;
                next += 1;
            }
            ids[r]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(p: [(f64, f64); 3]) -> [DVec2; 3] {
        p.map(|(x, y)| DVec2::new(x, y))
    }

    /// Zones laid on shelves in their order: each keeps its size, moves by whole texels, stays
    /// on its page with its padding, none overlaps another's padded rectangle, shelves start on
    /// tile rows, and the zones fill a page before the next is begun.
    #[cfg(feature = "unwrap")]
    #[test]
    fn shelved_zones_keep_their_size_their_padding_and_their_order() {
        let side = 256u32;
        let s = side as f32;
        // Zones of assorted sizes (texels) where a packer might have put them.
        let sizes: Vec<(u32, u32)> = (0..40).map(|k| (10 + (k * 37) % 90, 8 + (k * 53) % 70)).collect();
        let mut rects: Vec<ZoneRect> = sizes
            .iter()
            .enumerate()
            .map(|(k, &(w, h))| {
                let (x, y) = (3 + (k as u32 * 11) % 100, 5 + (k as u32 * 7) % 100);
                ZoneRect {
                    page: 0,
                    min: [x as f32 / s, y as f32 / s],
                    max: [(x + w) as f32 / s, (y + h) as f32 / s],
                }
            })
            .collect();
        let before: Vec<[f32; 2]> = rects.iter().map(|r| r.min).collect();
        let room: Vec<u32> = (0..40).map(|k| k / 7).collect();
        let pages = shelve(&mut rects, &room, side, PADDING).unwrap();
        assert!(pages >= 2, "40 zones of this size need more than one 256^2 page: {pages}");
        let texels = |v: f32| v * s;
        let mut boxes = Vec::new();
        for (k, (r, &(w, h))) in rects.iter().zip(&sizes).enumerate() {
            let (x0, y0) = (texels(r.min[0]), texels(r.min[1]));
            assert!(
                (texels(r.max[0]) - x0 - w as f32).abs() < 1e-3
                    && (texels(r.max[1]) - y0 - h as f32).abs() < 1e-3
            );
            for (a, b) in [(x0, before[k][0]), (y0, before[k][1])] {
                let moved = a - texels(b);
                assert!((moved - moved.round()).abs() < 1e-3, "zone {k} moved by {moved} texels");
            }
            let pad = PADDING as f32;
            assert!(x0 >= pad - 1e-3 && y0 >= pad - 1e-3, "zone {k} at {x0}, {y0}");
            assert!(x0 + (w as f32) + pad <= s + 1e-3 && y0 + (h as f32) + pad <= s + 1e-3, "zone {k}");
            assert!(r.page < pages);
            boxes.push((r.page, x0 - pad, y0 - pad, x0 + w as f32 + pad, y0 + h as f32 + pad));
        }
        for (i, a) in boxes.iter().enumerate() {
            for b in &boxes[i + 1..] {
                let apart = a.0 != b.0
                    || a.3 <= b.1 + 1e-3
                    || b.3 <= a.1 + 1e-3
                    || a.4 <= b.2 + 1e-3
                    || b.4 <= a.2 + 1e-3;
                assert!(apart, "padded zones overlap: {a:?} {b:?}");
            }
        }
        // In order: along a shelf left to right, shelves down the page, pages one after another.
        for (k, w) in boxes.windows(2).enumerate() {
            let (a, b) = (w[0], w[1]);
            // Within a room, right after the last; a new room from the next tile column.
            let at = if room[k + 1] == room[k] {
                a.3
            } else {
                (a.3.round() as u32).next_multiple_of(SHELF_ROWS) as f32
            };
            let next_on_shelf = a.0 == b.0 && (b.2 - a.2).abs() < 1e-3 && (b.1 - at).abs() < 1e-3;
            let next_shelf =
                a.0 == b.0 && b.2 > a.2 && b.1.abs() < 1e-3 && (b.2.round() as u32) % SHELF_ROWS == 0;
            let next_page = b.0 == a.0 + 1 && b.1.abs() < 1e-3 && b.2.abs() < 1e-3;
            assert!(
                next_on_shelf || next_shelf || next_page,
                "zone {} after zone {k}: {b:?} after {a:?}",
                k + 1
            );
        }
        // A zone larger than a page is refused with its size.
        let mut big = vec![ZoneRect { page: 0, min: [0.0, 0.0], max: [1.0, 0.5] }];
        let e = shelve(&mut big, &[0], side, PADDING).unwrap_err();
        assert!(format!("{e}").contains("does not fit"), "{e}");
    }

    #[test]
    fn shared_edges_do_not_overlap_but_crossing_triangles_do() {
        let a = tri([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]);
        let b = tri([(1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]);
        assert!(!triangles_overlap(&a, &b, 1e-9));
        let c = tri([(0.1, 0.1), (0.9, 0.1), (0.1, 0.9)]);
        assert!(triangles_overlap(&a, &c, 1e-9));
        let d = tri([(0.6, 0.6), (2.0, 0.6), (0.6, 2.0)]);
        assert!(!triangles_overlap(&a, &d, 1e-9));
        // Touching at a single vertex only.
        let e = tri([(1.0, 0.0), (2.0, 0.0), (1.0, 1.0)]);
        assert!(!triangles_overlap(&a, &e, 1e-9));
    }
}
