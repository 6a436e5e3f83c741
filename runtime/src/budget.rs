//! A GPU memory budget: what to leave out of a map, and how small to make the shadow maps, so
//! that the runtime's tables and shadow maps fit in a given number of bytes.
//!
//! What goes first is what the viewer misses least. The map's receivers are its atlas tiles
//! ([`Prm::without_atlas_tiles`]: every entry stays, so the light reaching a kept texel from any
//! light in the level is unchanged). The caller says where each atlas tile is from the camera
//! ([`TilePlace`]: the engine knows its views; `prm` measures it from the texels). In order:
//!
//! 1. atlas tiles outside the camera's view, the farthest first, only as many as needed;
//! 2. if all of those are not enough, the shadow maps halve (down to [`MIN_SHADOW_SIZE`]; a
//!    size asked below it stays), and step 1 is redone at each size, so no more tiles go than
//!    needed;
//! 3. then tiles in view, the farthest first: a loss the viewer sees, reported as such;
//! 4. if the map's fixed tables (the entries and their cells, the lightmap, the texel slots)
//!    and the smallest shadow maps alone exceed the budget, an error says how much they need.
//!
//! Lights do not rank the receivers: a tile near a light but out of view is not seen, and the
//! light it would have bounced into the kept tiles still arrives through the entries. Each
//! candidate is measured with [`GpuMemory::estimate`], the figure a test holds to what
//! `Runtime::new` allocates; the bytes fall as tiles go, so a bisection finds the fewest.

use prm::prm_file::{Prm, Reduced};

use crate::memory::{shadow_bytes, GpuMemory};

/// The smallest shadow map a budget may choose (texels per side).
pub const MIN_SHADOW_SIZE: u32 = 256;

/// Where one atlas tile's surface is, seen from the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TilePlace {
    /// The nearest of its stored texels to the camera, in metres.
    pub distance: f32,
    /// The camera sees some of its texels (`prm` asks: in the frustum, facing it, unoccluded).
    pub in_view: bool,
}

/// What a budget left out, and what the runtime then needs.
#[derive(Debug)]
pub struct Fit {
    /// The map to run: `None` when the whole map fits.
    pub reduced: Option<Reduced>,
    /// The shadow-map size to run with.
    pub shadow_size: u32,
    /// Bytes of the whole map's tables and shadow maps at the size asked for.
    pub before: u64,
    /// Bytes of the tables and shadow maps now (at most the budget).
    pub after: u64,
    /// Atlas tiles left out in the camera's view (a loss the viewer sees).
    pub in_view: usize,
    /// The nearest left-out tile's distance from the camera, metres (infinite for none).
    pub nearest: f32,
    /// The nearest left-out tile in view, metres (infinite for none).
    pub nearest_in_view: f32,
}

/// Why a budget cannot be met.
#[derive(Debug, thiserror::Error)]
pub enum BudgetError {
    #[error(
        "a GPU memory budget of {budget:.1} MB cannot hold this map: with every atlas tile left out its \
         fixed tables still take {tables:.1} MB (the entries and their cells, the lightmap, the texel \
         slots) and the lights' shadow maps {shadows:.1} MB at {size}^2; give at least {need:.1} MB",
        budget = mb(*budget), tables = mb(*tables), shadows = mb(*shadows), need = mb(tables + shadows)
    )]
    TooSmall { budget: u64, tables: u64, shadows: u64, size: u32 },
    #[error("{place} atlas tile places for a tile grid of {grid}")]
    Places { place: usize, grid: usize },
    #[error("leaving tiles out broke the map: {0}")]
    Invalid(#[from] prm::prm_file::InvalidPrm),
}

/// Bytes in MB (1e6), as budgets are given.
pub fn mb(b: u64) -> f64 {
    b as f64 / 1e6
}

/// Fit `prm` with `lights`' shadow maps of `shadow_size` into `budget` bytes, leaving out
/// atlas tiles and shrinking the shadow maps in the order of the module docs. `places` holds
/// one entry per atlas tile of the grid (row-major).
pub fn fit(
    prm: &Prm,
    places: &[TilePlace],
    lights: &[prm::Light],
    shadow_size: u32,
    sun_tiles: u32,
    budget: u64,
) -> Result<Fit, BudgetError> {
    let shadow_bytes = |lights: &[prm::Light], size: u32| shadow_bytes(lights, size, sun_tiles);
    let grid = (prm.tiles_x() * prm.tiles_y()) as usize;
    if places.len() != grid {
        return Err(BudgetError::Places { place: places.len(), grid });
    }
    let before = GpuMemory::estimate(prm).total() + shadow_bytes(lights, shadow_size);
    if before <= budget {
        return Ok(Fit {
            reduced: None,
            shadow_size,
            before,
            after: before,
            in_view: 0,
            nearest: f32::INFINITY,
            nearest_in_view: f32::INFINITY,
        });
    }
    // Atlas tiles that store texels, out of view first, then the farthest first.
    let layout = prm.layout();
    let mut order: Vec<u32> = (0..grid as u32).filter(|&t| !layout.texels[t as usize].is_empty()).collect();
    order.sort_by(|&a, &b| {
        let (pa, pb) = (places[a as usize], places[b as usize]);
        pa.in_view.cmp(&pb.in_view).then(pb.distance.total_cmp(&pa.distance)).then(a.cmp(&b))
    });
    let out_of_view = order.iter().take_while(|&&t| !places[t as usize].in_view).count();
    let cut = |k: usize| -> Result<(Reduced, u64), BudgetError> {
        let mut drop = vec![false; grid];
        for &t in &order[..k] {
            drop[t as usize] = true;
        }
        let reduced = prm.without_atlas_tiles(&drop)?;
        let tables = GpuMemory::estimate(&reduced.prm).total();
        Ok((reduced, tables))
    };
    // The fewest tiles of order[lo..=hi] whose cut fits with shadow maps of `shadows` bytes.
    let fewest = |lo: usize, hi: usize, shadows: u64| -> Result<Option<(usize, Reduced, u64)>, BudgetError> {
        let (reduced, tables) = cut(hi)?;
        if tables + shadows > budget {
            return Ok(None);
        }
        let (mut lo, mut best) = (lo, (hi, reduced, tables));
        let mut hi = hi;
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            let (reduced, tables) = cut(mid)?;
            if tables + shadows <= budget {
                hi = mid;
                best = (mid, reduced, tables);
            } else {
                lo = mid + 1;
            }
        }
        Ok(Some(best))
    };
    let mut size = shadow_size;
    let found = loop {
        if let Some(f) = fewest(0, out_of_view, shadow_bytes(lights, size))? {
            break Some((f, size));
        }
        // Halving helps only with lights, and not below the smallest size.
        if size <= MIN_SHADOW_SIZE || shadow_bytes(lights, size) == 0 {
            break None;
        }
        size = (size / 2).max(MIN_SHADOW_SIZE);
    };
    let ((k, reduced, tables), size) = match found {
        Some(f) => f,
        None => {
            let shadows = shadow_bytes(lights, size);
            match fewest(out_of_view, order.len(), shadows)? {
                Some(f) => (f, size),
                None => {
                    let (_, tables) = cut(order.len())?;
                    return Err(BudgetError::TooSmall { budget, tables, shadows, size });
                }
            }
        }
    };
    let dropped = &order[..k];
    Ok(Fit {
        after: tables + shadow_bytes(lights, size),
        shadow_size: size,
        before,
        in_view: dropped.iter().filter(|&&t| places[t as usize].in_view).count(),
        nearest: dropped.iter().map(|&t| places[t as usize].distance).fold(f32::INFINITY, f32::min),
        nearest_in_view: dropped
            .iter()
            .filter(|&&t| places[t as usize].in_view)
            .map(|&t| places[t as usize].distance)
            .fold(f32::INFINITY, f32::min),
        reduced: (k > 0).then_some(reduced),
    })
}
