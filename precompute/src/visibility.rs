//! Building a level's precomputed visibility for moving objects (paper 003 §3, data and query
//! in [`prm::visibility`]) by ray casting on the CPU.
//!
//! - Per object (the static level, then each movable), only its own triangles, at rest.
//! - **Coherent order** (§3.2.3, zig-zag): the object's texels split into charts (4-connected
//!   in the atlas); each chart is swept row by row inside its bounding box, alternating
//!   direction; the next chart is the unvisited one whose centroid is nearest the current one's.
//!   The order keeps consecutive cube maps close, so depth runs are long.
//! - **Cube maps**: at each texel's point, lifted off its surface, a ray through every pixel
//!   centre gives the first and second hit (`[z1, z2)`, [`prm::visibility::cssm`]); pixels
//!   below the tangent plane are "don't care". Texels are cast in parallel chunks and fed to
//!   the run compression in order: the output is the same at any thread count.
//! - **Occluder maps** ([`prm::visibility::Csm`]) per movable: orthographic entry and exit
//!   depths over its bounding sphere from every direction of a small cube map.

use glam::Vec3;
use prm::visibility::{cube, Csm, CssmBuilder, ObjectVisibility, Visibility};
use prm::{Bvh, Scene, TexelSet};
use rayon::prelude::*;

use crate::parallel::{Cancelled, Control};
use crate::params::{require, ParamError};

/// How finely visibility is sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisibilityParams {
    /// Pixels per side of each CSSM cube face (paper 003 uses 32 to 64). Rays cast per texel:
    /// 12 x res². Default 16.
    pub res: u32,
    /// Directions per cube face side of a movable's occluder maps. Default 16.
    pub occluder_dirs: u32,
    /// Pixels per side of each occluder map. Default 32.
    pub occluder_res: u32,
}

impl Default for VisibilityParams {
    fn default() -> Self {
        VisibilityParams { res: 16, occluder_dirs: 16, occluder_res: 32 }
    }
}

impl VisibilityParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        require((2..=128).contains(&self.res), "cube resolution", self.res, "2 to 128")?;
        require(
            (1..=32).contains(&self.occluder_dirs),
            "occluder directions",
            self.occluder_dirs,
            "1 to 32",
        )?;
        require(
            (2..=128).contains(&self.occluder_res),
            "occluder resolution",
            self.occluder_res,
            "2 to 128",
        )?;
        Ok(())
    }
}

/// Cube maps cast per parallel chunk.
const CHUNK: usize = 64;

/// The visibility of `scene`'s objects over `texels` (module doc). `control` reports texels done.
pub fn build_visibility(
    scene: &Scene,
    texels: &TexelSet,
    params: &VisibilityParams,
    control: Control,
) -> Result<Visibility, Cancelled> {
    let objects = scene.movables.len() + 1;
    let mut slots = vec![(0u32, 0u32); texels.len()];
    let mut escape = vec![0f32; texels.len()];
    let mut out = Vec::with_capacity(objects);
    let mut done = 0;
    for o in 0..objects as u32 {
        let tris: Vec<u32> =
            (0..scene.triangles.len() as u32).filter(|&t| scene.object(t as usize) == o).collect();
        let (lo, hi) = tris
            .iter()
            .flat_map(|&t| scene.corners(t as usize))
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p), hi.max(p)));
        let diagonal = (hi - lo).length().max(1e-6);
        let bvh = Bvh::build_subset(scene, &tris, scene.diagonal().max(diagonal));
        let order = coherent_order(texels, |t| scene.object(texels.texels[t].triangle as usize) == o);
        let mut builder = CssmBuilder::new(params.res, diagonal * 1.01);
        for chunk in order.chunks(CHUNK) {
            control.check()?;
            let maps: Vec<CubeMap> =
                chunk.par_iter().map(|&t| cube_map(&bvh, &texels.texels[t as usize], params.res)).collect();
            for (&t, (origin, intervals, open)) in chunk.iter().zip(maps) {
                builder.push(origin, &intervals);
                if o == 0 {
                    escape[t as usize] = open;
                }
            }
            done += chunk.len();
            (control.progress)(done);
        }
        for (k, &t) in order.iter().enumerate() {
            slots[t as usize] = (o, k as u32);
        }
        let occluder = (o > 0).then(|| occluder_maps(&bvh, lo, hi, params));
        out.push(ObjectVisibility { cssm: builder.finish(), occluder, texels: order });
    }
    Ok(Visibility { objects: out, slots, escape, width: texels.width, height: texels.height })
}

/// One texel's cube map: its origin, per pixel `(z1, z2)`, and the cosine-weighted share of
/// the pixels above the surface that meet nothing.
type CubeMap = (Vec3, Vec<(f32, f32)>, f32);

/// The depth intervals of one texel's cube map ([`CubeMap`]).
///
/// A pixel's interval holds for the directions bilinear filtering reads it for (within one
/// pixel of its centre), not only its centre: `z1` is the largest first hit and `z2` the
/// smallest second hit over its centre and its eight neighbours' on the same face. A query
/// point on the first surface anywhere there is then seen without a depth slack that would let
/// thin walls leak. Where that span holds a depth discontinuity (no common interval), the
/// centre's own interval is kept.
fn cube_map(bvh: &Bvh, t: &prm::Texel, res: u32) -> CubeMap {
    let origin = bvh.offset(t.position, t.normal);
    let r = res as usize;
    let pixels = 6 * r * r;
    // Per pixel centre: None for "don't care", else (first, second) hit distances.
    let hits: Vec<Option<(f32, f32)>> = (0..pixels)
        .map(|p| {
            let d = cube::pixel_direction(p, res);
            if d.dot(t.normal) < 0.0 {
                return None;
            }
            let Some(first) = bvh.closest_hit(origin, d, f32::INFINITY) else {
                return Some((f32::INFINITY, f32::INFINITY));
            };
            let at = origin + d * first.t;
            let past = bvh.eps_at(at) * 4.0;
            let second = bvh
                .closest_hit(at + d * past, d, f32::INFINITY)
                .map_or(f32::INFINITY, |h| first.t + past + h.t);
            Some((first.t, second))
        })
        .collect();
    // Each pixel's solid angle is about (2/res)² cos³ of its angle to its face's axis; weighted
    // by the cosine to the normal, the pixels that meet nothing are the share that escapes.
    let (mut open, mut all) = (0.0f32, 0.0f32);
    for (p, h) in hits.iter().enumerate() {
        if let Some((z1, _)) = h {
            let d = cube::pixel_direction(p, res);
            let w = d.abs().max_element().powi(3) * d.dot(t.normal);
            all += w;
            if !z1.is_finite() {
                open += w;
            }
        }
    }
    let escape = if all > 0.0 { (open / all).clamp(0.0, 1.0) } else { 0.0 };
    let intervals = (0..pixels)
        .map(|p| {
            let Some(own) = hits[p] else { return prm::visibility::cssm::DONT_CARE };
            let (f, y, x) = (p / (r * r), (p / r) % r, p % r);
            let (mut z1, mut z2) = own;
            for ny in y.saturating_sub(1)..=(y + 1).min(r - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(r - 1) {
                    if let Some((a, b)) = hits[f * r * r + ny * r + nx] {
                        z1 = z1.max(a);
                        z2 = z2.min(b);
                    }
                }
            }
            if z1 < z2 {
                (z1, z2)
            } else {
                own
            }
        })
        .collect();
    (origin, intervals, escape)
}

/// The texels `member` selects, in the coherent zig-zag order of the module doc.
pub fn coherent_order(texels: &TexelSet, member: impl Fn(usize) -> bool) -> Vec<u32> {
    let (w, h) = (texels.width as usize, texels.height as usize);
    let is_member = |flat: usize| {
        let t = texels.index[flat];
        t != TexelSet::EMPTY && member(t as usize)
    };
    // Charts: 4-connected components, found in row-major order of their first texel.
    let mut chart = vec![u32::MAX; w * h];
    let mut charts: Vec<Vec<usize>> = Vec::new();
    for start in 0..w * h {
        if chart[start] != u32::MAX || !is_member(start) {
            continue;
        }
        let id = charts.len() as u32;
        let mut stack = vec![start];
        let mut cells = Vec::new();
        chart[start] = id;
        while let Some(f) = stack.pop() {
            cells.push(f);
            let (x, y) = (f % w, f / w);
            let mut visit = |g: usize| {
                if chart[g] == u32::MAX && is_member(g) {
                    chart[g] = id;
                    stack.push(g);
                }
            };
            if x > 0 {
                visit(f - 1);
            }
            if x + 1 < w {
                visit(f + 1);
            }
            if y > 0 {
                visit(f - w);
            }
            if y + 1 < h {
                visit(f + w);
            }
        }
        cells.sort_unstable();
        charts.push(cells);
    }
    let centroid = |c: &[usize]| {
        c.iter().map(|&f| texels.texels[texels.index[f] as usize].position).sum::<Vec3>() / c.len() as f32
    };
    let centres: Vec<Vec3> = charts.iter().map(|c| centroid(c)).collect();
    let mut visited = vec![false; charts.len()];
    let mut order = Vec::new();
    let mut current = 0;
    for _ in 0..charts.len() {
        visited[current] = true;
        // Zig-zag over the chart's rows (its cells are sorted row-major).
        let cells = &charts[current];
        let mut row_start = 0;
        let mut row = 0;
        while row_start < cells.len() {
            let y = cells[row_start] / w;
            let end = row_start + cells[row_start..].iter().take_while(|&&f| f / w == y).count();
            let run = &cells[row_start..end];
            let mut push = |f: &usize| order.push(texels.index[*f]);
            if row % 2 == 0 {
                run.iter().for_each(&mut push);
            } else {
                run.iter().rev().for_each(&mut push);
            }
            row += 1;
            row_start = end;
        }
        let here = centres[current];
        let next = (0..charts.len()).filter(|&c| !visited[c]).min_by(|&a, &b| {
            (centres[a] - here).length_squared().total_cmp(&(centres[b] - here).length_squared())
        });
        match next {
            Some(n) => current = n,
            None => break,
        }
    }
    order
}

/// A movable's occluder maps over its bounding box `lo`..`hi` (rest frame).
fn occluder_maps(bvh: &Bvh, lo: Vec3, hi: Vec3, params: &VisibilityParams) -> Csm {
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-6) * 1.02;
    let mut csm =
        Csm { dirs: params.occluder_dirs, res: params.occluder_res, centre, radius, depths: Vec::new() };
    let (dirs, res) = (6 * (params.occluder_dirs as usize).pow(2), params.occluder_res);
    let maps: Vec<Vec<[u8; 2]>> = (0..dirs)
        .into_par_iter()
        .map(|k| {
            let d = cube::pixel_direction(k, params.occluder_dirs);
            let mut map = Vec::with_capacity((res * res) as usize);
            for y in 0..res {
                for x in 0..res {
                    let c = centre + csm.pixel_offset(d, x, y);
                    let reach = 2.0 * radius;
                    let entry = bvh.closest_hit(c - d * radius, d, reach).map(|h| h.t - radius);
                    let exit = bvh.closest_hit(c + d * radius, -d, reach).map(|h| radius - h.t);
                    map.push(match (entry, exit) {
                        (Some(a), Some(b)) => [csm.code(a, false), csm.code(b.max(a), true)],
                        _ => [prm::visibility::csm::MISS, 0],
                    });
                }
            }
            map
        })
        .collect();
    csm.depths = maps.concat();
    csm
}

/// The texel set of a level with movables: [`TexelSet::build`] unburied against the static
/// level only, so a floor texel under a block at rest keeps its point (the block moves away)
/// and a movable's texels are judged against the static level alone.
pub fn moving_texel_set(scene: &Scene, width: u32, height: u32) -> TexelSet {
    let statics: Vec<u32> =
        (0..scene.triangles.len() as u32).filter(|&t| scene.object(t as usize) == 0).collect();
    let bvh = Bvh::build_subset(scene, &statics, scene.diagonal());
    TexelSet::build_visible(scene, &bvh, width, height)
}
