//! The slow, obvious compose (DESIGN.md §5 steps 2-4 after the entry irradiance): cluster
//! weights, top-K selection, residual group weights and the weighted sum of panes, on the CPU.
//! The GPU passes (`weights.wgsl`, `compose.wgsl`) are held to these functions by the tests.

use glam::Vec3;
use prm::luminance;
use prm::prm_file::{far_share, Prm, TileLayout};

use super::concentrate::LinkLight;

/// Cluster weights from per-entry irradiance: the mean irradiance `m_c` over the cluster's
/// cells, less the share the near field already delivers.
///
/// An entry's irradiance `E_j` is its cell's power over A/N (`crate::cpu::entry_irradiance`), so
/// the cells' power over their area is `m_c = sum_j E_j / sum_j t_j`, with `t_j` = the cell's
/// area over A/N ([`NearTables`]). That, not the plain mean of the `E_j`, is what a pane asks
/// for: the gather estimator credits a walk to the cluster whose region it lands in, so a pane
/// is the answer to unit irradiance over the region, whatever its area (measured: the plain
/// mean left cornell's indirect light 1.9 % high, this -0.4 %).
///
/// Each entry's light counts in that mean by its stay share `s_j` (`prm::prm_file::Prm::stay`):
/// `m_c = sum_j s_j E_j / sum_j s_j t_j` (the plain form where every share is 1, as in a closed
/// level, or where all are 0). A pane answers even light over its cluster; a window's jamb,
/// half of whose light leaves through the opening, lit in a cluster with the wall inside,
/// sends the room about half what the same light on the wall would, and the weight must say
/// so (16 sunrooms at a low sun: every room 3-41 % too bright with the plain mean). And, in
/// each channel, by its albedo `rho_j`: `m_c = sum_j s_j rho_j E_j / sum_j s_j rho_j t_j`
/// ([`NearTables::reflect`]), so the light the cluster's cells reflect is what its pane sends
/// on, colour and all. A spot on the chamber's red carpet (albedo 0.6, 0.1, 0.08), in clusters
/// with the grey floor beside it, lit the room as if the floor had taken the light: 15.9 %
/// from the ground truth, green and blue 24 % and 22 % high; 6.1 % by albedo (bias +14.6 ->
/// +1.9 %). A channel no member reflects falls back to the plain mean.
///
/// Since `.prm` v14 the stay share's place is taken by the entry's bounce gain `g_j`
/// (`prm::prm_file::Prm::gain`: the light that lands over every bounce per unit the cell
/// reflects, the stay share its first term): `m_c = sum_j g_j rho_j E_j / sum_j g_j rho_j t_j`.
/// Under even light the pane's total is the sum of its cells' `g_j rho_j t_j`, so weighted so
/// the mean carries what the lit cells' light does over all its bounces, not what the
/// cluster's average cell's would (`docs/near-lights.md`, *Bounce gains*).
///
/// The near field ([`near_field`]) adds `sum_j (E_j - w_c t_j) near_j` of energy over the
/// texels (`near_j`: entry j's links' energy per unit weight); nothing makes that zero (a hot
/// entry on a floor has no links to its coplanar floor, its colder neighbours by a wall do). So
/// `w_c` is chosen to keep the cluster's energy, panes plus near field, at `m_c energy_c`:
/// `w_c = (m_c energy_c - sum_j E_j near_j) / (energy_c - sum_j t_j near_j)`, the denominator
/// kept at >= 0.1 energy_c and `w_c` at >= 0. Those energies are counted in luminance; in
/// each channel, `near_j` is tinted by entry j's albedo and `energy_c` by the cluster's
/// ([`NearTables::tint`]): a red entry's links deliver its red, and the balance
/// took them at its luminance, so a spot on the red runner of a closed box left the room
/// +32 % too red and green and blue -12 and -19 % (tinted: +11, +6, +7 %, where a grey runner
/// gives +4 % in every channel). Without links, `m_c`. A hot entry's links count at `E_j
/// near_j` too, the power its cell reflects, though the texels a few cm from a near light's
/// spot read its peak and sum to more (cell 813 by the chamber's corner spot: 382 against 123):
/// counted at what they read, the balance took that excess from the corner's panes, and with
/// it the whole room's later bounces (the room 8 m from that spot 18 % dark, its bias -8.3 %;
/// the measurements under [`near_deviation`]). The far
/// field ([`far_field`]) carries the rest of the deviation's first bounce, so `near_j` counts
/// its energy too (`prm::prm_file::Far::energy`): left out, its light came on top of panes
/// that already held all of it (a lamp 1 cm over a closed box's floor: 1.06 of the power's
/// indirect light, 1.01 with it counted).
pub fn cluster_weights(prm: &Prm, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
    cluster_weights_with(prm, &NearTables::new(prm), entry_irradiance)
}

/// [`cluster_weights`] with the map's [`NearTables`] built once (per frame they are the
/// same).
pub fn cluster_weights_with(prm: &Prm, tables: &NearTables, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
    prm.clusters()
        .iter()
        .map(|c| {
            if c.members.is_empty() {
                return Vec3::ZERO;
            }
            let (mut sum, mut near_sum, mut near_total) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
            let (mut stay_sum, mut stay_t, mut t_sum) = (Vec3::ZERO, Vec3::ZERO, 0.0f32);
            for &m in &c.members {
                let (e, m) = (entry_irradiance[m as usize], m as usize);
                let tint = tables.tint[m];
                sum += e;
                stay_sum += e * tables.reflect[m];
                stay_t += tables.area_ratio[m] * tables.reflect[m];
                t_sum += tables.area_ratio[m];
                near_sum += tint * (e * tables.energy[m]);
                near_total += tint * (tables.energy[m] * tables.area_ratio[m]);
            }
            let plain = if t_sum > 0.0 { sum / t_sum } else { Vec3::ZERO };
            let counted = stay_sum / stay_t.max(Vec3::splat(f32::MIN_POSITIVE));
            let w = Vec3::select(stay_t.cmpgt(Vec3::ZERO), counted, plain);
            // The pane's energy in each channel: its luminance's, tinted by the cluster's albedo.
            // A channel the cluster reflects none of keeps its weight: its pane carries none.
            let energy = c.energy * tint_of(stay_t);
            if near_total.max_element() > 0.0 && c.energy > 0.0 {
                let balanced = (w * energy - near_sum) / (energy - near_total).max(0.1 * energy);
                Vec3::select(energy.cmpgt(Vec3::ZERO), balanced.max(Vec3::ZERO), w)
            } else {
                w
            }
        })
        .collect()
}

/// A colour over its luminance: what each channel carries where that luminance carries 1 (grey
/// for black).
pub fn tint_of(colour: Vec3) -> Vec3 {
    let l = luminance(colour);
    if l > 0.0 {
        colour / l
    } else {
        Vec3::ONE
    }
}

/// Per-entry tables of the near field, built once per map.
pub struct NearTables {
    /// The cluster of each entry.
    pub cluster: Vec<u32>,
    /// Each entry's stay share (`Prm::stay`): how its light counts in the far field's bar.
    pub stay: Vec<f32>,
    /// Each entry's bounce gain times its albedo, `g_j rho_j`: how its light counts in its
    /// cluster's mean, channel by channel ([`cluster_weights`]).
    pub reflect: Vec<Vec3>,
    /// The entry's albedo over its luminance (grey where it is 0): its links' and far field's
    /// energy ([`Self::energy`], counted in luminance) in each channel, as the weights pass
    /// takes it. Those carry the first bounce (and its echo), whose colour is the albedo's, not
    /// the gain's, which counts every later bounce of the room too.
    pub tint: Vec<Vec3>,
    /// `t_j`: the entry's cell area over its share A/N. Under even irradiance E an entry's
    /// weight is `E t_j`, so `E_j - w_c t_j` is zero there: the near field answers only to
    /// light that is uneven over the cluster.
    pub area_ratio: Vec<f32>,
    /// The energy the entry's links (with their echo) and its far field deliver per unit
    /// deviation: `sum over its links of luminance(albedo) x factor x echo gain` plus
    /// `Far::energy`, in the units of a pane's energy (summed over texels).
    pub energy: Vec<f32>,
    /// The centroid of the entry's cell.
    pub centroid: Vec<Vec3>,
    /// The size of the entry's cell: the square root of its area.
    pub size: Vec<f32>,
    /// Per entry, the texels that stand for its cell, where [`lift_weights`] and
    /// [`near_deviation`] read the near field ([`cell_means`]): the far texels whose nearest
    /// entry it is, in the far field's order, entry j's at `cell_texels[cell_first[j] as
    /// usize..cell_first[j + 1] as usize]` as atlas texels (none for an entry no far texel is
    /// nearest to, and for every entry of a map without a far field).
    pub cell_first: Vec<u32>,
    pub cell_texels: Vec<u32>,
    /// The area (scene units²) of each texel of `cell_texels` (`prm::prm_file::Far::areas`;
    /// empty for a map before v17): where [`lift_weights`] sums the near field's power.
    pub cell_areas: Vec<f32>,
    /// Per cluster, `P_c`: the power its pane sends to the level over every bounce per unit
    /// weight, `sum_j (A/N)_j t_j g_j rho_j` over its members, channel by channel (the pane's
    /// luminance is matched to it in the bake: `prm_precompute::precompute::match_power`).
    pub power: Vec<Vec3>,
    /// Per near point, the entry whose cell its echo's source reading is measured against
    /// (`u32::MAX`: none): a texel's point the entry nearest its texel
    /// ([`NearTables::cell_texels`]), a crease point its texel's ([`echo_input`]).
    pub point_cell: Vec<u32>,
    /// Per entry, the near points of texels of its cell, entry j's at `cell_points[
    /// cell_point_first[j] as usize..cell_point_first[j + 1] as usize]`: whose expected first
    /// bounce [`echo_input`] averages.
    pub cell_point_first: Vec<u32>,
    pub cell_points: Vec<u32>,
    /// Per cluster, its albedo's tint, `tint_of` `sum_j t_j g_j rho_j` over its members: its
    /// pane's energy in each channel where its luminance's is 1 ([`cluster_weights`],
    /// [`lift_weights`]).
    pub cluster_tint: Vec<Vec3>,
    /// Per cluster, its room ([`super::rooms`]): [`lift_weights`] keeps the energy room by
    /// room.
    pub cluster_room: Vec<u32>,
    /// Rooms (at least 1).
    pub rooms: usize,
}

/// Per entry, the far texels whose nearest entry it is (the far field's neighbours are sorted
/// nearest first): [`NearTables::cell_first`] and [`NearTables::cell_texels`], as atlas
/// texels.
fn cell_texels(prm: &Prm) -> (Vec<u32>, Vec<u32>, Vec<f32>) {
    let n = prm.entries().len();
    let (texels, areas) = (&prm.far().texels, &prm.far().areas);
    let mut first = vec![0u32; n + 1];
    for t in texels.iter().filter(|t| (t.entries[0] as usize) < n) {
        first[t.entries[0] as usize + 1] += 1;
    }
    for j in 0..n {
        first[j + 1] += first[j];
    }
    let mut next = first.clone();
    let mut list = vec![0u32; first[n] as usize];
    let mut list_areas = if areas.is_empty() { Vec::new() } else { vec![0.0f32; first[n] as usize] };
    for (k, t) in texels.iter().enumerate().filter(|(_, t)| (t.entries[0] as usize) < n) {
        let slot = &mut next[t.entries[0] as usize];
        list[*slot as usize] = t.texel;
        if let (Some(a), Some(&area)) = (list_areas.get_mut(*slot as usize), areas.get(k)) {
            *a = area;
        }
        *slot += 1;
    }
    (first, list, list_areas)
}

/// [`NearTables::point_cell`], [`NearTables::cell_point_first`] and
/// [`NearTables::cell_points`] from the cell texels `cell_first` / `cell_texels`: each near
/// point's cell (its texel's; a crease point's texel's), and per entry the points of texels
/// (not crease points) in its cell.
fn point_cells_in(prm: &Prm, cell_first: &[u32], cell_texels: &[u32]) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let n = cell_first.len().saturating_sub(1);
    let mut entry_of = vec![u32::MAX; prm.texel_count()];
    for j in 0..n {
        for &t in &cell_texels[cell_first[j] as usize..cell_first[j + 1] as usize] {
            if let Some(e) = entry_of.get_mut(t as usize) {
                *e = j as u32;
            }
        }
    }
    let points: Vec<u32> = prm.near().chunk_by(|a, b| a.texel == b.texel).map(|run| run[0].texel).collect();
    let echo = prm.echo();
    let first_crease = echo.first_crease(points.len());
    let point_cell: Vec<u32> = (0..points.len())
        .map(|x| entry_of.get(points[echo.echo_of(x, points.len())] as usize).copied().unwrap_or(u32::MAX))
        .collect();
    let mut first = vec![0u32; n + 1];
    for &c in point_cell[..first_crease].iter().filter(|&&c| (c as usize) < n) {
        first[c as usize + 1] += 1;
    }
    for j in 0..n {
        first[j + 1] += first[j];
    }
    let mut next = first.clone();
    let mut list = vec![0u32; first[n] as usize];
    for (x, &c) in point_cell[..first_crease].iter().enumerate().filter(|&(_, &c)| (c as usize) < n) {
        let slot = &mut next[c as usize];
        list[*slot as usize] = x as u32;
        *slot += 1;
    }
    (point_cell, first, list)
}

/// Each near point's cell ([`NearTables::point_cell`]), without the rest of the tables.
pub fn point_cells(prm: &Prm) -> Vec<u32> {
    let (cell_first, cell_texels, _) = cell_texels(prm);
    point_cells_in(prm, &cell_first, &cell_texels).0
}

/// Per entry, the mean of `field` (per atlas texel) over the texels of its cell
/// ([`NearTables::cell_texels`]), None for an entry without any: what [`lift_weights`] and
/// [`near_deviation`] take as the near field on the cell. Next to a light near a surface the
/// near field changes across a cell much faster than the cell: one texel (the far texel
/// nearest the entry) read the peak of the first bounce rather than the cell's share (the
/// chamber's corner spot lifted a side wall's cluster to 1.9x its balanced weight).
pub fn cell_means(tables: &NearTables, field: &[Vec3]) -> Vec<Option<Vec3>> {
    run_means(&tables.cell_first, &tables.cell_texels, field)
}

/// Per run `list[first[j]..first[j + 1]]`, the mean of `field` over the indices it lists,
/// None for an empty run.
fn run_means(first: &[u32], list: &[u32], field: &[Vec3]) -> Vec<Option<Vec3>> {
    first
        .windows(2)
        .map(|w| {
            let run = &list[w[0] as usize..w[1] as usize];
            (!run.is_empty()).then(|| run.iter().map(|&k| field[k as usize]).sum::<Vec3>() / run.len() as f32)
        })
        .collect()
}

impl NearTables {
    pub fn new(prm: &Prm) -> NearTables {
        let n = prm.entries().len();
        let (mut cluster, mut area_ratio) = (vec![0u32; n], vec![0.0f32; n]);
        let cells = prm.cells();
        let (cell_first, cell_texels, cell_areas) = cell_texels(prm);
        let (point_cell, cell_point_first, cell_points) = point_cells_in(prm, &cell_first, &cell_texels);
        for (c, cl) in prm.clusters().iter().enumerate() {
            for &m in &cl.members {
                cluster[m as usize] = c as u32;
                let a = prm.entries()[m as usize].area;
                area_ratio[m as usize] = if a > 0.0 { cells.area(m as usize) / a } else { 0.0 };
            }
        }
        let mut energy = prm.link_energy();
        // The far field carries the rest of the deviation's first bounce.
        for (j, e) in energy.iter_mut().enumerate() {
            *e += prm.far().energy.get(j).copied().unwrap_or(0.0);
        }
        let centroid: Vec<Vec3> =
            (0..n).map(|j| cells.centroid(j).unwrap_or(prm.entries()[j].position)).collect();
        let size = (0..n).map(|j| cells.area(j).sqrt()).collect();
        let cluster_room = super::rooms::cluster_rooms(prm);
        let reflect: Vec<Vec3> = (0..n).map(|j| prm.gain(j) * prm.entries()[j].albedo).collect();
        // As the balance sums it (`cluster_weights_with`'s `stay_t`).
        let cluster_tint = prm
            .clusters()
            .iter()
            .map(|c| {
                let mut sum = Vec3::ZERO;
                for &m in &c.members {
                    sum += area_ratio[m as usize] * reflect[m as usize];
                }
                tint_of(sum)
            })
            .collect();
        let power = cluster_power(prm, &area_ratio, &reflect);
        NearTables {
            cluster,
            stay: (0..n).map(|j| prm.stay(j)).collect(),
            tint: prm.entries().iter().map(|e| tint_of(e.albedo)).collect(),
            reflect,
            area_ratio,
            energy,
            centroid,
            size,
            point_cell,
            cell_point_first,
            cell_points,
            cell_first,
            cell_texels,
            cell_areas,
            power,
            cluster_tint,
            rooms: super::rooms::room_count(&cluster_room),
            cluster_room,
        }
    }
}

/// [`NearTables::power`].
fn cluster_power(prm: &Prm, area_ratio: &[f32], reflect: &[Vec3]) -> Vec<Vec3> {
    prm.clusters()
        .iter()
        .map(|c| {
            c.members
                .iter()
                .map(|&m| prm.entries()[m as usize].area * area_ratio[m as usize] * reflect[m as usize])
                .sum()
        })
        .collect()
}

/// Bounces of the near field's echo the runtime applies (the second and the third).
pub const ECHO_BOUNCES: usize = 2;

/// What the echo's first bounce reads at each near point (its source): the links' light less
/// the mean, over the texels of the point's cell, of what the panes expected of their links
/// (`near` + `expected` - that mean; a point without a cell reads `near`).
///
/// The echo adds the near field's next bounce the panes missed: at receiver x, through source
/// point s, what x sees of s's light less what x's pane gave it. A walk from x that lands by s
/// takes the next bounce from the table row of s's cell (`prm_precompute::transport::next`),
/// made as the mean of the first bounce over a few of the cell's texels, so the pane's light
/// there is the cell's mean, not s's own expectation. The two differ where the first bounce
/// ramps up across the cell: at a crease point a centimetre from a wall that its links see at
/// a form factor near 1/2 (against the cell's mean, a few times less), the echo took that
/// point's expectation off, several times what the pane had. The window's lintel at dusk in
/// the sunroom read -0.66 W/m² of echo against 0.47 of panes at the jamb below it (truth
/// 0.63); with the cell's mean, 0.29.
pub fn echo_input(tables: &NearTables, near: &[Vec3], expected: &[Vec3]) -> Vec<Vec3> {
    let means = run_means(&tables.cell_point_first, &tables.cell_points, expected);
    near.iter()
        .zip(expected)
        .zip(&tables.point_cell)
        .map(|((&d, &e), &c)| match means.get(c as usize).copied().flatten() {
            Some(mean) => d + e - mean,
            None => d,
        })
        .collect()
}

/// One bounce of the echo: per near point, `sum over its links of factor x albedo(source) x
/// from(source)`.
pub fn echo_bounce(prm: &Prm, from: &[Vec3]) -> Vec<Vec3> {
    let echo = prm.echo();
    let mut out = vec![Vec3::ZERO; from.len()];
    for l in &echo.links {
        let x = l.source as usize;
        out[l.receiver as usize] += echo.albedo[x] * from[x] * l.factor;
    }
    // A crease point receives no echo: its bounce is its texel's, which the next bounce
    // passes on from it (`prm::prm_file::Echo::creases`).
    let points = out.len();
    for x in echo.first_crease(points)..points {
        out[x] = out[echo.echo_of(x, points)];
    }
    out
}

/// Indices of the (at most) `k` clusters with the largest `|luminance(weight)| x energy`,
/// strongest first (a weight the lift made negative takes light back, and ranks by how much);
/// zero-weight clusters are left out. Ties go to the lower index.
pub fn select_top_k(weights: &[Vec3], energies: &[f32], k: usize) -> Vec<usize> {
    let mut scored: Vec<(f32, usize)> = weights
        .iter()
        .zip(energies)
        .enumerate()
        .map(|(c, (w, e))| (luminance(*w).abs() * e, c))
        .filter(|(s, _)| *s > 0.0)
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.truncate(k);
    scored.into_iter().map(|(_, c)| c).collect()
}

/// The weight of each group's pane when only the clusters in `selected` are composed:
/// `r_g = sum over left-out clusters c of g of w_c x energy_c / energy_g`, which gives the
/// group's pane the (luminance) energy of the light those clusters would have added.
pub fn residual_weights(prm: &Prm, weights: &[Vec3], selected: &[bool]) -> Vec<Vec3> {
    let mut r = vec![Vec3::ZERO; prm.groups().len()];
    for (c, &g) in prm.group_of().iter().enumerate() {
        if !selected[c] {
            r[g as usize] += weights[c] * prm.clusters()[c].energy;
        }
    }
    for (v, g) in r.iter_mut().zip(prm.groups()) {
        *v = if g.energy > 0.0 { *v / g.energy } else { Vec3::ZERO };
    }
    r
}

/// Add `weight x` pane `pane` (cluster c < C, group C + g) into a full-atlas image.
pub fn add_pane(prm: &Prm, pane: usize, weight: Vec3, img: &mut [Vec3], layout: &TileLayout) {
    for t in prm.pane_tiles(pane, layout) {
        let s = weight * t.tile.scale;
        for (&texel, v) in t.texels.iter().zip(t.data) {
            img[texel as usize] += s * prm::prm_file::intensity(*v);
        }
    }
}

/// The lightmap from the clusters in `selected` (weights `weights`), plus, with `residual`, the
/// groups standing in for the rest.
pub fn compose_selected(
    prm: &Prm,
    weights: &[Vec3],
    selected: &[bool],
    residual: bool,
    layout: &TileLayout,
) -> Vec<Vec3> {
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    for c in 0..prm.clusters().len() {
        if selected[c] && weights[c] != Vec3::ZERO {
            add_pane(prm, c, weights[c], &mut img, layout);
        }
    }
    if residual {
        let first_group = prm.clusters().len();
        for (g, w) in residual_weights(prm, weights, selected).into_iter().enumerate() {
            if w != Vec3::ZERO {
                add_pane(prm, first_group + g, w, &mut img, layout);
            }
        }
    }
    img
}

/// Most entries the far field sends in one frame ([`far_sources`]).
pub const FAR_SOURCES: usize = 1024;

/// The far field's threshold against the light the level's surfaces reflect
/// ([`far_threshold`]): a source's luminance over `R / FAR_SOURCE_SCALE`.
pub const FAR_SOURCE_SCALE: f32 = 4.0 * FAR_SOURCES as f32;

/// The threshold a far-field source's luminance |phi_j| must exceed ([`far_sources`]), from
/// `reflected` (`R = sum_j s_j luminance(albedo_j A/N) luminance(E_j)`, about the light the
/// level's surfaces reflect onto the level, `s_j` the entry's stay share) and `magnitudes`
/// (every |phi_j|).
///
/// Light that leaves the level lights nothing, so it sets no bar: 16 sunlit rooms' reflected
/// light was mostly their sunlit façades', which face the open sky, and at noon only 117 of
/// their 8,056 entries were sources, the rooms' own deviations under the bar. Counted by stay
/// share, 348 are (the twin against the ground truth at noon 15.3 -> 14.0 %, at a low sun 15.2
/// -> 13.6 %); a closed level, every share 1, is unchanged.
///
/// `R` hardly moves when a light moves (it is about the power the surfaces receive, times
/// their albedo), so an entry whose own light did not change stays a source or not, as it was.
/// The threshold was a share of the sum of the deviations, which moves with the one light that
/// moves, and sources all over a level of many rooms came and went with it (the 4 x 4 halls'
/// rig: 36 of 123 sources changed between two frames, and 905 of 1,648 atlas tiles moved by
/// more than 1 % of their light, 389 with the sources held).
///
/// Where more than [`FAR_SOURCES`] entries are over `R / FAR_SOURCE_SCALE`, the threshold is
/// the (`FAR_SOURCES` + 1)-th largest |phi_j|, so that the cap is filled: no more than
/// `FAR_SOURCES` exceed it, and as many as can. It was `sum |phi_j| / FAR_SOURCES`, which no
/// more than that many can exceed but far fewer did: the 16 sunrooms at dawn had 1,053 entries
/// over the stable bar and sent 302, the sun patches' large deviations and the largest
/// negative ones; the many small negative ones of the patches' shaded clusters were left out,
/// and the far field added their light (+3.7 % of the level's, every room's ceiling +6 %). With
/// the cap filled: 14.3 -> 10.9 % against the ground truth (noise removed), where every entry
/// a source gives 10.5 % (`docs/sunroom.md`). The GPU (`shaders/far.wgsl`) finds the same
/// value by bisection over the bits of the magnitudes.
pub fn far_threshold(reflected: f32, magnitudes: &[f32]) -> f32 {
    let stable = reflected / FAR_SOURCE_SCALE;
    let over = magnitudes.iter().filter(|&&m| m > stable).count();
    if over <= FAR_SOURCES {
        return stable;
    }
    let mut above: Vec<f32> = magnitudes.iter().copied().filter(|&m| m > stable).collect();
    let (_, kth, _) = above.select_nth_unstable_by(FAR_SOURCES, |a, b| b.total_cmp(a));
    *kth
}

/// A far-field source this frame ([`far_sources`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FarSource {
    /// Its entry.
    pub entry: u32,
    /// Its deviation flux `phi_j = albedo_j (A/N) (E_j - t_j w_c + relay_j)` (W,
    /// `relay`: [`near_deviation`]): what the far field sends, seen as its texels' neighbours
    /// see it.
    pub phi: Vec3,
    /// The whole flux its cell reflects, `albedo_j (A/N) E_j` (W), and the light that lights
    /// the cell up close ([`LightSight::lit_by`]): the panes and the far field together send
    /// that flux as the neighbours see the cell, and a texel sees the spot the light makes as
    /// it sees the light ([`far_field`]). None where no light is that close.
    pub whole: Vec3,
    pub lit_by: Option<u32>,
    /// Where its cell's light lands ([`LinkLight::landing`]) when a light lights it up close
    /// or it lands apart ([`FarSource::apart`]), else its cell's centroid: the far field sends
    /// the whole flux from there.
    pub landing: Vec3,
    /// Which way the light at `landing` leaves ([`LinkLight::landing_normal`]); the entry's
    /// normal where `landing` is the centroid.
    pub normal: Vec3,
    /// Its light lands apart from its cell's centroid or its normal ([`lands_apart`]), and no
    /// light lights it up close: the far field sends its whole flux from `landing` as the
    /// texel's neighbours see the cell, less that flux from the centroid.
    pub apart: bool,
}

/// How far, in cell sizes, the light on a cell must land from its centroid for the far field
/// to send it from where it lands ([`lands_apart`]). Measured on the chamber's flashlight rig
/// (noise removed): at 0.1 sizes the moving rig's frames sent 87-92 sources apart, at 0.5
/// 17-24, and the flashlight's errors moved by at most 0.1 points (the floor by a pillar 10.2
/// -> 10.3 %; with no such test, 11.0 %); apart sources cost the GPU's far pass a sum of their
/// own per texel.
pub const LANDING_APART: f32 = 0.5;
/// The cosine of the angle between the way a cell's light leaves and its entry's normal past
/// which the far field sends it the way it leaves ([`lands_apart`]): 10 degrees.
pub const LANDING_TURN: f32 = 0.985;

/// Whether a cell's light lands apart from its centroid and normal: more than
/// [`LANDING_APART`] sizes from the centroid, or leaving more than [`LANDING_TURN`]'s angle
/// from the entry's normal. The far field then sends the cell's whole flux from where it lands,
/// the way it leaves, less that flux from the centroid, the way the pane and the deviation
/// sent it ([`far_field`]).
///
/// A narrow spot (8°-12°) on the chamber's pillar lights the faces toward it, in cells that
/// wrap a quarter of the way round the pillar, whose entry points face elsewhere; sent the
/// way those points face, the floor beside the pillar got its light on the wrong side
/// (`docs/near-lights.md`, *A flashlight on a pillar*). A flat cell lit evenly lands at its
/// centroid along its normal: nothing changes for it.
pub fn lands_apart(landing: Vec3, landing_normal: Vec3, centroid: Vec3, normal: Vec3, size: f32) -> bool {
    landing.distance(centroid) > LANDING_APART * size || landing_normal.dot(normal) < LANDING_TURN
}

/// The entries the far field (`prm::prm_file::Far`) sends this frame, ascending: those whose
/// deviation flux's luminance |phi_j| exceeds the threshold ([`far_threshold`]), never more
/// than [`FAR_SOURCES`], each with the light that lights its cell up close
/// (`link_light.sight`) and where its light lands (`link_light.landing`, `landing_normal`).
/// Empty without a far field.
pub fn far_sources(
    prm: &Prm,
    tables: &NearTables,
    entry_irradiance: &[Vec3],
    weights: &[Vec3],
    relay: &[Vec3],
    link_light: &LinkLight,
) -> Vec<FarSource> {
    let sight = &link_light.sight;
    if prm.far().texels.is_empty() {
        return Vec::new();
    }
    let phi: Vec<Vec3> = prm
        .entries()
        .iter()
        .enumerate()
        .map(|(j, e)| {
            let fit = weights[tables.cluster[j] as usize];
            let relay = relay.get(j).copied().unwrap_or(Vec3::ZERO);
            e.albedo * e.area * (entry_irradiance[j] - fit * tables.area_ratio[j] + relay)
        })
        .collect();
    let magnitudes: Vec<f32> = phi.iter().map(|p| luminance(p.abs())).collect();
    let reflected: f32 = prm
        .entries()
        .iter()
        .zip(entry_irradiance)
        .zip(&tables.stay)
        .map(|((e, irr), stay)| stay * luminance(e.albedo * e.area) * luminance(*irr))
        .sum();
    let threshold = far_threshold(reflected, &magnitudes);
    let entries = prm.entries();
    phi.iter()
        .enumerate()
        .filter(|&(j, _)| magnitudes[j] > threshold)
        .take(FAR_SOURCES)
        .map(|(j, p)| {
            let (centroid, normal, size) = (tables.centroid[j], entries[j].normal, tables.size[j]);
            let lit_by = sight.lit_by(centroid, normal, size);
            let at = link_light.landing.get(j).copied().unwrap_or(centroid);
            let toward = link_light.landing_normal.get(j).copied().unwrap_or(normal);
            let apart = lit_by.is_none() && lands_apart(at, toward, centroid, normal, size);
            let (landing, normal) = if lit_by.is_some() || apart { (at, toward) } else { (centroid, normal) };
            FarSource {
                entry: j as u32,
                phi: *p,
                whole: entries[j].albedo * entries[j].area * entry_irradiance[j],
                lit_by,
                landing,
                normal,
                apart,
            }
        })
        .collect()
}

/// How the far texels see the lights that light a cell up close ([`up_close`]; the first
/// [`CLOSE_SIGHTS`] of them, [`sighted`]): such a light makes a spot of light on the cell much
/// smaller than the cell (it is within [`HOT_REACH`] cell sizes of it), which the far field
/// otherwise sends as the texel's neighbour entries see the cell (`prm::prm_file::far_vote`). Beside a pillar's foot
/// or under its capital, a texel's neighbours lie on other faces and say nothing of what it
/// sees: on the chamber's torch 15 cm from a wall, a capital 3 m away that saw the torch's
/// spot got a sixth of its light. The spot is seen from the light's eye ([`sight_eye`]: a
/// point light's own position, a narrow spot's axis where it meets the level): the GPU reads
/// the light's cube of shadow maps there at the texel, the twin traces a ray
/// (`crate::cpu::light_sight`).
///
/// [`HOT_REACH`]: crate::cpu::concentrate::HOT_REACH
#[derive(Clone, Debug, Default)]
pub struct LightSight {
    /// Per light: the light where the far field sees its spots in its cube of shadow maps
    /// ([`sighted`]), else None.
    pub at: Vec<Option<prm::Light>>,
    /// Per light: its eye ([`sight_eye`]), where its cube is and its spots are seen from.
    pub eye: Vec<Vec3>,
    /// Per light in `at` that lights some cell up close: how much of it each far texel (in
    /// `Far::texels` order) sees, 0 to 1 (the GPU: its cube's PCF share); empty for the others.
    pub seen: Vec<Vec<f32>>,
}

impl LightSight {
    /// The light that lights a cell (centroid, unit normal, size) up close ([`up_close`]): of
    /// the lights with a position, the nearest (the first of equals).
    pub fn lit_by(&self, centroid: Vec3, normal: Vec3, size: f32) -> Option<u32> {
        let mut best: Option<(u32, f32)> = None;
        for (k, (at, &eye)) in self.at.iter().zip(&self.eye).enumerate() {
            let Some(d) = at.as_ref().and_then(|l| up_close(l, eye, centroid, normal, size)) else {
                continue;
            };
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((k as u32, d));
            }
        }
        best.map(|(k, _)| k)
    }
}

/// How far from a cell's centroid a spot's cone must reach for the spot to light the cell up
/// close ([`up_close`]), in cell sizes (the square root of its area). A cell is no disk: a
/// spot 15 cm from the chamber's corner, aimed into it, lit two corner cells through their
/// far ends while missing the disk of their area (radius `1/sqrt(pi)`, 0.56), so the far field
/// sent their light from their centroids, half a metre from where it lands: the texels 1-2 m
/// from the corner took 2.2x their first bounce and those 2-4 m away 1.4x (at 1 size: 1.5x
/// and 1.06x; measured with a one-bounce bake against a one-bounce ground truth). Of the
/// bundled rigs only that spot moves.
pub const CONE_REACH: f32 = 1.0;

/// The distance from a point or spot light's eye ([`sight_eye`]) to a cell (centroid, unit
/// normal, size) the light lights up close: the eye within
/// [`HOT_REACH`](crate::cpu::concentrate::HOT_REACH) sizes of the centroid and in front of the
/// cell, and for a spot, its outer cone reaching a disk of radius [`CONE_REACH`] cell sizes
/// about the centroid (a spot under a ceiling aimed down lights no ceiling cell, and would
/// render a cube for nothing: the chamber's dais spot did, every frame of its rig). None
/// otherwise.
pub fn up_close(l: &prm::Light, eye: Vec3, centroid: Vec3, normal: Vec3, size: f32) -> Option<f32> {
    let d = eye.distance(centroid);
    if !(d < crate::cpu::concentrate::HOT_REACH * size && normal.dot(eye - centroid) > 0.0) {
        return None;
    }
    if let prm::LightKind::Spot { outer, .. } = l.kind {
        // The disk about the centroid: where the axis meets its plane inside it, the cone holds
        // it; else one of four points on its rim holds the cone's nearest part, the one toward
        // where the axis meets the plane (or toward where the axis points along it, when it
        // points away).
        let r = size * CONE_REACH;
        let toward = l.direction.dot(normal);
        let mut u = l.direction - normal * toward;
        if toward < 0.0 {
            let hit = l.position + l.direction * ((centroid - l.position).dot(normal) / toward);
            u = hit - centroid;
            if u.length() <= r {
                return Some(d);
            }
        }
        let u = if u.length() > 1e-6 { u / u.length() } else { Vec3::ZERO };
        let v = normal.cross(u);
        let cos_outer = outer.cos();
        let inside = |q: Vec3| l.direction.dot((q - l.position).normalize_or_zero()) > cos_outer;
        if ![centroid, centroid + u * r, centroid + v * r, centroid - v * r].into_iter().any(inside) {
            return None;
        }
    }
    Some(d)
}

/// The cells, to tell whether a light lights some cell up close ([`up_close`]): a spot that
/// does owns a cube of shadow maps besides its frustum (`crate::lights::layers`).
#[derive(Clone, Debug, Default)]
pub struct UpClose {
    centroid: Vec<Vec3>,
    normal: Vec<Vec3>,
    size: Vec<f32>,
    /// The cells' mean size ([`UpClose::spacing`]), made once.
    spacing: f32,
}

impl UpClose {
    pub fn new(prm: &Prm, tables: &NearTables) -> UpClose {
        let n = tables.size.len();
        let mean = tables.size.iter().map(|&s| f64::from(s)).sum::<f64>() / n.max(1) as f64;
        UpClose {
            centroid: tables.centroid.clone(),
            normal: prm.entries().iter().map(|e| e.normal).collect(),
            size: tables.size.clone(),
            spacing: mean as f32,
        }
    }

    /// Whether a point or spot light, seen from `eye` ([`sight_eye`]), lights some cell up
    /// close.
    pub fn any(&self, l: &prm::Light, eye: Vec3) -> bool {
        (0..self.size.len())
            .any(|j| up_close(l, eye, self.centroid[j], self.normal[j], self.size[j]).is_some())
    }

    /// Per light, with its eye ([`sight_eye`]): a point or spot light that lights some cell
    /// up close (what `crate::lights::layers` is given: a spot with one frustum then owns a
    /// cube too, at its eye).
    pub fn lights(&self, lights: &[prm::Light], eyes: &[Vec3]) -> Vec<bool> {
        lights.iter().zip(eyes).map(|(l, &eye)| l.is_positional() && self.any(l, eye)).collect()
    }

    /// The cells' mean size (their entry spacing; 0 with no cells): what [`sight_eye`] steps
    /// back by.
    pub fn spacing(&self) -> f32 {
        self.spacing
    }
}

/// How far short of where its axis meets the level a narrow spot's eye stands
/// ([`sight_eye`]), in entry spacings ([`UpClose::spacing`]). The chamber's flashlight rig
/// moved by at most 0.4 points between 0.04 and 0.3 spacings.
pub const EYE_BACK: f32 = 0.1;

/// Where the far field sees a light's spots from ([`LightSight`]), and where its cube of
/// shadow maps is drawn: for a spot with a frustum (its outer cone within
/// `crate::lights::SPOT_CUBE_ABOVE`, 60°) whose axis meets the level within its
/// range, [`EYE_BACK`] spacings short of that point along the axis (at most half the way
/// back to the light); for every other light, the light itself. `first_hit(origin, unit
/// direction, tmax)` is the distance to the first triangle of the level the ray meets: the
/// GPU runtime's `crate::AxisCaster`, the twin's BVH.
///
/// A narrow spot's light lands in a patch much smaller than its distance, and a far texel sees
/// that patch as a point in it sees the texel, not as the light does: the chamber's flashlight
/// 1.2 m over the floor by a pillar cast the shaft's shadow onto the capital's underside as
/// seen from the patch, which the texels' neighbours (the vote) blurred over half a metre and
/// the light's own view put elsewhere (10.7 %; seen from the patch, 7.1 %). A point light's
/// patch is about as wide as the light is high, so its own position is as good a point as any
/// in the patch.
pub fn sight_eye(l: &prm::Light, first_hit: impl Fn(Vec3, Vec3, f32) -> Option<f32>, spacing: f32) -> Vec3 {
    let prm::LightKind::Spot { outer, .. } = l.kind else { return l.position };
    if outer > crate::lights::SPOT_CUBE_ABOVE {
        return l.position;
    }
    let reach = l.range.filter(|r| *r > 0.0).unwrap_or(f32::INFINITY);
    match first_hit(l.position, l.direction, reach) {
        Some(t) if t.is_finite() => {
            let back = (EYE_BACK * spacing).min(0.5 * t);
            l.position + l.direction * (t - back)
        }
        _ => l.position,
    }
}

/// The most lights the far field sees the spots of ([`LightSight`]): the first this many (in
/// the lights' order) that light some cell up close. Each far texel looks each of them up in
/// its cube of shadow maps once, and sums the sources they light up close apart from the
/// others (a lookup inside the sum over all sources doubled the far pass on lavapipe); the
/// spots of the lights after them are seen by the votes.
pub const CLOSE_SIGHTS: usize = 4;
// `shaders/far.wgsl` keeps the sights in a `vec4f`.
const _: () = assert!(CLOSE_SIGHTS == 4);

/// Which lights the far field sees the spots of: the first [`CLOSE_SIGHTS`] of those `close`
/// ([`UpClose::lights`]).
pub fn sighted(close: &[bool]) -> Vec<bool> {
    let mut left = CLOSE_SIGHTS;
    close
        .iter()
        .map(|&c| {
            let take = c && left > 0;
            left -= take as usize;
            take
        })
        .collect()
}

/// The far field at each of the map's far texels (in their order): `sum over sources j of
/// phi_j share V cos_x cos_j / (pi r² max(r², s_j²))`, r from the texel's point to the centroid
/// of the entry's cell (its light's centre, where the entry point is only a sample of it),
/// share = `far_share(|x - centroid_j|, reach, s_j)` (s_j: the cell's size), V the texel's
/// neighbours' visibility of j weighted as stored. The `max` only matters with no near links
/// (reach 0), where it bounds the spike a source next to the texel would make. A source lit up
/// close by a light ([`FarSource::lit_by`]) also sends its whole flux times what the texel
/// sees of that light (`sight`, faded into V as the light stands farther off the cell:
/// [`sight_share`]), from where the light lands on the cell ([`FarSource::landing`]), less
/// its whole flux times V from the centroid: the panes' first bounce and the deviation
/// together send the cell's whole flux by V from the centroid, and this sends it as the texel
/// sees it from where it is. A spot 15 cm from the chamber's wall, aimed at it, lights a patch
/// of a cell half a metre across; sent from the cell's centroid, the floor and ceiling in
/// front, which see the patch at a grazing angle, took it from where it is not (that spot's
/// error 10.5 -> 5.9 %). A source whose light lands apart
/// ([`FarSource::apart`]) does the same with V for the sight; both send from `landing` along
/// [`FarSource::normal`], the way the light leaves.
pub fn far_field(prm: &Prm, tables: &NearTables, sources: &[FarSource], sight: &LightSight) -> Vec<Vec3> {
    let (far, entries) = (prm.far(), prm.entries());
    far.texels
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut sum = Vec3::ZERO;
            for s in sources {
                let (j, e) = (s.entry as usize, &entries[s.entry as usize]);
                let (size, centroid) = (tables.size[j], tables.centroid[j]);
                let share = far_share(centroid.distance(t.position), far.reach, size);
                if share <= 0.0 {
                    continue;
                }
                let kernel = |d: Vec3, normal: Vec3| {
                    let (cx, cy) = (t.normal.dot(d), -normal.dot(d));
                    let r2 = d.length_squared();
                    if cx > 0.0 && cy > 0.0 {
                        share * cx * cy / (std::f32::consts::PI * r2 * r2.max(size * size))
                    } else {
                        0.0
                    }
                };
                let from_centroid = kernel(centroid - t.position, e.normal);
                let landed = s.lit_by.is_some() || s.apart;
                if from_centroid == 0.0 && !landed {
                    continue;
                }
                let v = vote(far, t, j, |k| {
                    let q = t.entries[k] as usize;
                    entries[q].normal.dot(centroid - tables.centroid[q]) > 0.0
                });
                let mut light = s.phi * v;
                if landed {
                    // The whole flux from where it lands, the way it leaves, as the texel sees
                    // the light that lights it up close or (apart) as the neighbours see the
                    // cell; less what the panes and the deviation sent of it from the centroid.
                    light -= s.whole * v;
                    let seen = match s.lit_by {
                        Some(l) => {
                            let at = sight.eye.get(l as usize).copied().unwrap_or(centroid);
                            let w = sight_share(e.normal.dot(at - centroid), size);
                            w * sight.seen[l as usize][i] + (1.0 - w) * v
                        }
                        None => v,
                    };
                    sum += s.whole * (seen * kernel(s.landing - t.position, s.normal));
                }
                sum += light * from_centroid;
            }
            sum
        })
        .collect()
}

/// How much a far texel takes a source lit up close as it sees the light's eye
/// ([`LightSight`], [`sight_eye`]), the rest as its neighbours see the cell (the vote), for an
/// eye `height` off the cell's plane (`size`: the cell's): all within one size, none at
/// [`HOT_REACH`](crate::cpu::concentrate::HOT_REACH), linear between (`sight_share` in
/// `shaders/far.wgsl`). What the light sees stands for what its spot on the cell sees only
/// while the light is close to the surface it lights: the chamber's flashlight 1 m from a side
/// wall (1.8 sizes) saw round a pillar that hides the wall's lit patch from the floor behind
/// it (11.9 %; at this share 9.1 %), where a torch 15 cm from a wall, or a lamp 3 cm over a
/// floor lighting the floor around it, sees what its spot sees. Measured against the light's
/// distance from the centroid (9.3 %) and the baseline across the texel's direction from
/// where the light lands (10.8 %); the height is kept. A narrow spot's eye is where its light
/// lands (that flashlight from there: 6.7 %), so this keeps to point lights.
pub fn sight_share(height: f32, size: f32) -> f32 {
    let w = (crate::cpu::concentrate::HOT_REACH - height / size).clamp(0.0, 1.0);
    // A cell of no size takes the vote.
    if w.is_nan() {
        0.0
    } else {
        w
    }
}

/// How much of far-field source `j` texel `t` sees: the weighted vote of its neighbour entries'
/// pair bits, over the neighbours that face the source (`faces(k)`). A neighbour turned away
/// from it has no bit to give (its own surface hides the source from it: the next facet of a
/// convex pillar) and would vote a lit texel dark; the chamber's 5 cm wall torch lost 1.3
/// points of first-bounce error to such votes. With no neighbour facing it, all of them vote.
fn vote(
    far: &prm::prm_file::Far,
    t: &prm::prm_file::FarTexel,
    j: usize,
    faces: impl Fn(usize) -> bool,
) -> f32 {
    prm::prm_file::far_vote(&t.weights, |k| far.sees(t.entries[k] as usize, j), faces)
}

/// The indirect lightmap for per-cluster weights (W/m² of entry irradiance): every pane times
/// its weight, no selection.
pub fn compose(prm: &Prm, weights: &[Vec3]) -> Vec<Vec3> {
    assert_eq!(weights.len(), prm.clusters().len(), "one weight per cluster");
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    let layout = prm.layout();
    for (c, w) in weights.iter().enumerate() {
        if *w != Vec3::ZERO {
            add_pane(prm, c, *w, &mut img, &layout);
        }
    }
    img
}

/// The whole indirect lightmap of every pane for these entry irradiances (no link light, as
/// [`cluster_weights`]): balanced weights, the near field, the weights lifted by it
/// ([`lift_weights`]), the panes, the near field added and the sum clamped
/// at zero. What the twin and the GPU give with every pane composed.
pub fn lightmap(prm: &Prm, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
    let tables = NearTables::new(prm);
    let (weights, near) = pane_weights_with(prm, &tables, &LinkLight::none(prm), entry_irradiance);
    let mut img = compose(prm, &weights);
    add_and_clamp(&mut img, &near);
    img
}

/// The weights the panes are composed with, and the near field (per atlas texel, signed):
/// [`cluster_weights_with`], the near field under them ([`near_field`]), then
/// [`lift_weights`]. The GPU's weight, near and lift passes.
pub fn pane_weights_with(
    prm: &Prm,
    tables: &NearTables,
    link_light: &LinkLight,
    entry_irradiance: &[Vec3],
) -> (Vec<Vec3>, Vec<Vec3>) {
    let balanced = cluster_weights_with(prm, tables, entry_irradiance);
    let near = near_field(prm, tables, link_light, entry_irradiance, &balanced);
    (lift_weights(prm, tables, &balanced, &near, entry_irradiance), near)
}

/// [`pane_weights_with`]'s weights with no light on the links of hot cells, as
/// [`cluster_weights`].
pub fn pane_weights(prm: &Prm, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
    pane_weights_with(prm, &NearTables::new(prm), &LinkLight::none(prm), entry_irradiance).0
}

/// Adds the near field (signed) into a lightmap of panes, then clamps every texel at zero (the
/// near and far fields are signed), as the GPU's compose does.
pub fn add_and_clamp(img: &mut [Vec3], near: &[Vec3]) {
    for (v, n) in img.iter_mut().zip(near) {
        *v = (*v + *n).max(Vec3::ZERO);
    }
}

/// The near field (`prm_precompute::near`; the GPU's `runtime/src/near.rs`), per atlas texel
/// and signed: each texel with links gets `sum albedo_j factor (E_j - w_c(j) t_j)` over them
/// (`t_j`: [`NearTables`]), from the entries' irradiance and the cluster weights, and its echo
/// ([`link_field`]); then the far field ([`far_sources`] with the links' own deviation,
/// [`near_deviation`]; [`far_field`], seeing lights by `link_light.sight`).
/// Hot cells' links use their own `E_j
/// kappa` for `E_j` (`link_light`). `weights` are the balanced ones
/// ([`cluster_weights_with`]); the panes take them lifted ([`pane_weights_with`]). A frame adds
/// it to the panes with [`add_and_clamp`].
pub fn near_field(
    prm: &Prm,
    tables: &NearTables,
    link_light: &LinkLight,
    entry_irradiance: &[Vec3],
    weights: &[Vec3],
) -> Vec<Vec3> {
    let mut img = link_field(prm, tables, link_light, entry_irradiance, weights);
    let sight = &link_light.sight;
    let relay = near_deviation(prm, tables, &img);
    let sources = far_sources(prm, tables, entry_irradiance, weights, &relay, link_light);
    for (t, v) in prm.far().texels.iter().zip(far_field(prm, tables, &sources, sight)) {
        img[t.texel as usize] += v;
    }
    img
}

/// [`near_field`]'s links with their echo alone, per atlas texel (0 at texels without links):
/// the GPU's near pass before the far field.
pub fn link_field(
    prm: &Prm,
    tables: &NearTables,
    link_light: &LinkLight,
    entry_irradiance: &[Vec3],
    weights: &[Vec3],
) -> Vec<Vec3> {
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    let mut k = 0;
    let runs: Vec<&[prm::prm_file::NearLink]> = prm.near().chunk_by(|a, b| a.texel == b.texel).collect();
    // Per near point, the links' deviation and what the panes expected of them.
    let (mut near, expected): (Vec<Vec3>, Vec<Vec3>) = runs
        .iter()
        .map(|links| {
            let (mut sum, mut expected_sum) = (Vec3::ZERO, Vec3::ZERO);
            for l in links.iter() {
                let j = l.entry as usize;
                let expected = weights[tables.cluster[j] as usize] * tables.area_ratio[j];
                let e = if link_light.hot[j] { link_light.value[k] } else { entry_irradiance[j] };
                let f = prm.entries()[j].albedo * l.factor;
                sum += f * (e - expected);
                expected_sum += f * expected;
                k += 1;
            }
            (sum, expected_sum)
        })
        .unzip();
    if !prm.echo().links.is_empty() {
        let mut bounce = echo_input(tables, &near, &expected);
        for _ in 0..ECHO_BOUNCES {
            bounce = echo_bounce(prm, &bounce);
            for (n, b) in near.iter_mut().zip(&bounce) {
                *n += *b;
            }
        }
    }
    for (links, sum) in runs.iter().zip(near) {
        // Crease points (texels past the atlas's) are never composed.
        if let Some(v) = img.get_mut(links[0].texel as usize) {
            *v += sum;
        }
    }
    img
}

/// Per entry, the near field's own light on its cell less its cluster's mean of it, `t_j (n_j -
/// u_c)` (W/m² of entry weight, as `E_j`): `n_j` the near links and their echo over the
/// entry's cell ([`link_field`], [`cell_means`]; 0 at a texel without links), `u_c` their mean
/// over the cluster's cells weighted by `t_j`, as [`lift_weights`] takes it. Entries without
/// texels take no part. The far field sends it with the entries' own deviation
/// ([`far_sources`]).
///
/// The lift gives a cluster's pane the near field's light that lands on the cluster, spread
/// over the cluster: next to a light near a surface, its first bounce lands in a few of a
/// cluster's cells, and their next bounce came from the whole cluster, 2-3 m across. Sending
/// the near field's deviation from that mean puts the next bounce back where the light landed,
/// beyond the links' reach, as the far field does for the light itself. Its first bounce is
/// all it sends: the later ones stay spread. Measured with the twin against the ground truth
/// (noise removed, chamber rigs): with the balance counting hot links at their cell's power
/// ([`cluster_weights`]) and the cone's reach ([`CONE_REACH`]), the spot 15 cm from a corner,
/// aimed into it, went from bias -8.3 % to +5.8 % (error 4.88 -> 4.87 %; the balance alone
/// +11.2 %, this alone -12.7 %), the spot under the ceiling aimed at it 7.64 -> 6.63 %, the
/// corner torch 5.93 -> 5.62 %, the torch under the ceiling 5.48 -> 5.17 %; no other placement
/// of the chamber, two_rooms or cornell rigs moved by more than 0.26 points, and the 4 x 4
/// halls stayed at 5.61 % (bias +0.8 -> +1.0 %). Then each cell's near field was read at one
/// texel, the far texel nearest its entry, which by the corner spot read the peak of its first
/// bounce; over all the cell's texels, with the far field's energies summed as it delivers
/// them (`prm::prm_file::Far::energy`), the corner spot's bias went +5.5 -> +1.1 % and
/// two_rooms' corner spot's +5.5 -> +1.6 % (`docs/near-lights.md`, *Corner spots: the balance and
/// the relay*).
pub fn near_deviation(prm: &Prm, tables: &NearTables, near: &[Vec3]) -> Vec<Vec3> {
    let mut relay = vec![Vec3::ZERO; prm.entries().len()];
    let vals = cell_means(tables, near);
    for (cl, u) in prm.clusters().iter().zip(cluster_means(prm, tables, &vals)) {
        let Some(u) = u else { continue };
        for &m in &cl.members {
            let m = m as usize;
            if let Some(v) = vals[m] {
                relay[m] = (v - u) * tables.area_ratio[m];
            }
        }
    }
    relay
}

/// Per cluster, the mean of its cells' values (`vals`: [`cell_means`]) weighted by `t_j`; None
/// where no member has a texel. The lift's `u_c` ([`lift_weights`]) and the relay's
/// ([`near_deviation`]).
fn cluster_means(prm: &Prm, tables: &NearTables, vals: &[Option<Vec3>]) -> Vec<Option<Vec3>> {
    prm.clusters()
        .iter()
        .map(|cl| {
            let (mut sum, mut t_sum) = (Vec3::ZERO, 0.0f32);
            for &m in &cl.members {
                let m = m as usize;
                if let Some(v) = vals[m] {
                    sum += v * tables.area_ratio[m];
                    t_sum += tables.area_ratio[m];
                }
            }
            (t_sum > 0.0).then(|| sum / t_sum)
        })
        .collect()
}

/// The cluster weights with the near field's later bounces: `(1 - lambda) w_c + u_c`.
///
/// The near and far fields deliver the first bounce of the light's deviation from each
/// cluster's mean (`K D`); its later bounces were left out, or rather spread by the balance
/// over the deviating cluster's pane. But `K D` is itself light on the level's surfaces, and a
/// pane is the answer (all bounces) to light on its cluster: so `u_c`, the mean of the near
/// field over cluster c's cells (each cell's mean over its texels, [`cell_means`], weighted by
/// `t_j`), weights c's pane with what the deviation's first bounce puts there. A
/// lamp 5 cm from the chamber's wall lights the floor in front of it through the near and far
/// fields; that floor's clusters now light the wall around the lamp with it (measured on the
/// chamber's torch rig: every placement better, the 5 cm wall 9.3 -> 8.7 %, the ceiling 9.9
/// -> 7.9 %).
///
/// The balance already kept each cluster's energy with the near field's, so the later bounces
/// must not add any: `lambda = sum_c u_c energy_c / sum_c w_c energy_c` (per channel, each
/// pane's energy in that channel: its luminance's tinted by the cluster's albedo,
/// [`NearTables::cluster_tint`], as the balance counts it) takes it back from every pane in
/// proportion, room by room (the sums over the clusters of one room,
/// [`NearTables::cluster_room`]): the near field's light stays in its room, and a light in one
/// sealed room does not change another's. Counted untinted, a spot on the closed box's red
/// runner, whose red light the lift spreads onto grey clusters, took the red back from the
/// runner's panes at their luminance, a third of their red: +15.4, +5.9, +6.3 % per channel
/// against the ground truth (+5.8, +10.3, +11.5 % without the lift); tinted, +5.4, +10.4,
/// +11.7 %.
///
/// **The room's power** (`.prm` v17: the far texels' areas, `prm::prm_file::Far::areas`). The
/// balance predicts what the near and far fields deliver from each entry's energy per unit
/// deviation (`NearTables::energy`); for a hot cell they deliver something else (its links
/// read where the light lands, the relay sends their deviation on), and the panes kept the
/// balance's guess. Under a narrow spot on the chamber's plinth (seed 0) the balance counted
/// the near and far fields at -3.1 % of the panes and raised them to match, where the fields
/// delivered +0.2 %: the panes sent 3.2 % more than the lit cells do over every bounce, and
/// the frame read +4.0 % (+1.7 and +1.5 % of raise at seeds 1 and 2). So where the map has the
/// areas, lambda keeps the room's power instead: the lifted panes send `D = sum_j (A/N) E_j
/// g_j rho_j` (what the room's cells send over every bounce: each pane's luminance is matched
/// to `P_c` in the bake) less the near and far fields' power over the far texels' areas, held
/// within [`POWER_KEPT_LIMITS`] of the balanced panes'. Counted per texel
/// instead of per area, the corner spot's few small texels by the corner (a texel's share of
/// a cut cell) made the fields' power look 2x what it is and the room 8 % dark. Measured with
/// the twin against the ground truths (noise removed, means of seeds 0-2, the biases per seed
/// within -2.3 to +1.2 % where they were -2.0 to +4.6 %): the plinth spot 7.12 -> 7.01 %, the
/// chamber's 26 rig placements 5.04 -> 5.03 %, two_rooms' and cornell's 21 placements 2.78 ->
/// 2.74 % (`docs/near-lights.md`, *The room's power*).
///
/// A lifted weight may be negative, and is kept so. u_c < 0 where the near field over c's
/// cells is negative: there the first bounce of a hot cluster's dimmer cells (below its mean)
/// brings c less light than that cluster's pane assumed, and c's pane takes back the later
/// bounces the hot pane gave too much (on the chamber's torch rig 140-150 of 256 clusters have
/// u_c < 0).
/// The selection ranks panes by |luminance(w)| x energy. Measured side by side (chamber torch
/// rig, 3 seeds, all panes): weights kept at >= 0 instead add energy (the corner torch +7.9 %
/// of bias against -0.5 % signed) and are no better anywhere (mean of the 9 placements 7.84
/// against 7.81 %); kept at >= 0 with lambda raised until the energy is kept, 8.02 %.
/// Without a far field (no texel stands for an entry) the weights are returned unchanged.
pub fn lift_weights(
    prm: &Prm,
    tables: &NearTables,
    weights: &[Vec3],
    near: &[Vec3],
    entry_irradiance: &[Vec3],
) -> Vec<Vec3> {
    let lift: Vec<Vec3> = cluster_means(prm, tables, &cell_means(tables, near))
        .into_iter()
        .map(|u| u.unwrap_or(Vec3::ZERO))
        .collect();
    let lambda = if tables.cell_areas.is_empty() {
        energy_lambda(prm, tables, weights, &lift)
    } else {
        power_lambda(prm, tables, weights, &lift, near, entry_irradiance)
    };
    weights
        .iter()
        .zip(lift)
        .zip(&tables.cluster_room)
        .map(|((w, u), &room)| *w * (Vec3::ONE - lambda[room as usize]) + u)
        .collect()
}

/// A map without its far texels' areas (before v17): per room, the lift keeps the panes'
/// energy as the balance set it.
fn energy_lambda(prm: &Prm, tables: &NearTables, weights: &[Vec3], lift: &[Vec3]) -> Vec<Vec3> {
    let (mut lifted, mut kept) = (vec![Vec3::ZERO; tables.rooms], vec![Vec3::ZERO; tables.rooms]);
    for (c, cl) in prm.clusters().iter().enumerate() {
        let (room, energy) = (tables.cluster_room[c] as usize, cl.energy * tables.cluster_tint[c]);
        lifted[room] += lift[c] * energy;
        kept[room] += weights[c] * energy;
    }
    lifted.iter().zip(&kept).map(|(l, k)| Vec3::select(k.cmpgt(Vec3::ZERO), *l / *k, Vec3::ZERO)).collect()
}

/// The most and least the panes' power in a room may be moved from the balance's by
/// [`lift_weights`]: a bound for stiff inputs (a near field that says it delivers more than
/// the cells send).
pub const POWER_KEPT_LIMITS: [f32; 2] = [0.5, 2.0];

/// Per room, the lambda that makes the lifted panes send the power the room's cells send over
/// every bounce, less what the near and far fields deliver there: `D = sum_j (A/N)_j E_j g_j
/// rho_j - sum_k a_k n_k` over the room's entries and their cells' texels (areas `a_k`,
/// [`NearTables::cell_areas`]), `lambda = (K + L - D) / K` with `K = sum_c w_c P_c` and `L =
/// sum_c u_c P_c` ([`NearTables::power`]), `D` held within [`POWER_KEPT_LIMITS`] of `K`.
fn power_lambda(
    prm: &Prm,
    tables: &NearTables,
    weights: &[Vec3],
    lift: &[Vec3],
    near: &[Vec3],
    entry_irradiance: &[Vec3],
) -> Vec<Vec3> {
    let rooms = tables.rooms;
    let (mut kept, mut lifted, mut target) =
        (vec![Vec3::ZERO; rooms], vec![Vec3::ZERO; rooms], vec![Vec3::ZERO; rooms]);
    for (c, cl) in prm.clusters().iter().enumerate() {
        let room = tables.cluster_room[c] as usize;
        kept[room] += weights[c] * tables.power[c];
        lifted[room] += lift[c] * tables.power[c];
        for &m in &cl.members {
            let m = m as usize;
            target[room] += prm.entries()[m].area * entry_irradiance[m] * tables.reflect[m];
        }
    }
    for j in 0..prm.entries().len() {
        let room = tables.cluster_room[tables.cluster[j] as usize] as usize;
        let run = tables.cell_first[j] as usize..tables.cell_first[j + 1] as usize;
        for (&t, &a) in tables.cell_texels[run.clone()].iter().zip(&tables.cell_areas[run]) {
            target[room] -= a * near[t as usize];
        }
    }
    (0..rooms)
        .map(|r| {
            let k = kept[r];
            let d = target[r].max(POWER_KEPT_LIMITS[0] * k).min(POWER_KEPT_LIMITS[1] * k);
            Vec3::select(k.cmpgt(Vec3::ZERO), (k + lifted[r] - d) / k, Vec3::ZERO)
        })
        .collect()
}
