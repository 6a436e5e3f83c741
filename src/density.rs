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
/// Largest atlas side chosen from a density (one page; levels that need more must give a
/// larger texel size).
pub const MAX_DENSITY_ATLAS: u32 = 8192;
/// Fraction of the atlas generated UVs are assumed to cover.
pub const UNWRAP_COVERAGE: f64 = 0.5;

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
    let coverage = if coverage.is_finite() { coverage.clamp(1e-3, 1.0) } else { 1.0 };
    let texels = area.max(0.0) / (texel_size as f64).powi(2) / coverage;
    let side = texels.sqrt().ceil();
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

/// The atlas side for a loaded level at `texel_size`: the one its UVs were generated for, or
/// from its authored UVs' coverage.
pub fn atlas_side(scene: &Scene, texel_size: f32) -> Result<u32, String> {
    match scene.report.generated_atlas {
        Some(side) => Ok(side),
        None => atlas_for_area(scene.total_area(), uv_coverage(scene), texel_size),
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
    fn absurd_sizes_are_refused() {
        assert!(atlas_for_area(1e9, 1.0, 0.01).unwrap_err().contains("limit"));
        assert!(atlas_for_area(100.0, 1.0, f32::NAN).unwrap_err().contains("texel size"));
        assert!(atlas_for_area(100.0, 1.0, 0.0).is_err());
    }
}
