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
    if let UnwrapLayout::Pages { texel_size, .. } = layout {
        // Each room's surface in texels: what its shelves are reserved from.
        let mut surface = vec![0.0f64; room_of_zone.iter().map(|&r| r as usize + 1).max().unwrap_or(0)];
        for (k, c) in corners.iter().enumerate() {
            let room = room_of_zone[zone[k] as usize] as usize;
            surface[room] += 0.5 * (c[1] - c[0]).cross(c[2] - c[0]).length() as f64;
        }
        let texel_area = (texel_size as f64).powi(2);
        let reserve: Vec<f64> = surface.iter().map(|a| a / texel_area).collect();
        pages.pages = shelve(&mut rects, &room_of_zone, &reserve, pages.side, PADDING)?;
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
/// The texels of the atlas a room is given per texel of its surface. uvunwrap's charts with
/// their padding cover about 60 % of their zones' rectangles, and the skyline packs those
/// into 75-90 % of a room's rectangle: a generated chamber's zones took 2.1-2.5 texels per
/// texel of its surface (the 16 chambers), so 3 leaves each room 15-40 % to grow by. A room
/// that needs more takes it, and moves the rooms after it.
const RESERVE_PER_TEXEL: f64 = 3.0;

#[cfg(feature = "unwrap")]
/// Place the zones again, room by room, each room in a rectangle of its own, the rooms'
/// rectangles on shelves across pages of `side` texels.
///
/// uvunwrap packs rectangles largest first, so the zones of one room land all over the pages,
/// and tiles where zones of two rooms meet hold texels of both: a pane is stored in those
/// tiles for each. Here the zones of each room (`room`, per zone:
/// `crate::zones::zones_in_rooms`, whose zones of a room are consecutive) are packed into one
/// rectangle, tallest first, each where its top is lowest ([`skyline`]), and the rooms' rectangles
/// are laid in the rooms' order on shelves across the pages. Each zone moves by whole texels
/// (its charts' rasterisation is unchanged) and keeps `pad` texels of its own all round;
/// rectangles and shelves start on multiples of [`SHELF_ROWS`] texels, so two rooms never
/// share a pane tile.
///
/// A room's rectangle is as large as its surface asks (`reserve`, per room, in texels, times
/// [`RESERVE_PER_TEXEL`]): a width of the page side over a power of two, the least at least
/// as wide as it is tall, and its rows; more only if its zones need more. An edit inside a
/// room (an object moved or turned, a material changed) keeps its surface, so however uvunwrap
/// packs that room's charts again, the rooms after it keep their places and their UVs, and an
/// update (`prm precompute --update`) need not walk them again. Only a room that outgrows its
/// rectangle moves the rooms after it. A room too large for a page is laid across pages in
/// rows of its own. Returns the pages used.
fn shelve(
    rects: &mut [ZoneRect],
    room: &[u32],
    reserve: &[f64],
    side: u32,
    pad: u32,
) -> Result<u32, UnwrapError> {
    let s = side as f32;
    // The rectangle's texels with its padding.
    let size = |r: &ZoneRect| [0, 1].map(|a| ((r.max[a] - r.min[a]) * s).ceil() as u32 + 2 * pad);
    if let Some(big) = rects.iter().map(size).find(|z| z[0] > side || z[1] > side) {
        return Err(format!("a zone of {}x{} texels does not fit a {side}^2 page", big[0], big[1]).into());
    }
    // Where the next room's rectangle goes: page, column, row, and the tallest on its shelf.
    let (mut page, mut x, mut y, mut shelf) = (0u32, 0u32, 0u32, 0u32);
    let mut k = 0;
    while k < rects.len() {
        let end = (k..rects.len()).find(|&e| room.get(e) != room.get(k)).unwrap_or(rects.len());
        let mut order: Vec<usize> = (k..end).collect();
        order.sort_by_key(|&z| (std::cmp::Reverse(size(&rects[z])[1]), z));
        let sizes: Vec<[u32; 2]> = order.iter().map(|&z| size(&rects[z])).collect();
        let wanted =
            room.get(k).and_then(|&q| reserve.get(q as usize)).copied().unwrap_or(0.0) * RESERVE_PER_TEXEL;
        let wanted = if wanted.is_finite() { wanted.max(0.0) } else { 0.0 };
        // The width: the page side halved while a square of the reservation still fits, and
        // while the widest zone does.
        let widest = sizes.iter().map(|z| z[0]).max().unwrap_or(0);
        let mut width = side;
        while width / 2 >= SHELF_ROWS && (width / 2) as f64 >= wanted.sqrt() && width / 2 >= widest {
            width /= 2;
        }
        // The room's zones packed into that width, tallest first: their places in the room's
        // rectangle, and the rows they take.
        let pack = |width: u32| {
            let (at, top) = skyline(&sizes, width);
            (at, top.next_multiple_of(SHELF_ROWS))
        };
        let (mut at, mut rows) = pack(width);
        while rows > side && width < side {
            width *= 2;
            (at, rows) = pack(width);
        }
        if rows > side {
            // Larger than a page: the room's shelves run on over pages of their own.
            if x > 0 || y > 0 {
                page += 1;
            }
            let (mut cx, mut cy, mut tall) = (0u32, 0u32, 0u32);
            for (&z, size) in order.iter().zip(&sizes) {
                if cx + size[0] > side {
                    (cx, cy, tall) = (0, (cy + tall).next_multiple_of(SHELF_ROWS), 0);
                }
                if cy + size[1] > side {
                    (page, cx, cy, tall) = (page + 1, 0, 0, 0);
                }
                place(&mut rects[z], page, [cx, cy], pad, s);
                cx += size[0];
                tall = tall.max(size[1]);
            }
            (x, y, shelf) = (0, (cy + tall).next_multiple_of(SHELF_ROWS), 0);
        } else {
            let height = rows
                .max(((wanted / width as f64).ceil().min(side as f64) as u32).next_multiple_of(SHELF_ROWS))
                .min(side);
            if x + width > side {
                (x, y, shelf) = (0, y + shelf, 0);
            }
            if y + height > side {
                (page, x, y, shelf) = (page + 1, 0, 0, 0);
            }
            for (&z, local) in order.iter().zip(&at) {
                place(&mut rects[z], page, [x + local[0], y + local[1]], pad, s);
            }
            x += width;
            shelf = shelf.max(height);
        }
        k = end;
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
/// Rectangles of `sizes` packed, in their order, into a strip `width` wide: each where its
/// top is lowest on the skyline of those before it (bottom-left, leftmost on ties). Returns
/// each one's corner and the strip's rows. A rectangle wider than the strip is put at its left
/// edge (the caller makes the strip wide enough).
fn skyline(sizes: &[[u32; 2]], width: u32) -> (Vec<[u32; 2]>, u32) {
    // The skyline: (column it begins at, its height), by column; each runs to the next's.
    let mut line: Vec<(u32, u32)> = vec![(0, 0)];
    let mut at = Vec::with_capacity(sizes.len());
    let mut rows = 0;
    for &[w, h] in sizes {
        // (top, row, column) of the best place, over the places beginning at a step.
        let mut best: Option<(u32, u32, u32)> = None;
        for (i, &(x, _)) in line.iter().enumerate() {
            if x + w > width && i > 0 {
                break;
            }
            let y = line[i..].iter().take_while(|s| s.0 < x + w).map(|s| s.1).max().unwrap_or(0);
            if best.is_none_or(|b| (y + h, y, x) < b) {
                best = Some((y + h, y, x));
            }
        }
        let (top, y, x) = best.unwrap_or((h, 0, 0));
        at.push([x, y]);
        rows = rows.max(top);
        // The new step over x..x + w, and the old height beyond its right end.
        let under = line.iter().take_while(|s| s.0 <= x + w).last().map_or(0, |s| s.1);
        line.retain(|s| s.0 < x || s.0 >= x + w);
        let k = line.iter().position(|s| s.0 > x).unwrap_or(line.len());
        line.insert(k, (x, top));
        if x + w < width && line.get(k + 1).is_none_or(|s| s.0 != x + w) {
            line.insert(k + 1, (x + w, under));
        }
    }
    (at, rows)
}

#[cfg(feature = "unwrap")]
/// Move a zone's rectangle, by whole texels, so its padded corner lies at `corner` of `page`.
fn place(r: &mut ZoneRect, page: u32, corner: [u32; 2], pad: u32, s: f32) {
    let from = [0, 1].map(|a| (r.min[a] * s).round() as i64 - pad as i64);
    let delta = [0, 1].map(|a| (corner[a] as i64 - from[a]) as f32 / s);
    for (a, d) in delta.into_iter().enumerate() {
        r.min[a] += d;
        r.max[a] += d;
    }
    r.page = page;
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

    /// Zone rectangles of `sizes` (texels) where a packer might have put them on a page of
    /// `side`.
    #[cfg(feature = "unwrap")]
    fn zone_rects(sizes: &[(u32, u32)], side: u32) -> Vec<ZoneRect> {
        let s = side as f32;
        sizes
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
            .collect()
    }

    /// Each zone keeps its size, moves by whole texels and stays on its page with its padding;
    /// no two padded zones overlap; rooms never share a 16 x 16 tile. Returns each zone's padded
    /// box (page, x0, y0, x1, y1) in texels.
    #[cfg(feature = "unwrap")]
    fn check_layout(
        rects: &[ZoneRect],
        before: &[ZoneRect],
        room: &[u32],
        side: u32,
        pages: u32,
    ) -> Vec<(u32, f32, f32, f32, f32)> {
        let s = side as f32;
        let pad = PADDING as f32;
        let mut boxes = Vec::new();
        for (k, (r, b)) in rects.iter().zip(before).enumerate() {
            let (x0, y0) = (r.min[0] * s, r.min[1] * s);
            for a in 0..2 {
                let (w, was) = ((r.max[a] - r.min[a]) * s, (b.max[a] - b.min[a]) * s);
                assert!((w - was).abs() < 1e-3, "zone {k} changed size");
                let moved = (r.min[a] - b.min[a]) * s;
                assert!((moved - moved.round()).abs() < 1e-3, "zone {k} moved by {moved} texels");
            }
            let (x1, y1) = (r.max[0] * s, r.max[1] * s);
            assert!(x0 >= pad - 1e-3 && y0 >= pad - 1e-3, "zone {k} at {x0}, {y0}");
            assert!(x1 + pad <= s + 1e-3 && y1 + pad <= s + 1e-3, "zone {k} reaches {x1}, {y1}");
            assert!(r.page < pages, "zone {k} on page {} of {pages}", r.page);
            boxes.push((r.page, x0 - pad, y0 - pad, x1 + pad, y1 + pad));
        }
        let tiles = |b: &(u32, f32, f32, f32, f32)| {
            let t = SHELF_ROWS as f32;
            let cover = |lo: f32, hi: f32| (lo / t).floor() as u32..((hi / t).ceil() as u32);
            let (xs, ys) = (cover(b.1 + 1e-3, b.3 - 1e-3), cover(b.2 + 1e-3, b.4 - 1e-3));
            ys.flat_map(move |y| xs.clone().map(move |x| (b.0, x, y))).collect::<Vec<_>>()
        };
        for (i, a) in boxes.iter().enumerate() {
            for (j, b) in boxes.iter().enumerate().skip(i + 1) {
                let apart = a.0 != b.0
                    || a.3 <= b.1 + 1e-3
                    || b.3 <= a.1 + 1e-3
                    || a.4 <= b.2 + 1e-3
                    || b.4 <= a.2 + 1e-3;
                assert!(apart, "padded zones {i} and {j} overlap: {a:?} {b:?}");
                if room[i] != room[j] {
                    let shared = tiles(a).into_iter().find(|t| tiles(b).contains(t));
                    assert!(shared.is_none(), "zones {i} and {j} of two rooms share tile {shared:?}");
                }
            }
        }
        boxes
    }

    /// Rooms laid out zone by zone: sizes, whole-texel moves, padding, no overlap, rooms on
    /// tiles of their own, every room's zones within its rectangle of the page; a zone larger
    /// than a page refused; a room larger than a page laid over pages of its own.
    #[cfg(feature = "unwrap")]
    #[test]
    fn shelved_rooms_keep_their_zones_whole_and_apart() {
        let side = 256u32;
        let sizes: Vec<(u32, u32)> = (0..40).map(|k| (10 + (k * 37) % 90, 8 + (k * 53) % 70)).collect();
        let before = zone_rects(&sizes, side);
        let mut rects = zone_rects(&sizes, side);
        let room: Vec<u32> = (0..40).map(|k| k / 7).collect();
        // Each room's surface: a third of its zones' rectangles (they cover it with room to spare).
        let reserve: Vec<f64> = (0..6)
            .map(|r| {
                sizes
                    .iter()
                    .zip(&room)
                    .filter(|(_, &q)| q == r)
                    .map(|(&(w, h), _)| (w * h) as f64)
                    .sum::<f64>()
                    / 3.0
            })
            .collect();
        let pages = shelve(&mut rects, &room, &reserve, side, PADDING).unwrap();
        assert!(pages >= 2, "40 zones of this size need more than one 256^2 page: {pages}");
        let boxes = check_layout(&rects, &before, &room, side, pages);
        // Zones as large as these (up to a third of the page's side) leave gaps between rooms'
        // rectangles, but the pages are not left mostly empty.
        let used: f32 = boxes.iter().map(|b| (b.3 - b.1) * (b.4 - b.2)).sum();
        let fill = used / (pages * side * side) as f32;
        assert!(fill > 0.4, "{pages} pages {fill} full");
        // A zone larger than a page is refused with its size.
        let mut big = vec![ZoneRect { page: 0, min: [0.0, 0.0], max: [1.0, 0.5] }];
        let e = shelve(&mut big, &[0], &[0.0], side, PADDING).unwrap_err();
        assert!(format!("{e}").contains("does not fit"), "{e}");
        // One room of more zones than a page holds, between two small ones: it begins a page of
        // its own and the room after it begins after it.
        let sizes: Vec<(u32, u32)> = (0..30).map(|k| (60 + k % 7, 50 + k % 5)).collect();
        let room: Vec<u32> = (0..30)
            .map(|k| {
                if k == 0 {
                    0
                } else if k < 29 {
                    1
                } else {
                    2
                }
            })
            .collect();
        let before = zone_rects(&sizes, side);
        let mut rects = zone_rects(&sizes, side);
        let pages = shelve(&mut rects, &room, &[4e3, 8e4, 4e3], side, PADDING).unwrap();
        check_layout(&rects, &before, &room, side, pages);
        let large = rects[1..29].iter().map(|r| r.page);
        let (first, last) = (large.clone().min().unwrap(), large.max().unwrap());
        assert_eq!((rects[0].page, first), (0, 1), "the large room begins a page");
        assert!(last > first, "the large room runs over pages");
        assert!(rects[29].page >= last, "the last room comes after the large one");
    }

    /// The point of a room's rectangle: change the zones of one room (other sizes, another
    /// count, other places where uvunwrap put them) and the other rooms' zones keep their
    /// places to the bit, as long as it keeps its surface and fits its rectangle. A room that
    /// outgrows its rectangle moves the rooms after it (and only those).
    #[cfg(feature = "unwrap")]
    #[test]
    fn an_edit_inside_a_room_leaves_the_other_rooms_in_place() {
        let side = 512u32;
        let sizes: Vec<(u32, u32)> = (0..48).map(|k| (40 + (k * 37) % 60, 30 + (k * 53) % 50)).collect();
        let room: Vec<u32> = (0..48).map(|k| k / 6).collect();
        let reserve: Vec<f64> = (0..8)
            .map(|r| sizes[6 * r..6 * r + 6].iter().map(|&(w, h)| (w * h) as f64).sum::<f64>() / 2.0)
            .collect();
        let lay = |sizes: &[(u32, u32)], room: &[u32]| {
            let before = zone_rects(sizes, side);
            let mut rects = zone_rects(sizes, side);
            let pages = shelve(&mut rects, room, &reserve, side, PADDING).unwrap();
            check_layout(&rects, &before, room, side, pages);
            rects
        };
        let base = lay(&sizes, &room);
        for edited in [0usize, 3, 7] {
            // The room's zones packed again: one wider, one shorter, their order turned, one
            // more zone.
            let mut sizes2 = sizes.clone();
            sizes2[6 * edited] = (sizes[6 * edited].0 + 17, sizes[6 * edited].1);
            sizes2[6 * edited + 1] = (sizes[6 * edited + 1].0, sizes[6 * edited + 1].1 - 9);
            sizes2[6 * edited..6 * edited + 6].reverse();
            sizes2.insert(6 * edited + 6, (12, 10));
            let mut room2 = room.clone();
            room2.insert(6 * edited + 6, edited as u32);
            let moved = lay(&sizes2, &room2);
            let others = |rects: &[ZoneRect], room: &[u32]| -> Vec<(u32, [f32; 2], [f32; 2])> {
                rects
                    .iter()
                    .zip(room)
                    .filter(|&(_, &q)| q != edited as u32)
                    .map(|(r, _)| (r.page, r.min, r.max))
                    .collect()
            };
            assert_eq!(
                others(&base, &room),
                others(&moved, &room2),
                "an edit in room {edited} moved another room"
            );
        }
        // Room 2 grown past its rectangle: rooms 0 and 1 stay, the rooms after it move.
        let mut grown = sizes.clone();
        for z in &mut grown[12..18] {
            *z = (z.0 + 40, z.1 + 40);
        }
        let moved = lay(&grown, &room);
        for k in 0..12 {
            assert_eq!((moved[k].page, moved[k].min), (base[k].page, base[k].min), "zone {k}");
        }
        assert!((18..48).any(|k| (moved[k].page, moved[k].min) != (base[k].page, base[k].min)));
    }

    /// The skyline packing against a brute-force check: every rectangle inside the strip, none
    /// overlapping another, the rows the tallest top, and no rectangle that could drop: each
    /// rests on the strip's floor or on another rectangle.
    #[cfg(feature = "unwrap")]
    #[test]
    fn skyline_packs_without_overlap_or_gaps_beneath() {
        for (n, width) in [(1usize, 64u32), (7, 100), (30, 256), (60, 512)] {
            let mut sizes: Vec<[u32; 2]> =
                (0..n as u32).map(|k| [8 + (k * 41) % 90, 6 + (k * 29) % 70]).collect();
            sizes.iter_mut().for_each(|z| z[0] = z[0].min(width));
            sizes.sort_by_key(|z| std::cmp::Reverse(z[1]));
            let (at, rows) = skyline(&sizes, width);
            assert_eq!(rows, at.iter().zip(&sizes).map(|(a, z)| a[1] + z[1]).max().unwrap());
            for (i, (a, z)) in at.iter().zip(&sizes).enumerate() {
                assert!(a[0] + z[0] <= width, "{i} leaves the strip");
                let rests = a[1] == 0
                    || at
                        .iter()
                        .zip(&sizes)
                        .any(|(b, y)| b[1] + y[1] == a[1] && b[0] < a[0] + z[0] && a[0] < b[0] + y[0]);
                assert!(rests, "{i} at {a:?} hangs in the air");
                for (j, (b, y)) in at.iter().zip(&sizes).enumerate().skip(i + 1) {
                    let apart = a[0] + z[0] <= b[0]
                        || b[0] + y[0] <= a[0]
                        || a[1] + z[1] <= b[1]
                        || b[1] + y[1] <= a[1];
                    assert!(apart, "{i} {a:?} {z:?} and {j} {b:?} {y:?} overlap");
                }
            }
            // Denser than one shelf per row of rectangles would be.
            let area: u32 = sizes.iter().map(|z| z[0] * z[1]).sum();
            if n > 7 {
                assert!(
                    area as f64 > 0.6 * (rows * width) as f64,
                    "{n} in {width}: {area} of {}",
                    rows * width
                );
            }
        }
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
