//! Geometry-guided smoothing of atlas images (the precompute's pane filter).
//!
//! A pane's walked values carry Monte Carlo noise that does not average out where a light's
//! weight sits in one or two clusters (a lamp by a wall), while the pane itself varies slowly
//! over a surface once the sharp part (the near links' first bounce) is kept out of it. The
//! filter averages a texel with its atlas neighbours on the same surface, out to a reach given
//! in the world (the precompute passes one entry spacing): per texel, `r` = the reach over the
//! texel's world size, rounded (at most [`MAX_RADIUS`]), and a Gaussian of standard deviation
//! `0.5 r + 0.5` texels cut at `r`. A texel takes only neighbours whose normal is within ~25
//! degrees, that sit off its plane by under a quarter of the filter's world footprint, and
//! that are no farther in the world than that footprint (`r + 1.5` texel sizes). So it never
//! mixes a floor with the wall above it, nor two charts that are neighbours in the atlas only,
//! and the same reach holds at any texel density (a 10-texel face is not blurred whole).
//!
//! It runs as two one-dimensional passes, along rows and then along columns, each normalised
//! over the taps it kept (the column pass tests its taps against the texel, and they carry
//! what the row pass took in against theirs, so light may reach a texel through one hop: up to
//! twice the footprint, or across a bevel between two faces; a hard crease still stops it): `4 r + 2` taps a texel instead of `(2 r + 1)²`, which is what makes
//! the measured reach (one entry spacing, 3 texels on the bundled levels: chamber torches
//! 10.0 -> 8.1 % mean error when it came) affordable in the precompute budget. Weights depend on
//! geometry only, so the filter is linear: smoothing panes and then summing them is summing and
//! then smoothing, which is what lets the runtime compose smoothed panes.

use glam::Vec3;
use rayon::prelude::*;

use super::TexelSet;
use crate::scene::Scene;

/// A texel set's smoothing filter, built once and applied to any number of atlas images.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Smoothing {
    /// Atlas width in texels.
    width: u32,
    /// Rows, then columns.
    passes: [Pass; 2],
}

/// One one-dimensional pass: for each covered texel (in `TexelSet::texels` order) its atlas
/// index and its taps (atlas index, weight), the weights summing to one.
#[derive(serde::Serialize, serde::Deserialize)]
struct Pass {
    /// The farthest a tap lies above or below its texel, in rows.
    row_reach: u32,
    target: Vec<u32>,
    start: Vec<u32>,
    taps: Vec<(u32, f32)>,
}

impl Smoothing {
    /// Smooth the covered texels of a full-atlas image in place (empty texels are left as
    /// they are and never read).
    pub fn apply(&self, img: &mut [Vec3]) {
        let height = (img.len() / self.width.max(1) as usize) as u32;
        self.apply_rows(img, 0..height, height);
    }

    /// How many rows a smoothed texel's value reaches: it depends on texels at most this far
    /// above or below it (the column pass's radius; the row pass stays in its row).
    pub fn row_reach(&self) -> u32 {
        self.passes.iter().map(|p| p.row_reach).sum()
    }

    /// How many columns a smoothed texel's value reaches (the row pass's largest radius, at
    /// most 16 texels; the column pass stays in its column). Scans the taps.
    pub fn column_reach(&self) -> u32 {
        let pass = &self.passes[0];
        let mut reach = 0u32;
        for (k, &t) in pass.target.iter().enumerate() {
            for &(n, _) in &pass.taps[pass.start[k] as usize..pass.start[k + 1] as usize] {
                reach = reach.max(n.abs_diff(t));
            }
        }
        reach
    }

    /// Smooth a window of whole atlas rows in place: `img` holds rows `window` of an atlas
    /// `height` rows high, row-major. A texel at least [`Smoothing::row_reach`] rows inside
    /// the window (or nearer the atlas's edge than that) gets exactly what
    /// [`Smoothing::apply`] gives it; the rest of the window is left unspecified. This is what
    /// lets the precompute smooth panes a band at a time.
    pub fn apply_rows(&self, img: &mut [Vec3], window: std::ops::Range<u32>, height: u32) {
        self.apply_rows_in(img, window, height, std::slice::from_ref(&(0..self.width)));
    }

    /// [`Smoothing::apply_rows`] for the texels of the column runs `cols` only (ascending, not
    /// overlapping): each of them gets what `apply_rows` gives it, provided the image is zero
    /// at every texel outside the runs within [`Smoothing::column_reach`] columns of one inside
    /// (the row pass reads that far; the column pass stays in its column). The rest of the
    /// image is left as it is. A pane whose light lies in a few charts is smoothed at the cost
    /// of those, not of the whole band.
    pub fn apply_rows_in(
        &self,
        img: &mut [Vec3],
        window: std::ops::Range<u32>,
        height: u32,
        cols: &[std::ops::Range<u32>],
    ) {
        let w = self.width as usize;
        let offset = window.start as usize * w;
        let mut valid = window;
        for pass in &self.passes {
            if valid.start > 0 {
                valid.start += pass.row_reach;
            }
            if valid.end < height {
                valid.end = valid.end.saturating_sub(pass.row_reach);
            }
            // Every output of the pass, in every run, is computed before any is written.
            let mut runs = Vec::new();
            let mut out: Vec<Vec3> = Vec::new();
            for row in valid.clone() {
                for c in cols {
                    let at = |x: u32| row as usize * w + x.min(self.width) as usize;
                    let first = pass.target.partition_point(|&t| (t as usize) < at(c.start));
                    let last = pass.target.partition_point(|&t| (t as usize) < at(c.end));
                    if first >= last {
                        continue;
                    }
                    runs.push(first..last);
                    out.extend(pass.start[first..=last].windows(2).map(|r| {
                        pass.taps[r[0] as usize..r[1] as usize]
                            .iter()
                            .fold(Vec3::ZERO, |a, &(n, wgt)| a + img[n as usize - offset] * wgt)
                    }));
                }
            }
            let mut values = out.into_iter();
            for run in runs {
                for (&t, v) in pass.target[run].iter().zip(&mut values) {
                    img[t as usize - offset] = v;
                }
            }
        }
    }

    /// The taps of texel `k` (index into `TexelSet::texels`) in pass `p` (0: rows, 1:
    /// columns), as (atlas index, weight).
    pub fn taps(&self, p: usize, k: usize) -> &[(u32, f32)] {
        let pass = &self.passes[p];
        &pass.taps[pass.start[k] as usize..pass.start[k + 1] as usize]
    }
}

/// The largest filter radius in texels, whatever the reach (a texel far smaller than the
/// reach: a thin strip's chart).
pub const MAX_RADIUS: u32 = 16;

impl TexelSet {
    /// The geometry-guided smoothing out to `reach` scene units (module doc of `smoothing`).
    pub fn smoothing(&self, scene: &Scene, reach: f32) -> Smoothing {
        let radius: Vec<u32> = self
            .texels
            .iter()
            .map(|t| {
                let r = reach / self.world_texel_size(scene, t.triangle as usize);
                if r.is_finite() {
                    r.round().clamp(0.0, MAX_RADIUS as f32) as u32
                } else {
                    0
                }
            })
            .collect();
        let pass = |along_rows: bool| self.smoothing_pass(scene, &radius, along_rows);
        Smoothing { width: self.width, passes: [pass(true), pass(false)] }
    }

    fn smoothing_pass(&self, scene: &Scene, radius: &[u32], along_rows: bool) -> Pass {
        let (w, h) = (self.width as i64, self.height as i64);
        let per_texel: Vec<Vec<(u32, f32)>> = self
            .texels
            .par_iter()
            .enumerate()
            .map(|(k, t)| {
                let r = radius[k] as i64;
                let sigma2 = (0.5 * radius[k] as f32 + 0.5).powi(2);
                let reach = (radius[k] as f32 + 1.5) * self.world_texel_size(scene, t.triangle as usize);
                let mut taps = Vec::with_capacity(2 * r as usize + 1);
                let mut total = 0.0;
                for s in -r..=r {
                    let (i, j) =
                        if along_rows { (t.i as i64 + s, t.j as i64) } else { (t.i as i64, t.j as i64 + s) };
                    if i < 0 || j < 0 || i >= w || j >= h {
                        continue;
                    }
                    let at = (j * w + i) as usize;
                    let n = self.index[at];
                    if n == Self::EMPTY {
                        continue;
                    }
                    let o = &self.texels[n as usize];
                    let d = o.position - t.position;
                    if o.normal.dot(t.normal) < 0.9
                        || d.dot(t.normal).abs() > 0.25 * reach
                        || d.length() > reach
                    {
                        continue;
                    }
                    let wgt = (-((s * s) as f32) / (2.0 * sigma2)).exp();
                    taps.push((at as u32, wgt));
                    total += wgt;
                }
                for tap in &mut taps {
                    tap.1 /= total;
                }
                taps
            })
            .collect();
        let mut start = Vec::with_capacity(per_texel.len() + 1);
        start.push(0u32);
        for taps in &per_texel {
            start.push(start.last().copied().unwrap_or(0) + taps.len() as u32);
        }
        let w = self.width;
        let row_reach = self
            .texels
            .iter()
            .zip(&per_texel)
            .flat_map(|(t, taps)| taps.iter().map(move |&(at, _)| (at / w).abs_diff(t.j)))
            .max()
            .unwrap_or(0);
        Pass {
            row_reach,
            target: self.texels.iter().map(|t| t.j * w + t.i).collect(),
            start,
            taps: per_texel.into_iter().flatten().collect(),
        }
    }
}
