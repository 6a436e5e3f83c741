//! The walks' next bounce from a table ([`NextBounce`]): at each vertex of a gather walk,
//! the light every cluster sends there after one bounce, instead of the cluster the next hit
//! happens to land in.
//!
//! A pane's k-th bounce at texel x is `E[beta_k [y_k in c]]` over walks from x. The gather
//! estimated it by crediting the cluster the k-th vertex landed in; a hot cluster (a pillar
//! face 15 cm from a torch, a third of the room's reflected light) is met by a texel 8 m away
//! in about one walk of a hundred, and each meeting put a blob of the pane filter's size into
//! its pane. But `E[beta_k [y_k in c] | y_{k-1}] = beta_{k-1} F_c(y_{k-1})`, where `F_c(y)` is
//! the first bounce cluster c's unit irradiance gives at y, and the precompute knows `F_c` at
//! every covered texel already: the near links' exact first bounce plus the far field's
//! (`crate::far::first_bounce_into`). So each vertex adds `beta F_c` for every cluster at once,
//! read from the table row of the cell it lies in (the mean of `F_c` over that cell's
//! texels), and the next hit adds nothing: every cluster that vertex sees contributes every
//! time. On the chamber's torches the walks' noise went from 4.9-8.1 % to 1.4-1.5 % at the
//! same 128 walks (1.8-2.1 % at 64), which is what lets the default take 64 walks.
//!
//! What the table cannot say is left to the walks' hits, unchanged: a vertex in a cell with
//! no texel (no row), a vertex with no cell (the back of a double-sided triangle), a texel
//! the far field does not light (its first hits are credited as before), and a hit farther
//! from its vertex than the far field's radius (neither the far field nor the table reaches
//! it).
//!
//! **Weak elements** ([`Cutoff`]). Every vertex adds its whole row, so the rows' length is
//! what the walks cost: in one room every cell sees every cluster (164 elements a row on the
//! chamber), most of them weakly. An element whose first bounce is under a cluster's cutoff
//! `t_c` is kept with probability `F / t_c` and then carries `t_c` (Russian roulette, made
//! once when the row is made): each element's expectation is unchanged, the rows are 2.6x
//! shorter on the chamber (671,221 -> 253,587 elements) and its walks 0.4-0.5 s faster. The
//! cutoff is the first bounce an albedo-1 cluster facing a cell head-on gives at `reach`
//! entry spacings: its area over `pi (reach s)^2` with s² = A / N the entry's area, so
//! `t_c = |c| / (pi reach²)`, the same at any density and scale, and a function of the row
//! alone (an update's rows follow only what changed). The noise it adds is the walks' kind (a
//! weak cluster's light at a vertex sometimes counted larger, mostly not), small against
//! theirs: at the default reach of 32 it moved the chamber's torch frames by 0.1-1.0 % RMS
//! against the same walks with every element (the tests hold the expectation).

use glam::Vec3;
use prm::fingerprint::{fnv1a, FNV_START};
use prm::sampling::stream;
use prm::TexelSet;
use rand::Rng;
use rayon::prelude::*;

use super::TexelPanes;

/// Texels per cell whose first bounce makes its row (their mean).
pub const CELL_SAMPLES: usize = 4;

/// Cells whose rows are made at a time (what the sampled texels' first bounce holds).
const CELL_CHUNK: usize = 2048;
use crate::cells::CellOwners;

/// The random streams' tag of the rows' roulette ([`Cutoff`]).
const CUTOFF_STREAM: u64 = 1 << 40;

/// Per cluster, the first bounce under which a row element is kept by Russian roulette only
/// (module doc, *Weak elements*), and the seed of its draws. Empty: every element is kept.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cutoff {
    below: Vec<f32>,
    seed: u64,
}

impl Cutoff {
    /// The cutoffs of clusters of `members` entries each at `reach` entry spacings (0: none).
    pub fn new(members: impl IntoIterator<Item = usize>, reach: f32, seed: u64) -> Cutoff {
        if !(reach > 0.0) {
            return Cutoff { below: Vec::new(), seed };
        }
        let per_entry = 1.0 / (std::f32::consts::PI * reach * reach);
        Cutoff { below: members.into_iter().map(|m| m as f32 * per_entry).collect(), seed }
    }

    /// Entry `e`'s row with its weak elements played out: each element under its cluster's
    /// cutoff (in its largest channel) is dropped, or kept at the cutoff with probability
    /// value / cutoff. The draws are entry `e`'s own stream, in the row's order.
    fn apply(&self, e: usize, row: TexelPanes) -> TexelPanes {
        if self.below.is_empty() {
            return row;
        }
        let mut rng = stream(self.seed, CUTOFF_STREAM, e as u64);
        row.into_iter()
            .filter_map(|(c, v)| {
                let (m, t) = (v.max_element(), self.below.get(c as usize).copied().unwrap_or(0.0));
                if m >= t {
                    return Some((c, v));
                }
                (rng.random::<f32>() * t < m).then(|| (c, v * (t / m)))
            })
            .collect()
    }

    /// A digest of the cutoffs and seed (every row's inputs include it).
    fn digest(&self) -> u64 {
        let h = self.below.iter().fold(FNV_START, |h, t| fnv1a(h, &t.to_le_bytes()));
        fnv1a(h, &self.seed.to_le_bytes())
    }
}

/// Per entry cell, the first bounce per unit irradiance of each cluster at its texels (their
/// mean), and which texels have their own first bounce given (module doc).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NextBounce {
    /// Bit per atlas texel (row-major): its whole first bounce is in its exact panes.
    whole: Vec<u64>,
    /// Per entry, where its row starts in `cluster` and `value`; then their length.
    first: Vec<u32>,
    /// Per row, the clusters ascending (at most 65,536 clusters: `PrecomputeParams::check`)
    /// and their first bounce (irradiance per unit cluster irradiance) in steps of the row's
    /// `unit`: 8 bytes an element instead of 16, the table being the largest thing the walks
    /// hold (192 MB on the 16 chambers before). A step is 1/65,535 of the row's largest value
    /// per channel, far below the walks' noise.
    cluster: Vec<u16>,
    value: Vec<[u16; 3]>,
    /// Per entry, its row's step per channel.
    unit: Vec<Vec3>,
    /// Bit per entry: its row was not made (an update makes only the rows its walks can
    /// reach; a walk that meets one of these counts it: [`NextBounce::left_out`]). Empty when
    /// every row was made.
    left_out: Vec<u64>,
    /// A hit farther than this from its vertex is the walks' (scene units).
    radius: f32,
}

impl NextBounce {
    /// The table for `entries` cells: each row is the mean first bounce at up to
    /// `CELL_SAMPLES` (4) of its cell's texels spread over it (a cell holds a texel when its
    /// entry owns the texel's point), the links' (`links(k)`, covered texel k's) plus the far
    /// field's (`first`). `lit`: the covered texels whose whole first bounce that is. With
    /// `only`, the rows of the entries it marks alone are made; the others are left out. Weak
    /// elements are played out by `cutoff`.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        set: &TexelSet,
        samples: &CellSamples,
        links: &(dyn Fn(usize) -> TexelPanes + Sync),
        lit: &[bool],
        first: &crate::far::FirstBounce,
        entries: usize,
        clusters: usize,
        radius: f32,
        only: Option<&[bool]>,
        cutoff: &Cutoff,
    ) -> NextBounce {
        let made = |e: usize| only.is_none_or(|o| o.get(e).copied().unwrap_or(false));
        // A row left out is empty: its entry's texels are not sampled.
        let sample = |e: usize| samples.of(e).take(if made(e) { CELL_SAMPLES } else { 0 });
        let mut bits = vec![0u64; (set.width as usize * set.height as usize).div_ceil(64)];
        for (t, _) in set.texels.iter().zip(lit).filter(|(_, &w)| w) {
            let a = t.j as usize * set.width as usize + t.i as usize;
            bits[a / 64] |= 1 << (a % 64);
        }
        let mut out = NextBounce { whole: bits, radius, ..NextBounce::default() };
        out.first.reserve(entries + 1);
        if only.is_some() {
            out.left_out = vec![0u64; entries.div_ceil(64)];
            for e in (0..entries).filter(|&e| !made(e)) {
                out.left_out[e / 64] |= 1 << (e % 64);
            }
        }
        // Each chunk's rows go straight into the table: only a chunk's are ever held twice.
        for cells in (0..entries).collect::<Vec<_>>().chunks(CELL_CHUNK) {
            let flat: Vec<usize> = cells.iter().flat_map(|&e| sample(e)).collect();
            let mut exact: Vec<TexelPanes> = flat.par_iter().map(|&k| links(k)).collect();
            first.add(&flat, &mut exact, None);
            let mut from = vec![0usize; cells.len() + 1];
            for (i, &e) in cells.iter().enumerate() {
                from[i + 1] = from[i] + sample(e).count();
            }
            let rows: Vec<QuantisedRow> = (0..cells.len())
                .into_par_iter()
                .map_init(
                    || (vec![Vec3::ZERO; clusters], Vec::new()),
                    |(acc, touched): &mut (Vec<Vec3>, Vec<u32>), i| {
                        let texels = &exact[from[i]..from[i + 1]];
                        for tp in texels {
                            for &(c, v) in tp {
                                if acc[c as usize] == Vec3::ZERO {
                                    touched.push(c);
                                }
                                acc[c as usize] += v;
                            }
                        }
                        touched.sort_unstable();
                        touched.dedup();
                        let scale = 1.0 / texels.len().max(1) as f32;
                        let row: TexelPanes = touched
                            .iter()
                            .map(|&c| (c, std::mem::take(&mut acc[c as usize]) * scale))
                            .collect();
                        touched.clear();
                        quantise(&cutoff.apply(cells[i], row))
                    },
                )
                .collect();
            drop(exact);
            for (unit, row) in rows {
                out.first.push(out.cluster.len() as u32);
                out.unit.push(unit);
                for (c, q) in row {
                    out.cluster.push(c);
                    out.value.push(q);
                }
            }
        }
        out.first.push(out.cluster.len() as u32);
        out
    }

    /// Whether atlas texel `atlas` has its whole first bounce given.
    pub fn whole(&self, atlas: u32) -> bool {
        let a = atlas as usize;
        self.whole.get(a / 64).is_some_and(|w| w >> (a % 64) & 1 == 1)
    }

    /// Entry `e`'s row (clusters, first bounce in steps, the step), None where its cell has
    /// none. Element k's first bounce is `unit * steps(value[k])`.
    pub fn row(&self, e: u32) -> Option<Row<'_>> {
        let e = e as usize;
        let (a, b) = (*self.first.get(e)? as usize, *self.first.get(e + 1)? as usize);
        (b > a).then(|| Row { cluster: &self.cluster[a..b], value: &self.value[a..b], unit: self.unit[e] })
    }

    /// This table with the rows `other` made where this one left them out (the two made for
    /// the same level: an update makes some rows first, the rest it needs later).
    pub fn merged(self, other: &NextBounce) -> NextBounce {
        if self.left_out.is_empty() {
            return self;
        }
        let entries = self.unit.len();
        let mut out = NextBounce { whole: self.whole.clone(), radius: self.radius, ..NextBounce::default() };
        let mut left_out = vec![0u64; entries.div_ceil(64)];
        for e in 0..entries {
            let from = if !self.left_out(e as u32) {
                &self
            } else if !other.left_out(e as u32) && other.unit.len() == entries {
                other
            } else {
                left_out[e / 64] |= 1 << (e % 64);
                &self
            };
            let (a, b) = (from.first[e] as usize, from.first[e + 1] as usize);
            out.first.push(out.cluster.len() as u32);
            out.unit.push(from.unit[e]);
            out.cluster.extend_from_slice(&from.cluster[a..b]);
            out.value.extend_from_slice(&from.value[a..b]);
        }
        out.first.push(out.cluster.len() as u32);
        if left_out.iter().any(|&w| w != 0) {
            out.left_out = left_out;
        }
        out
    }

    /// Whether any row was left out.
    pub fn left_out_any(&self) -> bool {
        self.left_out.iter().any(|&w| w != 0)
    }

    /// Whether entry `e`'s row was left out of the table (not made: `build`'s `only`).
    pub fn left_out(&self, e: u32) -> bool {
        let e = e as usize;
        self.left_out.get(e / 64).is_some_and(|w| w >> (e % 64) & 1 == 1)
    }

    /// Whether a hit `distance` from its vertex is in the table's reach.
    pub fn reaches(&self, distance: f32) -> bool {
        distance <= self.radius
    }

    /// Whether the table is whole and in range for `entries` cells, `clusters` clusters and an
    /// atlas of `texels` texels (a plan file read back is checked with it).
    pub fn fits(&self, entries: usize, clusters: usize, texels: usize) -> bool {
        self.first.len() == entries + 1
            && self.unit.len() == entries
            && self.unit.iter().all(|u| u.is_finite() && u.min_element() >= 0.0)
            && self.first.first() == Some(&0)
            && self.first.windows(2).all(|w| w[0] <= w[1])
            && self.first.last().is_some_and(|&l| l as usize == self.cluster.len())
            && self.cluster.len() == self.value.len()
            && self.cluster.iter().all(|&c| (c as usize) < clusters)
            && self.whole.len() == texels.div_ceil(64)
            && (self.left_out.is_empty() || self.left_out.len() == entries.div_ceil(64))
            && self.radius >= 0.0
    }

    /// Per entry, a digest of its row (clusters, and values to 16 mantissa bits as the update's
    /// other digests: `crate::update`), so an update can tell which rows an edit changed.
    pub fn row_digests(&self) -> Vec<u64> {
        (0..self.first.len().saturating_sub(1)).map(|e| self.row_digest(e)).collect()
    }

    /// Entry `e`'s row's digest ([`NextBounce::row_digests`]); a row left out has the digest
    /// of an empty one.
    pub fn row_digest(&self, e: usize) -> u64 {
        let (a, b) = match (self.first.get(e), self.first.get(e + 1)) {
            (Some(&a), Some(&b)) => (a as usize, b as usize),
            _ => (0, 0),
        };
        let mut h = FNV_START;
        for x in self.unit.get(e).copied().unwrap_or_default().to_array() {
            h = fnv1a(h, &crate::update::round16(x).to_le_bytes());
        }
        for (c, q) in self.cluster[a..b].iter().zip(&self.value[a..b]) {
            h = fnv1a(h, &c.to_le_bytes());
            for x in q {
                h = fnv1a(h, &x.to_le_bytes());
            }
        }
        h
    }

    /// Per entry, a digest of what [`NextBounce::build`] makes its row of: which of its
    /// cell's texels it samples, each one's digest of its exact first bounce's inputs
    /// (`exact`, per covered texel: `Preamble::exact_digests`), and the cutoff with the entry
    /// whose draws play out its weak elements. An update makes again only
    /// the rows whose inputs differ from the old bake's, to learn which values changed (the
    /// others' are as they were).
    pub fn input_digests(
        samples: &CellSamples,
        exact: &[u64],
        entries: usize,
        radius: f32,
        cutoff: &Cutoff,
    ) -> Vec<u64> {
        let start = fnv1a(cutoff.digest(), &radius.to_le_bytes());
        (0..entries)
            .into_par_iter()
            .map(|e| {
                let mut h = fnv1a(start, &(e as u64).to_le_bytes());
                for k in samples.of(e) {
                    h = fnv1a(h, &exact.get(k).copied().unwrap_or(0).to_le_bytes());
                }
                fnv1a(h, &(samples.of(e).count() as u32).to_le_bytes())
            })
            .collect()
    }
}

/// Per entry cell, the covered texels its row is the mean of: up to `CELL_SAMPLES` (4) of the
/// lit texels its entry owns, evenly spread over them (set order). Found once per bake (each
/// texel's cell) and read by every pass over the rows.
#[derive(Clone, Debug, Default)]
pub struct CellSamples {
    /// (entry, texel) pairs, by entry then texel.
    by_cell: Vec<(u32, u32)>,
    /// Per entry, where its pairs start; then their length.
    start: Vec<usize>,
}

impl CellSamples {
    /// The samples of `entries` cells over `set`'s texels that `lit` marks.
    pub fn new(set: &TexelSet, owners: &CellOwners, lit: &[bool], entries: usize) -> CellSamples {
        let owner: Vec<Option<u32>> = set
            .texels
            .par_iter()
            .zip(lit)
            .map(|(t, &w)| if w { owners.owner(t.triangle as usize, t.position) } else { None })
            .collect();
        let mut by_cell: Vec<(u32, u32)> = owner
            .iter()
            .enumerate()
            .filter_map(|(k, o)| o.filter(|&e| (e as usize) < entries).map(|e| (e, k as u32)))
            .collect();
        by_cell.sort_unstable();
        let mut start = vec![0usize; entries + 1];
        for &(e, _) in &by_cell {
            start[e as usize + 1] += 1;
        }
        for e in 0..entries {
            start[e + 1] += start[e];
        }
        CellSamples { by_cell, start }
    }

    /// Entry `e`'s sampled texels (covered texel indices).
    fn of(&self, e: usize) -> impl Iterator<Item = usize> + Clone + '_ {
        let texels = &self.by_cell[self.start[e]..self.start[e + 1]];
        let m = texels.len().min(CELL_SAMPLES);
        (0..m).map(move |i| texels[(2 * i + 1) * texels.len() / (2 * m)].1 as usize)
    }
}

/// A row's step per channel and its elements (cluster, steps), as [`quantise`] makes them.
type QuantisedRow = (Vec3, Vec<(u16, [u16; 3])>);

/// One cell's row of the table ([`NextBounce::row`]).
pub struct Row<'a> {
    pub cluster: &'a [u16],
    pub value: &'a [[u16; 3]],
    pub unit: Vec3,
}

/// A row's values as steps, per channel in units of its largest / 65,535, rounded to the
/// nearest (what it adds is then within half a step of the mean it was made of); elements
/// that round to nothing in every channel are left out. Clusters are below 65,536
/// (`PrecomputeParams::check`).
fn quantise(row: &TexelPanes) -> QuantisedRow {
    let top = row.iter().fold(Vec3::ZERO, |m, &(_, v)| m.max(v));
    let unit = top / f32::from(u16::MAX);
    let inverse = Vec3::select(unit.cmpgt(Vec3::ZERO), unit.recip(), Vec3::ZERO);
    let out = row
        .iter()
        .map(|&(c, v)| {
            let q = (v * inverse).round().clamp(Vec3::ZERO, Vec3::splat(f32::from(u16::MAX)));
            (c as u16, [q.x as u16, q.y as u16, q.z as u16])
        })
        .filter(|(_, q)| *q != [0; 3])
        .collect();
    (unit, out)
}

/// A row element's steps as floats.
#[inline]
pub fn steps(q: [u16; 3]) -> Vec3 {
    Vec3::new(f32::from(q[0]), f32::from(q[1]), f32::from(q[2]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quantised_row_is_within_half_a_step_of_its_values_and_drops_only_what_rounds_to_nothing() {
        let row: TexelPanes = vec![
            (3, Vec3::new(1.0, 0.5, 0.0)),
            (7, Vec3::new(1e-6, 0.0, 0.0)),
            (9, Vec3::new(0.25, 2.0, 1e-9)),
            (65_535, Vec3::new(0.3, 0.7, 4e-3)),
        ];
        let (unit, q) = quantise(&row);
        // The step per channel is the channel's largest over 65,535.
        assert_eq!(unit, Vec3::new(1.0, 2.0, 4e-3) / 65_535.0);
        // 1e-6 is under half a step of 1/65,535 in every channel: left out; the rest kept in order.
        let kept: Vec<u16> = q.iter().map(|&(c, _)| c).collect();
        assert_eq!(kept, [3, 9, 65_535]);
        for &(c, s) in &q {
            let v = row.iter().find(|&&(x, _)| x as u16 == c).map(|&(_, v)| v).unwrap();
            let err = (unit * steps(s) - v).abs();
            assert!(err.cmple(unit * 0.5 + 1e-12).all(), "cluster {c}: {v} came back as {}", unit * steps(s));
        }
        // A row of nothing stays nothing, with a zero step rather than a division by zero.
        let (unit, q) = quantise(&vec![(1, Vec3::ZERO)]);
        assert_eq!((unit, q.len()), (Vec3::ZERO, 0));
    }

    #[test]
    fn the_cutoff_keeps_strong_elements_and_each_weak_one_in_expectation() {
        // Clusters of 16, 16, 4 and 4 entries at a reach of 4 spacings: cutoffs 16 / (16 pi)
        // and 4 / (16 pi).
        let cutoff = Cutoff::new([16, 16, 4, 4], 4.0, 7);
        let (t0, t1) = (1.0 / std::f32::consts::PI, 0.25 / std::f32::consts::PI);
        let row: TexelPanes = vec![
            (0, Vec3::new(0.5, 0.2, 0.1)),    // above t0: kept as it is
            (1, Vec3::new(0.02, 0.05, 0.01)), // a sixth of t0
            (2, Vec3::new(0.03, 0.0, 0.015)), // under half of t1
            (3, Vec3::new(0.2, 0.1, 0.0)),    // above t1
        ];
        let runs = 20_000;
        let mut sum = [Vec3::ZERO; 4];
        for e in 0..runs {
            let out = cutoff.apply(e, row.clone());
            assert_eq!(out, cutoff.apply(e, row.clone()), "the draws are the entry's own");
            // The strong elements come back whole, and each weak one kept carries its
            // cluster's cutoff in its largest channel, its channels in proportion.
            assert_eq!(out.first(), row.first());
            assert_eq!(out.last(), row.last());
            for &(c, v) in &out {
                let (t, was) = (if c < 2 { t0 } else { t1 }, row[c as usize].1);
                if c == 1 || c == 2 {
                    assert!((v.max_element() - t).abs() < 1e-6 * t, "cluster {c} kept at {v}");
                    assert!((v * was.max_element() - was * t).abs().max_element() < 1e-6, "{v} for {was}");
                }
                sum[c as usize] += v;
            }
        }
        // The mean over 20,000 entries' draws is each element's value: within 4 standard errors
        // of a keep-or-drop draw (p = 1/6 and 0.38: a relative error under 3 % and 2 %).
        for (c, &(_, v)) in row.iter().enumerate() {
            let mean = sum[c] / runs as f32;
            assert!((mean - v).abs().cmple(v * 0.04 + 1e-9).all(), "cluster {c}: mean {mean} for {v}");
        }
        // No cutoff, no change; the cutoff and its seed are in the rows' input digests.
        let none = Cutoff::new([16, 16, 4, 4], 0.0, 7);
        assert_eq!(none.apply(3, row.clone()), row);
        assert_ne!(none.digest(), cutoff.digest());
        assert_ne!(Cutoff::new([16, 16, 4, 4], 4.0, 8).digest(), cutoff.digest());
    }
}
