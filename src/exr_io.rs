//! EXR files with named float channels, in the DESIGN.md §8 layouts.
//!
//! - Texel set: `P.x P.y P.z N.x N.y N.z mask`.
//! - Lightmaps: `R G B`, or layers such as `indirect.R indirect.G indirect.B`,
//!   `direct.R ...`, `stderr.R ...` in one file, irradiance in W/m².
//!
//! Row 0 of the image is atlas row j = 0 (v = 0). Channels are 32-bit float, ZIP-compressed.
//! Files are written atomically.
//!
//! **Pages.** An atlas of several lightmap pages ([`crate::density::Atlas`]) is one file with a
//! layer set per page: layers `page0`, `page1`, ... each a page's side square, holding the same
//! channels (`page1.indirect.R` ...). Reading such a file stacks the pages back into one image,
//! as every stage holds them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use exr::prelude::*;
use glam::Vec3;

use crate::texels::TexelSet;

/// An EXR read or write failure, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum ExrError {
    #[error("{path}: {source}")]
    Exr { path: PathBuf, source: exr::error::Error },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: no channel named '{name}' (has: {have})")]
    MissingChannel { path: PathBuf, name: String, have: String },
    #[error("{path}: channel '{name}' has {got} values for a {width}x{height} image")]
    BadSize { path: PathBuf, name: String, got: usize, width: usize, height: usize },
}

/// A float image with named channels, each `width * height` values, row-major; `pages`
/// lightmap pages stacked down it (1 for any other image).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Channels {
    pub width: usize,
    pub height: usize,
    pub pages: usize,
    pub channels: BTreeMap<String, Vec<f32>>,
}

/// Layer name of lightmap page `p` in a file of several pages.
fn page_name(p: usize) -> String {
    format!("page{p}")
}

impl Channels {
    pub fn new(width: usize, height: usize) -> Self {
        Channels::paged(width, height, 1)
    }

    /// An image of `pages` lightmap pages stacked down `height` rows (written a layer set per
    /// page).
    pub fn paged(width: usize, height: usize, pages: usize) -> Self {
        Channels { width, height, pages: pages.max(1), channels: BTreeMap::new() }
    }

    /// Add (or replace) a channel.
    pub fn insert(&mut self, name: impl Into<String>, values: Vec<f32>) {
        debug_assert_eq!(values.len(), self.width * self.height);
        self.channels.insert(name.into(), values);
    }

    /// Add `prefix.R`, `prefix.G`, `prefix.B` (or bare `R G B` for an empty prefix).
    pub fn insert_rgb(&mut self, prefix: &str, rgb: &[Vec3]) {
        for (k, c) in ["R", "G", "B"].iter().enumerate() {
            let name = if prefix.is_empty() { c.to_string() } else { format!("{prefix}.{c}") };
            self.insert(name, rgb.iter().map(|v| v[k]).collect());
        }
    }

    /// A channel by exact name.
    pub fn get(&self, name: &str) -> Option<&[f32]> {
        self.channels.get(name).map(|v| &v[..])
    }

    /// An RGB layer (`prefix.R` ...; bare `R G B` for an empty prefix).
    pub fn rgb(&self, prefix: &str) -> Option<Vec<Vec3>> {
        let name = |c: &str| if prefix.is_empty() { c.to_string() } else { format!("{prefix}.{c}") };
        let (r, g, b) = (self.get(&name("R"))?, self.get(&name("G"))?, self.get(&name("B"))?);
        Some((0..r.len()).map(|i| Vec3::new(r[i], g[i], b[i])).collect())
    }

    /// Write as a scanline EXR, atomically: one layer, or a layer set per page.
    pub fn write(&self, path: &Path) -> std::result::Result<(), ExrError> {
        let pages = self.pages.max(1);
        let rows = self.height / pages;
        let part = |p: usize, name: Option<String>| {
            let range = p * rows * self.width..(p + 1) * rows * self.width;
            let list: Vec<AnyChannel<FlatSamples>> = self
                .channels
                .iter()
                .map(|(channel, v)| {
                    AnyChannel::new(channel.as_str(), FlatSamples::F32(v[range.clone()].to_vec()))
                })
                .collect();
            let attributes =
                name.map_or_else(LayerAttributes::default, |n| LayerAttributes::named(n.as_str()));
            Layer::new(
                (self.width, rows),
                attributes,
                Encoding::SMALL_LOSSLESS,
                AnyChannels::sort(SmallVec::from_vec(list)),
            )
        };
        let tmp = crate::fsutil::temp_path(path);
        let written = if pages == 1 {
            Image::from_layer(part(0, None)).write().to_file(&tmp)
        } else {
            let layers: Vec<_> = (0..pages).map(|p| part(p, Some(page_name(p)))).collect();
            let bounds = exr::meta::attribute::IntegerBounds::from_dimensions((self.width, rows));
            Image::from_layers(ImageAttributes::new(bounds), layers).write().to_file(&tmp)
        };
        let result = written.map_err(|source| ExrError::Exr { path: path.into(), source }).and_then(|_| {
            std::fs::rename(&tmp, path).map_err(|source| ExrError::Io { path: path.into(), source })
        });
        if result.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        result
    }

    /// Read every channel of the first layer (layer name prefixes kept, as `layer.channel`); a
    /// file of lightmap pages (layers `page0` .. `pageN` of one size) comes back stacked.
    pub fn read(path: &Path) -> std::result::Result<Channels, ExrError> {
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .all_layers()
            .all_attributes()
            .from_file(path)
            .map_err(|source| ExrError::Exr { path: path.into(), source })?;
        let layers = &image.layer_data;
        let paged = layers.len() > 1
            && layers.iter().enumerate().all(|(p, l)| {
                l.attributes.layer_name.as_ref().is_some_and(|n| n.to_string() == page_name(p))
                    && l.size == layers[0].size
            });
        let mut out = Channels::default();
        for (p, layer) in layers.iter().enumerate() {
            let (w, h) = (layer.size.width(), layer.size.height());
            if out.channels.is_empty() && p == 0 {
                out.width = w;
                out.height = h;
            } else if (w, h) != (out.width, if paged { h } else { out.height }) {
                continue;
            }
            let prefix = match paged {
                true => None,
                false => layer.attributes.layer_name.as_ref().map(|n| format!("{n}.")),
            };
            for ch in &layer.channel_data.list {
                let name = format!("{}{}", prefix.clone().unwrap_or_default(), ch.name);
                let values: Vec<f32> = ch.sample_data.values_as_f32().collect();
                if values.len() != w * h {
                    return Err(ExrError::BadSize {
                        path: path.into(),
                        name,
                        got: values.len(),
                        width: w,
                        height: h,
                    });
                }
                out.channels.entry(name).or_default().extend(values);
            }
        }
        out.pages = if paged { layers.len() } else { 1 };
        out.height *= out.pages;
        if let Some((name, v)) = out.channels.iter().find(|(_, v)| v.len() != out.width * out.height) {
            return Err(ExrError::BadSize {
                path: path.into(),
                name: name.clone(),
                got: v.len(),
                width: out.width,
                height: out.height,
            });
        }
        Ok(out)
    }

    /// A channel by name, or an error listing what the file has.
    pub fn require(&self, path: &Path, name: &str) -> std::result::Result<&[f32], ExrError> {
        self.get(name).ok_or_else(|| ExrError::MissingChannel {
            path: path.into(),
            name: name.into(),
            have: self.channels.keys().cloned().collect::<Vec<_>>().join(" "),
        })
    }
}

/// The texel-set EXR: `P.x P.y P.z N.x N.y N.z mask`, zero where not covered.
pub fn texel_channels(set: &TexelSet) -> Channels {
    let (w, h) = (set.width as usize, set.height as usize);
    let mut ch = Channels::new(w, h);
    let mut p = [vec![0.0; w * h], vec![0.0; w * h], vec![0.0; w * h]];
    let mut n = [vec![0.0; w * h], vec![0.0; w * h], vec![0.0; w * h]];
    let mut mask = vec![0.0; w * h];
    for t in &set.texels {
        let k = t.j as usize * w + t.i as usize;
        for a in 0..3 {
            p[a][k] = t.position[a];
            n[a][k] = t.normal[a];
        }
        mask[k] = 1.0;
    }
    for (a, c) in ["x", "y", "z"].iter().enumerate() {
        ch.insert(format!("P.{c}"), std::mem::take(&mut p[a]));
        ch.insert(format!("N.{c}"), std::mem::take(&mut n[a]));
    }
    ch.insert("mask", mask);
    ch
}
