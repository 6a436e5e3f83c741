//! Lightmap UVs (`TEXCOORD_1`): generated for the whole level when a primitive lacks them,
//! then checked on the joined scene (outside [0, 1] is reported, overlap is an error unless
//! allowed).

use std::path::Path;

use super::primitive::Prim;
use super::{LoadOptions, SceneError};
use crate::density::UnwrapLayout;
use crate::scene::{LoadReport, Scene};
use crate::{density, uv};

/// How many primitives have no lightmap UVs; with `require_uv1`, the first one is an error.
pub(super) fn count_missing(path: &Path, prims: &[Prim], opts: &LoadOptions) -> Result<usize, SceneError> {
    let missing: Vec<&Prim> = prims.iter().filter(|p| p.uv1.is_none()).collect();
    if let Some(first) = missing.first() {
        if opts.require_uv1 {
            return Err(SceneError::MissingUv1 { path: path.into(), place: first.place.clone() });
        }
    }
    Ok(missing.len())
}

/// Generate lightmap UVs for every primitive (uvunwrap, packed for the options' resolution) and
/// note it in `report`, whose `primitives_without_uv1` says how many lacked them.
pub(super) fn generate(
    path: &Path,
    prims: &mut [Prim],
    opts: &LoadOptions,
    report: &mut LoadReport,
) -> Result<(), SceneError> {
    let unwrap_error = |reason| SceneError::Unwrap { path: path.into(), reason };
    let mut layout = match opts.unwrap_resolution {
        Some(r) => UnwrapLayout::OnePage(r),
        None => {
            let area = prims.iter().map(Prim::area).sum();
            density::unwrap_layout(area, opts.texel_size, opts.page_size).map_err(unwrap_error)?
        }
    };
    let atlas = match uv::unwrap_primitives(&mut prims_uv_view(prims), layout) {
        // One page was the density's estimate, from a typical packing's coverage; charts that
        // pack worse (small pages, many small charts) get pages at the texel size asked for.
        Err(uv::UnwrapError::MorePages { .. }) if opts.unwrap_resolution.is_none() => {
            layout = UnwrapLayout::Pages { texel_size: opts.texel_size, page_size: opts.page_size };
            uv::unwrap_primitives(&mut prims_uv_view(prims), layout)
        }
        r => r,
    }
    .map_err(|e| unwrap_error(e.to_string()))?;
    report.uv1_generated = true;
    report.generated_atlas = Some(atlas);
    report.generated_layout = Some(layout);
    let why = match layout {
        UnwrapLayout::OnePage(_) if opts.unwrap_resolution.is_some() => String::new(),
        UnwrapLayout::OnePage(_) => format!(", the size {} m texels give the level", opts.texel_size),
        UnwrapLayout::Pages { texel_size, .. } => format!(" at {texel_size} m texels"),
    };
    report.notes.push(format!(
        "{} primitive(s) had no TEXCOORD_1: lightmap UVs were generated for the whole level (uvunwrap, \
            packed into {atlas}{why}, with 2-texel padding)",
        report.primitives_without_uv1
    ));
    Ok(())
}

/// The UV-generation view of the primitives: positions, indices and the UVs to fill.
fn prims_uv_view(prims: &mut [Prim]) -> Vec<uv::UnwrapPrim<'_>> {
    prims
        .iter_mut()
        .map(|p| uv::UnwrapPrim {
            positions: &mut p.positions,
            normals: &mut p.normals,
            uv_albedo: &mut p.uv_albedo,
            indices: &mut p.indices,
            uv1: &mut p.uv1,
        })
        .collect()
}

/// Report triangles with lightmap UVs outside [0, 1]; overlapping lightmap UVs are an error
/// unless the options allow them (then they are reported).
pub(super) fn check(
    path: &Path,
    scene: &Scene,
    opts: &LoadOptions,
    report: &mut LoadReport,
) -> Result<(), SceneError> {
    report.uv_out_of_range = uv::count_out_of_range(scene);
    if report.uv_out_of_range > 0 {
        report.notes.push(format!(
            "{} triangle(s) have lightmap UVs outside [0, 1]; the parts outside get no texels",
            report.uv_out_of_range
        ));
    }
    let overlaps = uv::find_overlaps(scene);
    if let Some(&(a, b)) = overlaps.first() {
        if !opts.allow_overlap {
            return Err(SceneError::UvOverlap {
                path: path.into(),
                first: scene.describe_triangle(a),
                second: scene.describe_triangle(b),
                pairs: overlaps.len(),
            });
        }
        report.uv_overlapping_pairs = overlaps.len();
        report.notes.push(format!(
            "{} pair(s) of triangles overlap in lightmap UV space (allowed): they share texels",
            overlaps.len()
        ));
    }
    Ok(())
}
