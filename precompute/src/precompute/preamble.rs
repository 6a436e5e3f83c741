//! The preamble of a precompute: every phase before the walks (texels, entries and their
//! cells, clusters and groups, the far field, the near and echo links, the links' exact first
//! bounce, the smoothing), kept as one value so a one-machine precompute, a sharded one's
//! plan and its merge share it (`crate::shard`).

use std::sync::atomic::AtomicBool;
use std::time::Instant;

use glam::Vec3;
use prm::density::UnwrapLayout;
use prm::fingerprint::{fingerprint_hex, geometry_fingerprint};
use prm::prm_file::{far_share, Cells, Echo, Entry, Far, NearLink, NearPoint, Prm};
use prm::{Bvh, Scene, Smoothing, TexelSet};
use rayon::prelude::*;

use super::{Phase, PrecomputeError, PrecomputeParams, Report};
use crate::cells::{entry_cells_in_rooms, entry_rooms, filled_rooms, CellOwners, CellReport};
use crate::cluster::{centroids, cluster_by_room, cluster_entries, Clustering};
use crate::entries::{is_enclosed, relocate, sample_entries};
use crate::far::{far_field, EnergySum, FarReuse, FirstBounce};
use crate::near::{crease_points, echo_links, near_links, EchoReuse, NearReuse};
use crate::parallel::stop_if;
use crate::transport::{CellSamples, Cutoff, Estimator, LinkedCells, NextBounce, TexelPanes, Transport};
use crate::update::{TriangleDigest, Untouched, UpdateCache};

/// Everything the walks and the panes' encoding take from the level before any walk: the
/// texel set, the entries and their cells, the clusters and groups, the near, echo and far
/// fields, the links' exact first bounce and the smoothing, with the counts the file's
/// header records. It depends on the level and the parameters only (not on the thread
/// count), so a sharded precompute (`crate::shard`) makes it once and every shard and the
/// merge read it.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Preamble {
    pub(crate) set: TexelSet,
    /// Per covered texel, the world area it stands for ([`TexelSet::visible_areas`]): what
    /// a pane's power is summed over (`crate::precompute::match_power`; empty without it).
    pub(crate) texel_areas: Vec<f32>,
    pub(crate) entries: Vec<Entry>,
    pub(crate) cells: Cells,
    /// Per entry, the share of its cell's reflected light that lands on the level
    /// ([`crate::cells::reflections`]).
    pub(crate) stays: Vec<f32>,
    /// Per entry, the light that lands on the level over every bounce per unit its cell
    /// reflects ([`crate::cells::reflections`]).
    pub(crate) gains: Vec<Vec3>,

    pub(crate) owners: CellOwners,
    pub(crate) clustering: Clustering,
    pub(crate) centroids: Vec<Vec3>,
    pub(crate) grouping: Option<Clustering>,
    pub(crate) far: Far,
    pub(crate) near: Vec<NearLink>,
    pub(crate) near_points: Vec<NearPoint>,
    /// Per near link, the share of its cell's first bounce the walks keep (None: the walks
    /// keep all of it: `transport::LinkedCells`).
    pub(crate) keep: Option<Vec<f32>>,
    /// The walks' next-bounce table (None: their hits give every bounce).
    pub(crate) next: Option<NextBounce>,
    /// Whether the walks read a next-bounce table (`next`, which an update makes after its
    /// plan: [`Preamble::make_next`]).
    #[serde(skip)]
    pub(crate) next_on: bool,
    /// Per entry, its room (`prm::rooms`, of this level): an update makes the table's rows of
    /// the rooms its walks can reach only.
    #[serde(skip)]
    pub(crate) entry_room: Vec<u32>,
    /// The texels each row of the table is made of, and the texels the far field lights (found
    /// once for the rows' digests and each pass that makes rows).
    #[serde(skip)]
    pub(crate) samples: CellSamples,
    #[serde(skip)]
    pub(crate) lit: Vec<bool>,
    /// The table's cutoff of weak elements (`PrecomputeParams::next_cutoff`).
    #[serde(skip)]
    pub(crate) cutoff: Cutoff,
    pub(crate) echo: Echo,
    /// The echo's crease points and their near links (`crate::near::crease_points`), which the
    /// file lists after the texels' (the bake's own uses of the links are the texels').
    pub(crate) crease_links: Vec<NearLink>,
    pub(crate) crease_points: Vec<NearPoint>,
    pub(crate) smoothing: Option<Smoothing>,
    /// The level's rooms, kept when the walks are recorded for an update (`keep_rooms`).
    #[serde(skip)]
    pub(crate) rooms: Option<prm::rooms::Rooms>,
    /// An update's settled entries and the rooms of the level as baked.
    #[serde(skip)]
    pub(crate) untouched: Option<Untouched>,
    /// The header's level fingerprint and page texel size, and what the walks' rays meet
    /// (`prm::fingerprint::geometry_fingerprint`: a shard checks its level with it).
    pub(crate) fingerprint: String,
    pub(crate) geometry: u64,
    pub(crate) page_texel_size: f32,
    /// Entries left out inside solids, and the share of the surface no cell covers.
    pub(crate) enclosed: usize,
    pub(crate) area_without_entry: f64,
}

impl Preamble {
    /// Every phase before the walks (module doc), timed into `report`. `check` sees the
    /// entries before they are clustered (an update refuses there); `cache` gives the
    /// clusters and groups instead of k-means; `keep_rooms` keeps the level's rooms.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn build(
        scene: &Scene,
        bvh: &Bvh,
        params: &PrecomputeParams,
        cache: Option<&UpdateCache>,
        update: Option<(&Prm, &[TriangleDigest])>,
        keep_rooms: bool,
        defer_next: bool,
        check: impl FnOnce(&[Entry]) -> Result<(), PrecomputeError>,
        report: &mut Report,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        cancel: &AtomicBool,
    ) -> Result<Preamble, PrecomputeError> {
        // The texels, and beside them the level's rooms (`prm::rooms`: cells, clusters and
        // the far field keep to them), whose flood fill runs on one thread.
        let (mut texels_s, mut rooms_s) = (0.0, 0.0);
        let (set, rooms) = rayon::join(
            || {
                timed(&mut texels_s, || {
                    TexelSet::build_visible(scene, bvh, params.atlas.width(), params.atlas.height())
                })
            },
            || timed(&mut rooms_s, || prm::rooms::Rooms::of_scene(scene)),
        );
        report.seconds_texels += texels_s;
        report.seconds_clustering += rooms_s;
        // Rays that start in a closed room try its own tree first (`Bvh::localise`): on 16
        // chambers a closest hit 1.5x faster, the same answers. Here, after the texels, so
        // that every run traces the same rays with the same trees.
        timed(&mut report.seconds_clustering, || bvh.localise(scene, &rooms));
        progress(Phase::Texels, 1, 1);
        let (entries, found, (cut, owners, cell_report), enclosed) =
            timed(&mut report.seconds_entries, || lit_entries(scene, bvh, &rooms, params));
        // The map keeps the cells in triangles no longer than an entry spacing, so that the
        // runtime's fine points lie close enough together ([`Cells::split_long`]); the near
        // links integrate the same surface over the cells as cut, which is as exact and half
        // the shadow rays, and look at the pieces only of a triangle a texel sees in part.
        let (cells, piece_from) =
            cut.split_long_from(CELL_EDGE_SPACINGS * entries.first().map_or(0.0, |e| e.area.max(0.0).sqrt()));
        let albedo: Vec<Vec3> = entries.iter().map(|e| e.albedo).collect();
        let crate::cells::Reflections { stays, gains } = timed(&mut report.seconds_entries, || {
            crate::cells::reflections(scene, bvh, &cut, &owners, &albedo, params.seed, params.max_bounces)
        });
        check(&entries)?;
        progress(Phase::Entries, 1, 1);
        stop_if(cancel)?;

        // Each entry's room; one with no free voxel in front of it takes another entry's on its
        // triangle, else its neighbour's; a texel with none (on a floor a millimetre from the
        // wall, whose voxel column is the wall's) takes its cell's.
        let mut texel_room: Vec<Option<u32>> = timed(&mut report.seconds_clustering, || {
            set.texels.par_iter().map(|t| rooms.room_of(t.position, t.normal)).collect()
        });
        let side = rooms.voxel_side();
        let room = filled_rooms(&found);
        // An update takes the far field's pairs between blocks of entries the edit cannot have
        // reached, and those entries' texels' near links, from the old bake
        // (`crate::update::Untouched`).
        let untouched = match (cache, update) {
            (Some(cache), Some((old, now))) => timed(&mut report.seconds_far, || {
                let old = (old.entries(), old.cells());
                Some(Untouched::new(cache, old, now, scene, &entries, &cells, &rooms, &room))
            }),
            _ => None,
        };
        report.update_entries_settled =
            untouched.as_ref().map_or(0, |u| u.entry.iter().filter(|&&s| s).count());
        let settled = untouched.as_ref().map(|u| (u.blocks(), u.same_blocks()));
        let rooms = keep_rooms.then_some(rooms);
        for (r, t) in texel_room.iter_mut().zip(&set.texels).filter(|(r, _)| r.is_none()) {
            *r = owners.owner(t.triangle as usize, t.position).and_then(|e| room.get(e as usize).copied());
        }
        report.room_voxel = side;
        report.rooms = room.iter().collect::<std::collections::BTreeSet<_>>().len();
        let clustering = timed(&mut report.seconds_clustering, || match cache {
            Some(cache) => Clustering::from_assignment(&cache.assignment, cache.clusters),
            None => {
                let k = params.clusters as usize;
                cluster_by_room(
                    &entries,
                    &room,
                    k,
                    scene.total_area(),
                    params.kmeans_iterations as usize,
                    params.seed,
                )
            }
        });
        let cents = centroids(&entries, &clustering);
        progress(Phase::Clustering, 1, 1);
        stop_if(cancel)?;

        // The entry spacing sqrt(A / N), the unit of the near, far and smoothing reaches.
        let spacing = entries.first().map_or(0.0, |e| e.area.max(0.0).sqrt());
        // Each cell's centroid and area, once (a cell's are sums over its pieces).
        let cell: Vec<(Vec3, f32)> = (0..entries.len())
            .map(|j| (cells.centroid(j).unwrap_or(entries[j].position), cells.area(j)))
            .collect();
        let (far, far_kept) = timed(&mut report.seconds_far, || {
            if params.far_field {
                let reach = params.near_radius * spacing;
                let radius = params.far_radius * spacing;
                let reuse = match (update, &settled, &untouched) {
                    (Some((old, _)), Some((settled, same)), Some(u)) => Some(FarReuse {
                        old: old.far(),
                        settled,
                        entry: &u.entry,
                        same,
                        old_room: &u.old_room,
                        boxes: &u.boxes,
                        by_geometry: Default::default(),
                    }),
                    _ => None,
                };
                // A full precompute adds up the far field's energies while it makes the first
                // bounce (`walk_and_encode`); an update sums those of the entries it changed.
                let sum = reuse.is_some();
                let far = far_field(
                    bvh,
                    &set,
                    &entries,
                    &room,
                    &texel_room,
                    &cell,
                    reach,
                    radius,
                    reuse.as_ref(),
                    sum,
                );
                (far, reuse.map_or(0, |r| r.by_geometry.into_inner()))
            } else {
                (Far::default(), 0)
            }
        });
        report.update_far_pairs_kept = far_kept;
        // An update takes a settled texel's near and echo links from the old bake.
        // A texel keeps its links only where the old bake had the same texel at its atlas index
        // (`crate::update::same_texels`).
        let same_texel: Option<Vec<bool>> = update.map(|(old, _)| {
            crate::update::same_texels(&set.texels, set.width, &old.far().texels, old.near_points())
        });
        let settled_texels: Option<Vec<bool>> =
            untouched.as_ref().zip(same_texel.as_ref()).map(|(u, same)| {
                texel_room
                    .iter()
                    .zip(&set.texels)
                    .zip(same)
                    .map(|((&r, t), &s)| s && u.texel(t.triangle, r))
                    .collect()
            });
        let (near, near_points, near_kept) = timed(&mut report.seconds_near, || {
            if params.near_radius > 0.0 {
                let reuse = match (update, &settled_texels, &untouched) {
                    (Some((old, _)), Some(s), Some(u)) => Some(NearReuse {
                        old: old.near(),
                        settled: s,
                        same_texel: same_texel.as_deref().unwrap_or(&[]),
                        triangle: &u.triangle,
                        old_far: old.far(),
                        changed: &u.changed,
                        boxes: &u.boxes,
                        by_geometry: Default::default(),
                    }),
                    _ => None,
                };
                let (near, points) = near_links(
                    bvh,
                    &set,
                    &entries,
                    (&cut, &cells, &piece_from),
                    params.near_radius,
                    &far,
                    reuse.as_ref(),
                );
                (near, points, reuse.map_or(0, |r| r.by_geometry.into_inner()))
            } else {
                (Vec::new(), Vec::new(), 0)
            }
        });
        report.update_near_texels_kept = near_kept;
        // The links' first bounce, exact: the gather leaves it out of its first hits and the
        // panes get it back unsmoothed (`transport::LinkedCells`). Only the plain gather does
        // this (the MIS and scatter estimators walk it as before).
        let linked = params.estimator == Estimator::Gather && !near.is_empty();
        let keep = linked.then(|| linked_shares(&set, &cell, &near, &far));
        // The walks read each bounce after the first from a table of the clusters' first
        // bounce (`transport::NextBounce`); the far field's share of it joins the links' in
        // each band's exact panes as it is encoded (`Preamble::band_exact`). An update makes
        // it after its plan, for the rooms its walks can reach.
        let next_on = params.next_bounce && keep.is_some() && !far.texels.is_empty();
        let (samples, lit) = if next_on {
            timed(&mut report.seconds_far, || {
                let lit = crate::far::far_lit(&set, &far);
                (CellSamples::new(&set, &owners, &lit, entries.len()), lit)
            })
        } else {
            (CellSamples::default(), Vec::new())
        };
        // The echo links need the near links' points only; made now, so nothing of the walks
        // is held while they are.
        let echo = timed(&mut report.seconds_near, || {
            let reuse = match (update, &settled_texels, &same_texel) {
                (Some((old, _)), Some(settled), Some(same)) => {
                    Some(EchoReuse { old: old.echo(), old_points: old.near_points(), settled, same })
                }
                _ => None,
            };
            let (mut echo, creases) =
                echo_links(scene, bvh, &set, &entries, &near_points, params.echo_radius, reuse);
            let made = crease_points(
                scene,
                bvh,
                &set,
                &entries,
                (&cut, &cells, &piece_from),
                params.near_radius,
                &far,
                &near_points,
                (&mut echo, &creases),
            );
            (echo, made)
        });
        let (echo, (crease_links, crease_points)) = echo;

        let t = Instant::now();
        let smoothing =
            (params.smooth_radius > 0.0).then(|| set.smoothing(scene, params.smooth_radius * spacing));
        let grouping = match cache {
            Some(c) => (c.groups > 0).then(|| Clustering::from_assignment(&c.group_of, c.groups)),
            None => group_clusters(scene, &entries, &clustering.members, &cents, params),
        };
        report.seconds_panes += t.elapsed().as_secs_f64();
        let cutoff = Cutoff::new(clustering.members.iter().map(Vec::len), params.next_cutoff, params.seed);
        let mut pre = Preamble {
            texel_areas: if params.match_power { set.visible_areas(scene, bvh) } else { Vec::new() },
            set,
            entries,
            cells,
            stays,
            gains,
            owners,
            clustering,
            centroids: cents,
            grouping,
            far,
            near,
            near_points,
            keep,
            next: None,
            next_on,
            entry_room: room,
            samples,
            lit,
            cutoff,
            echo,
            crease_links,
            crease_points,
            smoothing,
            rooms,
            untouched,
            fingerprint: fingerprint_hex(scene, params.atlas.width(), params.atlas.height()),
            geometry: geometry_fingerprint(scene),
            page_texel_size: page_texel_size(scene),
            enclosed,
            area_without_entry: cell_report.area_without_entry / scene.total_area().max(f64::MIN_POSITIVE),
        };
        if next_on && !defer_next {
            timed(&mut report.seconds_far, || pre.make_next(None));
        }
        pre.count(report);
        Ok(pre)
    }

    /// The counts the report (and the file's header) take from the preamble.
    pub(crate) fn count(&self, report: &mut Report) {
        report.texels = self.set.len();
        report.entries_enclosed = self.enclosed;
        report.cell_triangles = self.cells.triangles.len();
        report.area_without_entry = self.area_without_entry;
        report.clusters = self.clustering.members.len() as u32;
        report.far_texels = self.far.texels.len();
        // Each pair's bit is stored both ways.
        report.far_pairs = self.far.visible.iter().map(|w| w.count_ones() as usize).sum::<usize>() / 2;
        report.near_links = self.near.len();
        report.near_links_hiding = self.near.iter().filter(|l| l.hidden != 0).count();
        report.echo_links = self.echo.links.len();
        report.crease_points = self.crease_points.len();
        report.crease_links = self.crease_links.len();
    }

    /// Each entry's cell centroid and area, as the far field reads them.
    pub(crate) fn cell(&self) -> Vec<(Vec3, f32)> {
        (0..self.entries.len())
            .map(|j| (self.cells.centroid(j).unwrap_or(self.entries[j].position), self.cells.area(j)))
            .collect()
    }

    /// The far field's first bounce for the exact panes (`crate::far::FirstBounce`): with the
    /// walks' next-bounce table only. Made once per use of [`Preamble::band_exact`]'s loop.
    pub(crate) fn first_bounce(&self) -> Option<FirstBounce<'_>> {
        if !self.next_on {
            return None;
        }
        let cell = self.cell();
        let clusters = self.clustering.members.len();
        Some(FirstBounce::new(
            &self.set,
            &self.entries,
            &cell,
            &self.far,
            &self.clustering.assignment,
            clusters,
        ))
    }

    /// The walks' next-bounce table (`transport::NextBounce`), made into `next`: every row,
    /// or with `only` (per entry) those rows alone, the others left out. Rows `next` already
    /// holds are kept, not made again.
    pub(crate) fn make_next(&mut self, only: Option<&[bool]>) {
        let Some(first) = self.first_bounce() else { return };
        let clusters = self.clustering.members.len();
        let area: Vec<f32> = (0..self.entries.len()).map(|j| self.cells.area(j)).collect();
        let exact = |k: usize| {
            exact_first_bounce(
                &self.set,
                &self.entries,
                &area,
                &self.near,
                &self.clustering.assignment,
                k..k + 1,
            )
            .pop()
            .unwrap_or_default()
        };
        let had = self.next.as_ref();
        let wanted: Option<Vec<bool>> = had.map(|had| {
            (0..self.entries.len())
                .map(|e| had.left_out(e as u32) && only.is_none_or(|o| o.get(e).copied().unwrap_or(false)))
                .collect()
        });
        let next = NextBounce::build(
            &self.set,
            &self.samples,
            &exact,
            &self.lit,
            &first,
            self.entries.len(),
            clusters,
            self.far.radius,
            wanted.as_deref().or(only),
            &self.cutoff,
        );
        drop(first);
        self.next = Some(match self.next.take() {
            Some(had) => had.merged(&next),
            None => next,
        });
    }

    /// Per entry, a digest of the inputs of its next-bounce row (`NextBounce::input_digests`;
    /// `exact` from [`Preamble::exact_digests`] with the far field's part); empty without a
    /// table.
    pub(crate) fn row_inputs(&self, exact: &[u64]) -> Vec<u64> {
        if !self.next_on {
            return Vec::new();
        }
        NextBounce::input_digests(&self.samples, exact, self.entries.len(), self.far.radius, &self.cutoff)
    }

    /// Per covered texel (set order), a digest of what [`Preamble::band_exact`] makes its exact
    /// first bounce of (with the far field's part where `first` is given): an update's tile
    /// digests (`crate::update::tile_digests`) hold these instead of the values, which cost the
    /// far field's sum over every entry in view at every texel (8 s of an update of the 16
    /// chambers).
    pub(crate) fn exact_digests(&self, first: Option<&FirstBounce>) -> Vec<u64> {
        use crate::update::{mix_floats, mix_word};
        let mut out = match first {
            Some(f) => f.input_digests(),
            None => vec![0; self.set.len()],
        };
        if self.keep.is_some() {
            // What `exact_first_bounce` reads of a linked entry.
            let entry: Vec<u64> = (0..self.entries.len())
                .map(|j| {
                    let e = &self.entries[j];
                    let h = mix_floats(mix_word(1, j as u64), &e.albedo.to_array());
                    let h = mix_floats(h, &[e.area, self.cells.area(j)]);
                    mix_word(h, u64::from(self.clustering.assignment[j]))
                })
                .collect();
            for l in &self.near {
                let k = self.set.index[l.texel as usize] as usize;
                if let Some(d) = out.get_mut(k) {
                    *d = mix_word(mix_floats(*d, &[l.factor]), entry[l.entry as usize]);
                }
            }
        }
        out
    }

    /// The exact first bounce of covered texels `range` (set order): the links', and the far
    /// field's too where `first` is given ([`Preamble::first_bounce`]), made here so that it is
    /// never held for the whole level.
    /// With `need` (an update's texels walked again) only the texels it marks get theirs;
    /// the others', which are taken from the cache, are left empty. Without it, `energy`
    /// adds up the far field's energies as the far field's part is made.
    pub(crate) fn band_exact(
        &self,
        range: std::ops::Range<usize>,
        first: Option<&FirstBounce>,
        need: Option<&[bool]>,
        energy: Option<&mut EnergySum>,
    ) -> Vec<TexelPanes> {
        let linked = self.keep.is_some();
        if !linked && first.is_none() {
            return Vec::new();
        }
        // Runs of the texels that need it (a texel's value does not depend on the run).
        let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
        for k in range.clone().filter(|&k| need.is_none_or(|n| n[k])) {
            match runs.last_mut() {
                Some(r) if r.end == k => r.end = k + 1,
                _ => runs.push(k..k + 1),
            }
        }
        let mut out: Vec<TexelPanes> = vec![Vec::new(); range.len()];
        if linked {
            let area: Vec<f32> = (0..self.entries.len()).map(|j| self.cells.area(j)).collect();
            let assignment = &self.clustering.assignment;
            for run in &runs {
                let exact =
                    exact_first_bounce(&self.set, &self.entries, &area, &self.near, assignment, run.clone());
                for (o, e) in out[run.start - range.start..].iter_mut().zip(exact) {
                    *o = e;
                }
            }
        }
        if let Some(first) = first {
            if need.is_none() {
                let texels: Vec<usize> = range.collect();
                first.add(&texels, &mut out, energy);
            } else {
                let texels: Vec<usize> = runs.iter().flat_map(|r| r.clone()).collect();
                let mut some: Vec<TexelPanes> =
                    texels.iter().map(|&k| std::mem::take(&mut out[k - range.start])).collect();
                first.add(&texels, &mut some, None);
                for (&k, e) in texels.iter().zip(some) {
                    out[k - range.start] = e;
                }
            }
        }
        out
    }

    /// The near links with the share of their first bounce the walks keep (None: the walks
    /// keep all of it).
    pub(crate) fn linked(&self) -> Option<LinkedCells<'_>> {
        self.keep.as_ref().map(|keep| LinkedCells { links: &self.near, keep })
    }

    /// The walks' estimator over this preamble.
    pub(crate) fn transport<'a>(
        &'a self,
        scene: &'a Scene,
        bvh: &'a Bvh,
        linked: Option<&'a LinkedCells<'a>>,
        params: &PrecomputeParams,
    ) -> Transport<'a> {
        Transport {
            scene,
            bvh,
            entries: &self.entries,
            owners: &self.owners,
            linked,
            next: self.next.as_ref(),
            assignment: &self.clustering.assignment,
            clusters: self.clustering.members.len(),
            paths: params.paths,
            max_bounces: params.max_bounces,
            seed: params.seed,
            stats: Default::default(),
        }
    }
}

/// Per link, the share of its cell's first bounce the gather's walks keep: the far field's
/// share where it lights the texel (what the link's fade leaves to it), else none.
fn linked_shares(set: &TexelSet, cell: &[(Vec3, f32)], near: &[NearLink], far: &Far) -> Vec<f32> {
    near.par_iter()
        .map(|l| {
            let (centroid, area) = cell[l.entry as usize];
            let fades = far.texels.binary_search_by_key(&l.texel, |f| f.texel).is_ok();
            let d = centroid.distance(set.texels[set.index[l.texel as usize] as usize].position);
            if fades {
                far_share(d, far.reach, area.sqrt())
            } else {
                0.0
            }
        })
        .collect()
}

/// Per covered texel of `range` (set order), what the links left out of the walks add to each
/// cluster's pane: per unit of cluster irradiance, cell j (its area `area[j]`) takes `t_j` of
/// it (its area over A/N), which its link turns into `albedo_j factor t_j` at the texel;
/// exactly what the runtime's near field takes back from `w_c`
/// (`prm_runtime::cpu::near_field`). Made where it is needed (a band, a table chunk) rather
/// than held for the whole level: on the 16 chambers that was 48 MB.
fn exact_first_bounce(
    set: &TexelSet,
    entries: &[Entry],
    area: &[f32],
    links: &[NearLink],
    assignment: &[u32],
    range: std::ops::Range<usize>,
) -> Vec<TexelPanes> {
    // The links are sorted by atlas texel, as the covered texels are: a range's are one run.
    let atlas = |k: usize| set.texels.get(k).map_or(u32::MAX, |t| t.j * set.width + t.i);
    let (from, to) = (atlas(range.start), atlas(range.end));
    let run = links.partition_point(|l| l.texel < from)..links.partition_point(|l| l.texel < to);
    let mut out: Vec<TexelPanes> = vec![Vec::new(); range.len()];
    for l in &links[run] {
        let j = l.entry as usize;
        let e = &entries[j];
        let t = if e.area > 0.0 { area[j] / e.area } else { 0.0 };
        let (k, c) = (set.index[l.texel as usize] as usize - range.start, assignment[j]);
        let v = e.albedo * (l.factor * t);
        match out[k].iter_mut().find(|(x, _)| *x == c) {
            Some(slot) => slot.1 += v,
            None => out[k].push((c, v)),
        }
    }
    for tp in &mut out {
        tp.sort_by_key(|&(c, _)| c);
    }
    out
}

/// `f()`, with its run time in seconds added to `seconds`.
fn timed<T>(seconds: &mut f64, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let out = f();
    *seconds += t.elapsed().as_secs_f64();
    out
}

/// [`lit_entries`]' result: the kept entries, their rooms, their cells, and how many were left out.
type LitEntries = (Vec<Entry>, Vec<Option<u32>>, (Cells, CellOwners, CellReport), usize);

/// The entry points with their rooms (`cells::entry_rooms`) and cells. An entry inside a solid moves to a point of its
/// triangle outside it, or is left out (how many are is the last value): it would never see
/// light, and in a cluster's mean it would only dim it.
fn lit_entries(scene: &Scene, bvh: &Bvh, rooms: &prm::rooms::Rooms, params: &PrecomputeParams) -> LitEntries {
    let first = sample_entries(scene, params.entries as usize, params.seed);
    let sampled: Vec<Option<Entry>> = first
        .par_iter()
        .enumerate()
        .map(|(j, e)| {
            let (seed, j) = (params.seed, j as u64);
            if is_enclosed(scene, bvh, e, seed, j) {
                relocate(scene, bvh, e, seed, j)
            } else {
                Some(*e)
            }
        })
        .collect();
    let keep: Vec<bool> = sampled.iter().map(Option::is_some).collect();
    // A left-out entry keeps its first point: it takes no cell.
    let placed: Vec<Entry> = sampled.iter().zip(&first).map(|(e, f)| e.unwrap_or(*f)).collect();
    let entries: Vec<Entry> = sampled.iter().flatten().copied().collect();
    // The kept entries' rooms, once: the cells' (by sampled index, none for a left-out entry)
    // and the clusters' and far field's.
    let room = entry_rooms(rooms, &entries);
    let mut kept = room.iter();
    let placed_room: Vec<Option<u32>> =
        keep.iter().map(|&k| if k { kept.next().copied().flatten() } else { None }).collect();
    let cells = entry_cells_in_rooms(scene, &placed, &keep, Some((rooms, &placed_room)));
    let enclosed = sampled.len() - entries.len();
    // Faces no entry reached get one of their own, and the cells are cut again with them.
    let spacing = entries.first().map_or(0.0, |e| e.area.max(0.0).sqrt());
    let added = entries_for_faces_left_out(scene, &cells.1, spacing, entries.first().map_or(0.0, |e| e.area));
    if added.is_empty() {
        return (entries, room, cells, enclosed);
    }
    let mut placed = placed;
    let mut keep = keep;
    let mut entries = entries;
    placed.extend_from_slice(&added);
    keep.extend(std::iter::repeat_n(true, added.len()));
    entries.extend_from_slice(&added);
    let room = entry_rooms(rooms, &entries);
    let mut kept = room.iter();
    let placed_room: Vec<Option<u32>> =
        keep.iter().map(|&k| if k { kept.next().copied().flatten() } else { None }).collect();
    let cells = entry_cells_in_rooms(scene, &placed, &keep, Some((rooms, &placed_room)));
    (entries, room, cells, enclosed)
}

/// What share of an entry's area a face no entry reached must have to get an entry of its own.
const LEFT_OUT_SHARE: f32 = 0.25;

/// The longest edge a cell triangle keeps in the map, in entry spacings
/// ([`Cells::split_long`]). Measured on the chamber (one seed, all panes, 512-sample ground
/// truths, noise removed): the torch 15 cm from a corner 7.2 -> 5.4 %, the other torch frames
/// the same to 0.1 point; its cells 23,418 -> 46,070 triangles, its file 23.8 -> 24.7 MB. On 16
/// sunlit rooms at a low sun: 31.4 -> 22.4 %. Half a spacing cut the chamber's triangles six
/// times over for nothing more.
const CELL_EDGE_SPACINGS: f32 = 1.0;

/// An entry for each face the cells left out ([`CellOwners::owner`] none): a triangle of at
/// least [`LEFT_OUT_SHARE`] of an entry's area (`area`), at its centroid, largest first, unless
/// one already added faces its way within a spacing (the other half of its quad: that one's
/// cell takes it across their shared edge). Such a face has no entry of its own and no entry
/// of its surface near it: a window sill between its jambs, whose sunlight was lost (a row of
/// sunlit rooms at the default density: the rooms whose sill got no entry had 0.68-0.8 of the
/// indirect light of the others). Joining it to an entry of another surface would credit its
/// light to that surface's cluster (a plinth top to the floor beside it: `crate::cells`).
fn entries_for_faces_left_out(scene: &Scene, owners: &CellOwners, spacing: f32, area: f32) -> Vec<Entry> {
    if !(spacing > 0.0 && area > 0.0) {
        return Vec::new();
    }
    let centroid = |t: usize| scene.corners(t).iter().sum::<Vec3>() / 3.0;
    let mut left: Vec<(usize, f32)> = (0..scene.triangles.len())
        .filter(|&t| scene.area(t) >= LEFT_OUT_SHARE * area && owners.owner(t, centroid(t)).is_none())
        .map(|t| (t, scene.area(t)))
        .collect();
    left.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut added: Vec<Entry> = Vec::new();
    for (t, _) in left {
        let (p, n) = (centroid(t), scene.face_normal(t));
        if added.iter().any(|e| e.normal.dot(n) >= 0.7 && e.position.distance(p) <= spacing) {
            continue;
        }
        let third = Vec3::splat(1.0 / 3.0);
        added.push(Entry {
            position: p,
            normal: n,
            albedo: scene.albedo(t, third),
            area,
            triangle: t as u32,
        });
    }
    added
}

/// The texel size the level's generated UVs were packed at in pages (how it loads again with
/// the same UVs; a level whose charts packed worse than the density estimated may fill only
/// one), else 0.
fn page_texel_size(scene: &Scene) -> f32 {
    match scene.report.generated_layout {
        Some(UnwrapLayout::Pages { texel_size, .. }) => texel_size,
        _ => 0.0,
    }
}

/// Groups the clusters (k-means on centroid and mean normal, area-weighted like the entries):
/// each group's pane is the sum of its clusters' contributions, smoothed, dilated and tiled
/// like theirs (`walk_and_encode`). None without groups.
fn group_clusters(
    scene: &Scene,
    entries: &[Entry],
    members: &[Vec<u32>],
    cents: &[Vec3],
    params: &PrecomputeParams,
) -> Option<Clustering> {
    let c = members.len();
    if params.groups == 0 || c < 2 {
        return None;
    }
    let pseudo: Vec<Entry> = members
        .iter()
        .zip(cents)
        .map(|(m, &position)| {
            let area: f32 = m.iter().map(|&e| entries[e as usize].area).sum();
            let normal = m
                .iter()
                .fold(Vec3::ZERO, |a, &e| a + entries[e as usize].normal * entries[e as usize].area)
                .normalize_or_zero();
            Entry { position, normal, albedo: Vec3::ZERO, area, triangle: 0 }
        })
        .collect();
    Some(cluster_entries(
        &pseudo,
        (params.groups as usize).min(c),
        scene.total_area(),
        params.kmeans_iterations as usize,
        params.seed ^ 0x6772_6f75_7073,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parallel::Control;

    /// Two sealed unit rooms side by side (the second 2 m along x), grey 0.6, built and loaded
    /// as the bundled levels are (`crate::scenes::Builder`, lightmap UVs at 128²).
    fn two_rooms() -> Scene {
        let mut b = crate::scenes::Builder::default();
        let grey = b.material("grey", [0.6, 0.6, 0.6]);
        for x in [0.0, 2.0] {
            b.boxed(grey, Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0), true, &[]);
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("two_rooms.glb");
        std::fs::write(&path, b.finish(128).unwrap().to_glb()).unwrap();
        prm::gltf_load::load_scene(&path, &Default::default()).unwrap()
    }

    /// A 3 m room with a 1 x 0.6 m shelf on a wall (up-facing, 1.5 m up, no edge shared with
    /// the wall): at 64 entries (0.86 m² each) sampling often gives the shelf none, and no
    /// entry of its own surface is near (the floor is 1.5 m below). It gets one of its own, so
    /// its light is kept: every face of a quarter of an entry's area is in a cell.
    #[test]
    fn a_face_no_entry_reached_gets_one_of_its_own() {
        let mut b = crate::scenes::Builder::default();
        let grey = b.material("grey", [0.6, 0.6, 0.6]);
        b.boxed(grey, Vec3::ZERO, Vec3::splat(3.0), true, &[]);
        let v = Vec3::new;
        b.quad(grey, v(1.0, 1.5, 3.0), v(2.0, 1.5, 3.0), v(2.0, 1.5, 2.4), v(1.0, 1.5, 2.4));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shelf.glb");
        std::fs::write(&path, b.finish(64).unwrap().to_glb()).unwrap();
        let scene = prm::gltf_load::load_scene(&path, &Default::default()).unwrap();
        let bvh = Bvh::build(&scene);
        let rooms = prm::rooms::Rooms::of_scene(&scene);
        let on_shelf = |p: Vec3| (p.y - 1.5).abs() < 1e-4 && p.z > 2.39;
        let shelf: Vec<usize> =
            (0..scene.triangles.len()).filter(|&t| scene.corners(t).iter().all(|&c| on_shelf(c))).collect();
        assert_eq!(shelf.len(), 2);
        let mut without = 0;
        for seed in 0..12 {
            let params = PrecomputeParams { entries: 64, seed, ..PrecomputeParams::production() };
            let sampled = sample_entries(&scene, 64, seed);
            let (entries, _, (cells, owners, report), _) = lit_entries(&scene, &bvh, &rooms, &params);
            if !sampled.iter().any(|e| on_shelf(e.position)) {
                without += 1;
                // One entry was added, on the shelf.
                assert_eq!(entries.len(), sampled.len() + 1, "seed {seed}");
                assert!(on_shelf(entries[entries.len() - 1].position), "seed {seed}");
            }
            for &t in &shelf {
                let c = scene.corners(t).iter().sum::<Vec3>() / 3.0;
                let owner =
                    owners.owner(t, c).unwrap_or_else(|| panic!("seed {seed}: shelf triangle {t} left out"));
                assert!(
                    on_shelf(entries[owner as usize].position),
                    "seed {seed}: shelf in another surface's cell"
                );
            }
            let covered: f64 = (0..entries.len()).map(|k| cells.area(k) as f64).sum();
            assert!(report.area_without_entry == 0.0, "seed {seed}: {} left out", report.area_without_entry);
            assert!((covered / scene.total_area() - 1.0).abs() < 1e-4, "seed {seed}: {covered}");
        }
        assert!(without > 0 && without < 12, "{without} of 12 seeds left the shelf without an entry");
    }

    /// An update's table with the first room's rows only (`Preamble::make_next` with `only`):
    /// those rows are the whole table's to the bit, the second room's are empty and said to be
    /// left out; the first room's texels walk as with the whole table and meet no row left out,
    /// while the second room's walks meet them and count it (an update then refuses). The
    /// second room's rows made afterwards complete it into the whole table.
    #[test]
    fn rows_left_out_of_the_table_are_empty_and_counted_where_walks_meet_them() {
        let scene = two_rooms();
        let bvh = Bvh::build(&scene);
        let params = PrecomputeParams {
            entries: 256,
            paths: 8,
            clusters: 16,
            groups: 0,
            atlas: prm::density::Atlas::single(128),
            ..PrecomputeParams::production()
        };
        let build = |defer: bool| {
            let mut report = Report::default();
            Preamble::build(
                &scene,
                &bvh,
                &params,
                None,
                None,
                false,
                defer,
                |_| Ok(()),
                &mut report,
                &|_, _, _| {},
                &AtomicBool::new(false),
            )
            .unwrap()
        };
        let whole = build(false);
        let mut part = build(true);
        assert!(part.next_on && part.next.is_none(), "the table waits for the update's plan");
        let first_room = part.entry_room[part.entries.iter().position(|e| e.position.x < 1.5).unwrap()];
        let only: Vec<bool> = part.entry_room.iter().map(|&r| r == first_room).collect();
        let made = only.iter().filter(|&&o| o).count();
        assert!(made > 0 && made < only.len(), "{made} of {} entries in the first room", only.len());
        part.make_next(Some(&only));
        let (w, p) = (whole.next.as_ref().unwrap(), part.next.as_ref().unwrap());
        let mut rows = 0;
        for (e, &o) in only.iter().enumerate() {
            let e = e as u32;
            match (o, w.row(e), p.row(e)) {
                (true, Some(a), Some(b)) => {
                    assert_eq!((a.cluster, a.value, a.unit), (b.cluster, b.value, b.unit), "entry {e}");
                    rows += 1;
                }
                (true, None, None) => {}
                (true, a, b) => {
                    panic!("entry {e}: {} in the whole table, {} in the part", a.is_some(), b.is_some())
                }
                (false, _, b) => assert!(b.is_none() && p.left_out(e), "entry {e} is not left out"),
            }
            assert!(!w.left_out(e), "the whole table left out entry {e}");
        }
        assert!(rows > made / 2, "{rows} rows of {made} entries");
        let walk = |pre: &Preamble, room: bool| {
            let texels: Vec<prm::Texel> =
                pre.set.texels.iter().filter(|t| (t.position.x < 1.5) == room).copied().collect();
            let linked = pre.linked();
            let transport = pre.transport(&scene, &bvh, linked.as_ref(), &params);
            let prepared = transport.prepare(Estimator::Gather);
            let out = transport.run_texels(&prepared, &texels, pre.set.width, Control::none()).unwrap();
            let met = transport.stats.rows_left_out.load(std::sync::atomic::Ordering::Relaxed);
            (out, met)
        };
        let (a, met_whole) = walk(&whole, true);
        let (b, met_first) = walk(&part, true);
        assert_eq!((met_whole, met_first), (0, 0));
        assert!(a == b, "the first room's walks differ with its rows alone");
        let (_, met_second) = walk(&part, false);
        assert!(met_second > 0, "the second room's walks met none of its rows left out");
        // The rest made later joins the rows made first: the whole table, to the bit.
        part.make_next(None);
        assert!(part.next == whole.next, "the table made in two parts is not the whole one");
    }
}
