//! The invariants of a radiance map, checked once for every [`super::Prm`]: a loaded file and a
//! fresh bake pass the same door, so nothing downstream (the CPU compose, the GPU upload) needs
//! to check again or can be made to index out of bounds.

use std::collections::HashSet;

use glam::Vec3;

use super::{tile_layout, Far, Header, PrmParts};

/// Largest atlas side and tile side a map may declare.
const MAX_ATLAS: u32 = 65536;
const MAX_TILE: u32 = 4096;

/// The first invariant `p` breaks, in words.
pub(super) fn invariants(p: &PrmParts) -> Result<(), String> {
    let h = &p.header;
    atlas(h)?;
    counts(p)?;
    entries(p)?;
    tiles(p)?;
    ranges(p)?;
    far(p)?;
    if let Some(c) = p.group_of.iter().position(|&g| g as usize >= p.groups.len()) {
        return Err(format!("cluster {c} is in group {}, of {}", p.group_of[c], p.groups.len()));
    }
    let mask_bytes = (h.atlas_width as u64 * h.atlas_height as u64).div_ceil(8);
    if p.mask.len() as u64 != mask_bytes {
        return Err(format!(
            "mask is {} bytes for a {}x{} atlas",
            p.mask.len(),
            h.atlas_width,
            h.atlas_height
        ));
    }
    let want = tile_layout(h, &p.mask, &p.tiles).len;
    if p.data.len() != want {
        return Err(format!("tile data is {} bytes, the tiles' masked texels need {want}", p.data.len()));
    }
    if let Some(c) =
        p.clusters.iter().position(|c| !(c.energy.is_finite() && c.energy >= 0.0 && c.centroid.is_finite()))
    {
        return Err(format!("cluster {c} has a non-finite energy or centroid"));
    }
    Ok(())
}

/// A plausible atlas and tile size (checked before any section is read, too): at least one
/// page, the pages stacked down a square page's width, and texel indices that fit a u32.
pub(super) fn atlas(h: &Header) -> Result<(), String> {
    let paged = h.pages > 1;
    if h.tile_size == 0
        || h.tile_size > MAX_TILE
        || h.atlas_width == 0
        || h.atlas_height == 0
        || h.atlas_width > MAX_ATLAS
        || h.pages == 0
        || h.pages > crate::density::MAX_PAGES
        || (!paged && h.atlas_height > MAX_ATLAS)
        || (paged && h.atlas_height as u64 != h.atlas_width as u64 * h.pages as u64)
        || h.atlas_width as u64 * h.atlas_height as u64 > u32::MAX as u64
        || !(h.page_texel_size.is_finite() && h.page_texel_size >= 0.0)
        || (paged && h.page_texel_size == 0.0)
    {
        return Err(format!(
            "implausible atlas {}x{} in {} page(s) / tile size {}",
            h.atlas_width, h.atlas_height, h.pages, h.tile_size
        ));
    }
    Ok(())
}

/// The header's counts are the parts' lengths.
fn counts(p: &PrmParts) -> Result<(), String> {
    let h = &p.header;
    let want_of = if p.groups.is_empty() { 0 } else { p.clusters.len() };
    for (what, declared, has) in [
        ("entries", h.entries as usize, p.entries.len()),
        ("clusters", h.clusters as usize, p.clusters.len()),
        ("groups", h.groups as usize, p.groups.len()),
        ("tiles", h.tiles as usize, p.tiles.len()),
        ("cluster groups", want_of, p.group_of.len()),
    ] {
        if declared != has {
            return Err(format!("{declared} {what} declared, {has} present"));
        }
    }
    Ok(())
}

fn entries(p: &PrmParts) -> Result<(), String> {
    let ok = |e: &super::Entry| {
        e.position.is_finite()
            && e.normal.is_finite()
            && e.albedo.is_finite()
            && e.area.is_finite()
            && e.area >= 0.0
    };
    if let Some(k) = p.entries.iter().position(|e| !ok(e)) {
        return Err(format!("entry {k} has non-finite or negative values"));
    }
    if !p.stays.is_empty() && p.stays.len() != p.entries.len() {
        return Err(format!("{} stay shares for {} entries", p.stays.len(), p.entries.len()));
    }
    if let Some(k) = p.stays.iter().position(|s| !(0.0..=1.0).contains(s)) {
        return Err(format!("entry {k} has a stay share of {} (not in 0 to 1)", p.stays[k]));
    }
    if !p.gains.is_empty() && p.gains.len() != p.entries.len() {
        return Err(format!("{} bounce gains for {} entries", p.gains.len(), p.entries.len()));
    }
    if let Some(k) = p.gains.iter().position(|g| !(g.is_finite() && g.min_element() >= 0.0)) {
        return Err(format!("entry {k} has a bounce gain of {} (not finite and non-negative)", p.gains[k]));
    }
    let n = p.entries.len();
    let cells = &p.cells;
    if cells.first.len() != n + 1
        || cells.first.first() != Some(&0)
        || cells.first.last().map(|&l| l as usize) != Some(cells.triangles.len())
        || cells.first.windows(2).any(|w| w[0] > w[1])
    {
        return Err(format!(
            "cell offsets do not run from 0 to the {} cell triangles over {n} entries",
            cells.triangles.len()
        ));
    }
    if let Some(k) = cells.triangles.iter().position(|t| !t.iter().all(|v| v.is_finite())) {
        return Err(format!("cell triangle {k} has non-finite corners"));
    }
    let texels = p.header.atlas_width as u64 * p.header.atlas_height as u64;
    // Crease points (`Echo::creases`) take the texel numbers past the atlas's, in order.
    let creases = p.echo.creases.len() as u64;
    for (k, l) in p.near.iter().enumerate() {
        if l.texel as u64 >= texels + creases
            || l.entry as usize >= n
            || !(l.factor.is_finite() && l.factor >= 0.0)
        {
            return Err(format!(
                "near-field link {k} is out of range (texel {}, entry {}, factor {})",
                l.texel, l.entry, l.factor
            ));
        }
        if k > 0 && (p.near[k - 1].texel, p.near[k - 1].entry) >= (l.texel, l.entry) {
            return Err(format!("near-field link {k} is out of order"));
        }
        let triangles = (cells.first[l.entry as usize + 1] - cells.first[l.entry as usize]) as usize;
        if triangles < super::HIDDEN_TRIANGLES && l.hidden >> triangles != 0 {
            return Err(format!(
                "near-field link {k} hides triangles past its cell's {triangles} (bits {:#x})",
                l.hidden
            ));
        }
    }
    let runs: Vec<u32> = p.near.chunk_by(|a, b| a.texel == b.texel).map(|r| r[0].texel).collect();
    if runs.len() != p.near_points.len() {
        return Err(format!(
            "{} texels have near-field links but {} points are given",
            runs.len(),
            p.near_points.len()
        ));
    }
    for (k, (pt, &texel)) in p.near_points.iter().zip(&runs).enumerate() {
        if pt.texel != texel {
            return Err(format!(
                "near-field point {k} is for texel {} but its links are texel {texel}'s",
                pt.texel
            ));
        }
        if !pt.position.is_finite() || !pt.normal.is_finite() || (pt.normal.length() - 1.0).abs() > 1e-3 {
            return Err(format!(
                "near-field point {k} is not a point with a unit normal ({}, {})",
                pt.position, pt.normal
            ));
        }
    }
    let first_crease =
        p.near_points.len().checked_sub(creases as usize).ok_or_else(|| {
            format!("{creases} crease points but {} near-field points", p.near_points.len())
        })?;
    for (k, pt) in p.near_points.iter().enumerate() {
        let crease = k >= first_crease;
        if crease != (pt.texel as u64 >= texels)
            || (crease && pt.texel as u64 != texels + (k - first_crease) as u64)
        {
            return Err(format!(
                "near-field point {k} has texel {} where {first_crease} texels' points and {creases} crease points are given",
                pt.texel
            ));
        }
    }
    if let Some(k) = p.echo.creases.iter().position(|&c| c as usize >= first_crease) {
        return Err(format!(
            "crease point {k} lies on near-field point {}, not a texel's",
            p.echo.creases[k]
        ));
    }
    let echo = &p.echo;
    if (!echo.links.is_empty() || creases > 0) && echo.albedo.len() != p.near_points.len() {
        return Err(format!(
            "the echo has {} albedos for {} near-field points",
            echo.albedo.len(),
            p.near_points.len()
        ));
    }
    if let Some(k) = echo.albedo.iter().position(|a| !(a.cmpge(Vec3::ZERO).all() && a.cmple(Vec3::ONE).all()))
    {
        return Err(format!("echo albedo {k} is not in [0, 1] ({})", echo.albedo[k]));
    }
    let points = p.near_points.len();
    for (k, l) in echo.links.iter().enumerate() {
        if l.receiver as usize >= points
            || l.source as usize >= points
            || l.receiver == l.source
            || !(l.factor.is_finite() && l.factor >= 0.0)
        {
            return Err(format!(
                "echo link {k} is out of range (receiver {}, source {}, factor {})",
                l.receiver, l.source, l.factor
            ));
        }
        if k > 0 && (echo.links[k - 1].receiver, echo.links[k - 1].source) >= (l.receiver, l.source) {
            return Err(format!("echo link {k} is out of order"));
        }
        if l.receiver as usize >= first_crease {
            return Err(format!("echo link {k} lights crease point {}, which is never composed", l.receiver));
        }
    }
    // An entry belongs to one cluster at most: the runtime's per-entry tables name one, and
    // the GPU's per-cluster passes (the lift's, the relay's) write each member's slot once.
    let mut owner: Vec<Option<usize>> = vec![None; n];
    for (k, c) in p.clusters.iter().enumerate() {
        if let Some(bad) = c.members.iter().find(|&&m| m as usize >= n) {
            return Err(format!("cluster {k}'s member {bad} is not an entry (there are {n})"));
        }
        for &m in &c.members {
            if let Some(other) = owner[m as usize].replace(k) {
                return Err(format!("entry {m} is a member of cluster {other} and of cluster {k}"));
            }
        }
    }
    Ok(())
}

/// Every tile names a pane that exists and an atlas tile inside the grid, with a usable scale.
fn tiles(p: &PrmParts) -> Result<(), String> {
    let h = &p.header;
    let panes = p.clusters.len() as u64 + p.groups.len() as u64;
    let grid = (h.atlas_width.div_ceil(h.tile_size) as u64) * (h.atlas_height.div_ceil(h.tile_size) as u64);
    for (k, tile) in p.tiles.iter().enumerate() {
        if tile.cluster as u64 >= panes
            || tile.index as u64 >= grid
            || !tile.scale.is_finite()
            || tile.scale.min_element() < 0.0
        {
            return Err(format!(
                "tile {k} is out of range (cluster {}, index {}, scale {})",
                tile.cluster, tile.index, tile.scale
            ));
        }
    }
    Ok(())
}

/// The panes' tile ranges hold only their own tiles and together cover every tile (the runtime
/// reads tiles by pane id, the CPU twin by range: a stray tile would make them disagree), one
/// tile per atlas index each.
fn ranges(p: &PrmParts) -> Result<(), String> {
    let n = p.tiles.len() as u64;
    let owns = |first: u32, count: u32, pane: u64| {
        first as u64 + count as u64 <= n
            && p.tiles[first as usize..(first + count) as usize].iter().all(|t| t.cluster as u64 == pane)
    };
    for (k, c) in p.clusters.iter().enumerate() {
        if !owns(c.first_tile, c.tile_count, k as u64) {
            return Err(format!("cluster {k}'s tile range is wrong"));
        }
    }
    let base = p.clusters.len() as u64;
    for (g, gr) in p.groups.iter().enumerate() {
        let energy_ok = gr.energy.is_finite() && gr.energy >= 0.0;
        if !energy_ok || !owns(gr.first_tile, gr.tile_count, base + g as u64) {
            return Err(format!("group {g} has a bad energy or tile range"));
        }
    }
    let covered: u64 = p
        .clusters
        .iter()
        .map(|c| c.tile_count as u64)
        .chain(p.groups.iter().map(|g| g.tile_count as u64))
        .sum();
    if covered != n {
        return Err(format!("the panes' tile ranges cover {covered} of {n} tiles"));
    }
    let mut seen = HashSet::with_capacity(p.tiles.len());
    if let Some(k) = p.tiles.iter().position(|t| !seen.insert((t.cluster, t.index))) {
        return Err(format!(
            "tile {k} repeats atlas tile {} of pane {}",
            p.tiles[k].index, p.tiles[k].cluster
        ));
    }
    Ok(())
}

/// The far field: empty, or block offsets for the entries' blocks running up to the pairs,
/// each block's pairs naming blocks in ascending order, a block's bits per pair, a finite reach
/// and radius, texels in atlas order with finite points, unit normals, entries in range and
/// weights >= 0 summing to 1, a finite energy >= 0 per entry, and (v17) none or one finite area
/// >= 0 per texel.
fn far(p: &PrmParts) -> Result<(), String> {
    let (f, h, n) = (&p.far, &p.header, p.entries.len());
    if f.texels.is_empty() && f.block_first.is_empty() && f.pair_block.is_empty() && f.visible.is_empty() {
        return match (f.energy.len(), f.areas.len()) {
            (0, 0) => Ok(()),
            (e, a) => Err(format!("{e} far-field energies and {a} texel areas without a far field")),
        };
    }
    if f.texels.is_empty() {
        return Err("a far field without texels".into());
    }
    let blocks = Far::blocks(n);
    let first = &f.block_first;
    if first.len() != blocks + 1
        || first[0] != 0
        || first.windows(2).any(|w| w[0] > w[1])
        || first[blocks] as usize != f.pair_block.len()
    {
        return Err(format!(
            "far-field block offsets ({}) do not run over {blocks} blocks' pairs",
            first.len()
        ));
    }
    for a in 0..blocks {
        let run = &f.pair_block[first[a] as usize..first[a + 1] as usize];
        for (k, &b) in run.iter().enumerate() {
            if b as usize >= blocks || (k > 0 && run[k - 1] >= b) {
                return Err(format!(
                    "far-field pair {} names block {b} (of {blocks}, ascending in each block)",
                    first[a] as usize + k
                ));
            }
        }
    }
    if f.visible.len() != f.pair_block.len() * Far::BLOCK || f.visible.len() > u32::MAX as usize {
        return Err(format!(
            "{} far-field visibility words for {} pairs of blocks",
            f.visible.len(),
            f.pair_block.len()
        ));
    }
    if !(f.radius.is_finite() && f.radius >= 0.0) {
        return Err(format!("far-field radius {} is not finite and >= 0", f.radius));
    }
    if !(f.reach.is_finite() && f.reach >= 0.0) {
        return Err(format!("far-field reach {} is not finite and >= 0", f.reach));
    }
    if f.energy.len() != n {
        return Err(format!("{} far-field energies for {n} entries", f.energy.len()));
    }
    if let Some(j) = f.energy.iter().position(|e| !(e.is_finite() && *e >= 0.0)) {
        return Err(format!("far-field energy of entry {j} is {} (not finite and >= 0)", f.energy[j]));
    }
    let atlas = h.atlas_width as u64 * h.atlas_height as u64;
    for (k, t) in f.texels.iter().enumerate() {
        let ok = (t.texel as u64) < atlas
            && (k == 0 || f.texels[k - 1].texel < t.texel)
            && t.position.is_finite()
            && (t.normal.length() - 1.0).abs() < 1e-3
            && t.entries.iter().all(|&e| (e as usize) < n)
            && t.weights.iter().all(|w| w.is_finite() && *w >= 0.0)
            && (t.weights.iter().sum::<f32>() - 1.0).abs() < 1e-3;
        if !ok {
            return Err(format!("far-field texel {k} is out of range, out of order or not finite"));
        }
    }
    if !f.areas.is_empty() && f.areas.len() != f.texels.len() {
        return Err(format!("{} far-field texel areas for {} texels", f.areas.len(), f.texels.len()));
    }
    if let Some(k) = f.areas.iter().position(|a| !(a.is_finite() && *a >= 0.0)) {
        return Err(format!("far-field texel {k}'s area is {} (not finite and >= 0)", f.areas[k]));
    }
    Ok(())
}
