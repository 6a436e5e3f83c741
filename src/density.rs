//! Lightmap density: how many atlas texels a level gets when no size is given, from a texel
//! size in metres, so a level of one room and one of a hundred get the same texels per square
//! metre (issue 13).
//!
//! The side is the smallest multiple of [`ATLAS_STEP`] whose covered texels, at the level's
//! UV coverage, are at least `area / texel_size^2`, and never below [`MIN_ATLAS`]: a small
//! level keeps the resolution it always had (the bundled one-room levels stay at 256^2).
//! Authored UVs (`TEXCOORD_1`) cover the fraction of the atlas their triangles' UV areas sum
//! to; generated ones are assumed to cover [`UNWRAP_COVERAGE`] (uvunwrap packing zone by zone,
//! `crate::zones`, covers 49-52 % of the atlas it packs the bundled halls into).

use crate::scene::Scene;

/// Default world size of a lightmap texel, in metres: the bundled chamber's at 256^2.
pub const DEFAULT_TEXEL_SIZE: f32 = 0.18;
/// Smallest atlas side chosen from a density.
pub const MIN_ATLAS: u32 = 256;
/// Atlas sides chosen from a density are multiples of this (a whole number of pane tiles).
pub const ATLAS_STEP: u32 = 16;
/// Largest atlas side chosen from a density for authored UVs (one page), and largest page side.
pub const MAX_DENSITY_ATLAS: u32 = 8192;
/// Fraction of the atlas generated UVs are assumed to cover.
pub const UNWRAP_COVERAGE: f64 = 0.5;
/// Default side of a page of generated lightmap UVs, in texels.
pub const DEFAULT_PAGE_SIZE: u32 = 1024;
/// Most pages an atlas may have (the layers wgpu guarantees a texture array).
pub const MAX_PAGES: u32 = 256;

/// A lightmap atlas: `pages` square pages of `side` x `side` texels (issue 13).
///
/// Every per-texel image of the project (texel sets, panes, the `.prm` mask, EXR images in
/// memory) holds the pages **stacked** down one image `side` wide and `side x pages` tall: page
/// p is rows `p side .. (p + 1) side`, and a lightmap UV's v runs over the whole stack, so a
/// texel's (page, x, y) is (row / side, column, row % side). Generated UVs never split a chart
/// across pages, and uvunwrap keeps charts 2 texels from every page edge, so no filter or
/// bilinear lookup of a chart reads another page. Authored UVs are one page. The runtime's
/// lightmap is a texture array of the pages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Atlas {
    /// Width and height of a page, in texels.
    pub side: u32,
    /// Number of pages.
    pub pages: u32,
}

impl Atlas {
    /// One square page.
    pub const fn single(side: u32) -> Atlas {
        Atlas { side, pages: 1 }
    }

    /// Width of the stacked image: a page's side.
    pub const fn width(self) -> u32 {
        self.side
    }

    /// Height of the stacked image: the pages' sides end to end.
    pub const fn height(self) -> u32 {
        self.side * self.pages
    }

    /// Texels of the stacked image.
    pub fn texels(self) -> u64 {
        self.width() as u64 * self.height() as u64
    }
}

impl std::fmt::Display for Atlas {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.pages {
            1 => write!(f, "{}^2", self.side),
            n => write!(f, "{n} pages of {}^2", self.side),
        }
    }
}

/// A page size for generated UVs: a multiple of [`ATLAS_STEP`], 64 to [`MAX_DENSITY_ATLAS`].
pub fn check_page_size(page_size: u32) -> Result<(), String> {
    if (64..=MAX_DENSITY_ATLAS).contains(&page_size) && page_size % ATLAS_STEP == 0 {
        Ok(())
    } else {
        Err(format!(
            "page size {page_size} must be a multiple of {ATLAS_STEP} from 64 to {MAX_DENSITY_ATLAS} texels"
        ))
    }
}

/// How generated lightmap UVs are laid out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum UnwrapLayout {
    /// One square page of this side, at the highest density that fits it.
    OnePage(u32),
    /// As many pages of `page_size`^2 as the charts need at `texel_size` metres a texel.
    Pages { texel_size: f32, page_size: u32 },
}

/// The layout generated UVs get for `area` square metres at `texel_size`: one page of the side
/// [`atlas_for_area`] gives (the levels that fit a page keep the layout they always had), else
/// pages of `page_size`^2 at exactly that texel size. Errors name the limit a level exceeds.
pub fn unwrap_layout(area: f64, texel_size: f32, page_size: u32) -> Result<UnwrapLayout, String> {
    check_texel_size(texel_size)?;
    check_page_size(page_size)?;
    let side = side_for_area(area, UNWRAP_COVERAGE, texel_size);
    if side <= page_size as f64 {
        return Ok(UnwrapLayout::OnePage(
            ((side / ATLAS_STEP as f64).ceil() as u32 * ATLAS_STEP).max(MIN_ATLAS.min(page_size)),
        ));
    }
    let pages = (side / page_size as f64).powi(2).ceil();
    if !(pages <= MAX_PAGES as f64) {
        return Err(format!(
            "{area:.0} m^2 at {texel_size} m texels needs about {pages:.0} pages of {page_size}^2, over the \
             {MAX_PAGES} limit; give a larger texel size or --page-size"
        ));
    }
    Ok(UnwrapLayout::Pages { texel_size, page_size })
}

/// The (unbounded, unrounded) side of a square atlas giving `area` texels of `texel_size` at
/// `coverage`.
fn side_for_area(area: f64, coverage: f64, texel_size: f32) -> f64 {
    let coverage = if coverage.is_finite() { coverage.clamp(1e-3, 1.0) } else { 1.0 };
    let texels = area.max(0.0) / (texel_size as f64).powi(2) / coverage;
    texels.sqrt().ceil()
}

/// A texel size the density may use: finite, 1 mm to 100 m.
pub fn check_texel_size(texel_size: f32) -> Result<(), String> {
    if texel_size.is_finite() && (1e-3..=100.0).contains(&texel_size) {
        Ok(())
    } else {
        Err(format!("texel size {texel_size} must be 0.001 to 100 metres"))
    }
}

/// The atlas side that gives `area` square metres texels of `texel_size` metres when the
/// lightmap UVs cover `coverage` of the atlas. Errors when that exceeds [`MAX_DENSITY_ATLAS`].
pub fn atlas_for_area(area: f64, coverage: f64, texel_size: f32) -> Result<u32, String> {
    check_texel_size(texel_size)?;
    let side = side_for_area(area, coverage, texel_size);
    let steps = (side / ATLAS_STEP as f64).ceil();
    if !(steps * ATLAS_STEP as f64 <= MAX_DENSITY_ATLAS as f64) {
        return Err(format!(
            "{area:.0} m^2 at {texel_size} m texels needs a {side:.0}^2 atlas, over the {MAX_DENSITY_ATLAS}^2 \
             limit; give a larger texel size or an explicit --atlas"
        ));
    }
    Ok((steps as u32 * ATLAS_STEP).max(MIN_ATLAS))
}

/// Fraction of the unit UV square the level's lightmap UVs cover: the sum of its triangles'
/// UV areas, at most 1.
pub fn uv_coverage(scene: &Scene) -> f64 {
    let sum: f64 = (0..scene.triangles.len())
        .map(|t| {
            let [a, b, c] = scene.uv1_corners(t);
            0.5 * ((b - a).perp_dot(c - a) as f64).abs()
        })
        .sum();
    sum.min(1.0)
}

/// The atlas for a loaded level at `texel_size`: the one its UVs were generated for, or one
/// page sized from its authored UVs' coverage.
pub fn atlas(scene: &Scene, texel_size: f32) -> Result<Atlas, String> {
    match scene.report.generated_atlas {
        Some(atlas) => Ok(atlas),
        None => atlas_for_area(scene.total_area(), uv_coverage(scene), texel_size).map(Atlas::single),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_gives_the_texel_size_asked_for() {
        // 10,000 m^2 at 0.25 m texels, full coverage: 160,000 texels, a 400^2 atlas.
        assert_eq!(atlas_for_area(10_000.0, 1.0, 0.25), Ok(400));
        // Half coverage needs twice the texels: 565.7 -> 576 (a multiple of 16).
        assert_eq!(atlas_for_area(10_000.0, 0.5, 0.25), Ok(576));
        // Four times the area, twice the side.
        assert_eq!(atlas_for_area(40_000.0, 1.0, 0.25), Ok(800));
        // A small level keeps the floor.
        assert_eq!(atlas_for_area(5.0, 0.6, 0.18), Ok(MIN_ATLAS));
    }

    #[test]
    fn a_level_larger_than_a_page_gets_pages_at_the_texel_size() {
        // 10,000 m^2 at 0.25 m, half coverage: a 566^2 square fits a 1024 page, as before.
        assert_eq!(unwrap_layout(10_000.0, 0.25, 1024), Ok(UnwrapLayout::OnePage(576)));
        // It does not fit 256^2 pages: pages at exactly the texel size asked for.
        assert_eq!(
            unwrap_layout(10_000.0, 0.25, 256),
            Ok(UnwrapLayout::Pages { texel_size: 0.25, page_size: 256 })
        );
        // A small level keeps the floor, or the page when that is smaller.
        assert_eq!(unwrap_layout(5.0, 0.18, 1024), Ok(UnwrapLayout::OnePage(MIN_ATLAS)));
        assert_eq!(unwrap_layout(5.0, 0.18, 128), Ok(UnwrapLayout::OnePage(128)));
        // More pages than a texture array holds, and pages of no sensible size, are refused.
        assert!(unwrap_layout(1e9, 0.01, 1024).unwrap_err().contains("pages"));
        for bad in [0, 48, 100, 16384] {
            assert!(unwrap_layout(100.0, 0.18, bad).unwrap_err().contains("page size"), "{bad}");
        }
        let a = Atlas { side: 64, pages: 3 };
        assert_eq!((a.width(), a.height(), a.texels()), (64, 192, 64 * 192));
        assert_eq!(a.to_string(), "3 pages of 64^2");
        assert_eq!(Atlas::single(256).to_string(), "256^2");
    }

    #[test]
    fn absurd_sizes_are_refused() {
        assert!(atlas_for_area(1e9, 1.0, 0.01).unwrap_err().contains("limit"));
        assert!(atlas_for_area(100.0, 1.0, f32::NAN).unwrap_err().contains("texel size"));
        assert!(atlas_for_area(100.0, 1.0, 0.0).is_err());
    }
}
