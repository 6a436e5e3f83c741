//! Photometric emission profiles: IES LM-63 (`.ies`) and EULUMDAT (`.ldt`) files, type C.
//!
//! A profile is a table of intensity over two angles around the light's axis (paper 001 §3.2,
//! "an arbitrary spherical profile, IES/LDT photometries as used in lighting design"):
//! gamma from the nadir (0 = along the light's `direction`, pi = straight back) and the C
//! angle around the axis (0 along the light's C0 reference, 90 degrees counter-clockwise seen
//! from behind the light, i.e. looking along its axis from above a downlight). Intensity
//! between the tabulated angles is bilinear; outside the tabulated gamma range it is zero (a
//! downlight measured 0-90 degrees sends nothing up). Symmetric files (one C plane, a quadrant,
//! a half) are folded, not expanded.
//!
//! The table is used **relative to its peak**: the light's `intensity` (W/sr, DESIGN.md §3) is
//! the intensity along its brightest direction. Candela and lumen figures in the file (the
//! multiplier, lamp flux, cd/klm) only scale the peak and so drop out; the file gives the
//! shape, the level gives the brightness, as for every other light.
//!
//! The shape is also integrated and tabulated for sampling on a fixed grid of
//! [`GRID_GAMMA`] x [`GRID_C`] cells, uniform in cos gamma and C: photons leave a profiled
//! light with nearly equal flux each, as paper 001 §3.3 wants of every path.
//!
//! We parse these formats ourselves: the maintained crate for them is AGPL-licensed and the
//! MIT one stops with `todo!()` on type A/B files and panics on an empty table, where a level
//! designer's bad file must get an error that names the problem.

use std::f32::consts::{PI, TAU};
use std::path::Path;

use glam::Vec3;

/// Sampling grid: cells in cos gamma.
pub const GRID_GAMMA: usize = 90;
/// Sampling grid: cells in C.
pub const GRID_C: usize = 72;

/// How the file's C planes cover the circle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Symmetry {
    /// One plane: the same in every C.
    Axial,
    /// C 0-90, mirrored about the C0-C180 and C90-C270 planes.
    Quadrant,
    /// C 0-180, mirrored about the C0-C180 plane.
    HalfC0,
    /// C 90-270, mirrored about the C90-C270 plane.
    HalfC90,
    /// The whole circle.
    Full,
}

/// A bad photometric file.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{format} photometry: {what}")]
pub struct PhotometryError {
    /// "IES" or "EULUMDAT".
    pub format: &'static str,
    pub what: String,
}

/// A type C intensity table, relative to its peak.
#[derive(Clone, Debug, PartialEq)]
pub struct Photometry {
    /// Gamma angles, radians, ascending, within [0, pi].
    gamma: Vec<f32>,
    /// C angles of the stored planes, radians, ascending.
    c: Vec<f32>,
    /// `c.len()` planes of `gamma.len()` values, divided by the peak (so in [0, 1]).
    values: Vec<f32>,
    symmetry: Symmetry,
    /// The file's peak intensity in its own units (candela or cd/klm): information only.
    pub peak: f32,
    /// Integral of the relative intensity over the sphere (sr); `intensity x` this is a
    /// profiled point light's flux.
    pub solid_integral: f32,
    /// Cumulative sampling weights of the grid cells (cos gamma major), ending at 1.
    cdf: Vec<f32>,
}

impl Photometry {
    /// A table from its angles (degrees) and planes of values; checks everything a file can
    /// get wrong.
    pub fn new(
        format: &'static str,
        gamma_deg: &[f32],
        c_deg: &[f32],
        planes: &[Vec<f32>],
    ) -> Result<Photometry, PhotometryError> {
        let bad = |what: String| PhotometryError { format, what };
        if gamma_deg.is_empty() || c_deg.is_empty() {
            return Err(bad("no angles".into()));
        }
        let ascending = |a: &[f32]| a.iter().all(|x| x.is_finite()) && a.windows(2).all(|w| w[0] < w[1]);
        if !ascending(gamma_deg) || gamma_deg[0] < 0.0 || gamma_deg[gamma_deg.len() - 1] > 180.0 {
            return Err(bad(format!("vertical angles {gamma_deg:?} must ascend within 0-180 degrees")));
        }
        if !ascending(c_deg) || c_deg[0] < 0.0 || c_deg[c_deg.len() - 1] > 360.0 {
            return Err(bad(format!("horizontal angles {c_deg:?} must ascend within 0-360 degrees")));
        }
        let (first, last) = (c_deg[0], c_deg[c_deg.len() - 1]);
        let symmetry = match (c_deg.len(), first, last) {
            (1, _, _) => Symmetry::Axial,
            (_, 0.0, 90.0) => Symmetry::Quadrant,
            (_, 0.0, 180.0) => Symmetry::HalfC0,
            (_, 90.0, 270.0) => Symmetry::HalfC90,
            (_, 0.0, _) if last > 180.0 => Symmetry::Full,
            _ => {
                return Err(bad(format!(
                "horizontal angles {first}-{last} degrees: expected one plane, 0-90, 0-180, 90-270 or 0-360"
            )))
            }
        };
        if planes.len() != c_deg.len() || planes.iter().any(|p| p.len() != gamma_deg.len()) {
            return Err(bad(format!(
                "{} planes of {:?} values for {} horizontal and {} vertical angles",
                planes.len(),
                planes.iter().map(Vec::len).collect::<Vec<_>>(),
                c_deg.len(),
                gamma_deg.len()
            )));
        }
        let flat: Vec<f32> = planes.concat();
        if let Some(v) = flat.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(bad(format!("intensity {v} is negative or not finite")));
        }
        let peak = flat.iter().copied().fold(0.0f32, f32::max);
        if !(peak > 0.0) {
            return Err(bad("every intensity is zero".into()));
        }
        let mut p = Photometry {
            gamma: gamma_deg.iter().map(|g| g.to_radians()).collect(),
            c: c_deg.iter().map(|c| c.to_radians()).collect(),
            values: flat.iter().map(|v| v / peak).collect(),
            symmetry,
            peak,
            solid_integral: 0.0,
            cdf: Vec::new(),
        };
        p.tabulate();
        Ok(p)
    }

    /// Fill the sampling grid: each cell's weight is its solid angle times the relative
    /// intensity averaged over 4 x 4 points in it.
    fn tabulate(&mut self) {
        let cell = 2.0 / GRID_GAMMA as f32 * (TAU / GRID_C as f32);
        let mut cdf = Vec::with_capacity(GRID_GAMMA * GRID_C);
        let mut sum = 0.0f64;
        for i in 0..GRID_GAMMA {
            for j in 0..GRID_C {
                let mut w = 0.0f32;
                for a in 0..4 {
                    for b in 0..4 {
                        let z = 1.0 - 2.0 * (i as f32 + (a as f32 + 0.5) / 4.0) / GRID_GAMMA as f32;
                        let c = TAU * (j as f32 + (b as f32 + 0.5) / 4.0) / GRID_C as f32;
                        w += self.relative(z.clamp(-1.0, 1.0).acos(), c);
                    }
                }
                sum += (w / 16.0 * cell) as f64;
                cdf.push(sum as f32);
            }
        }
        self.solid_integral = sum as f32;
        for x in &mut cdf {
            *x /= sum as f32;
        }
        self.cdf = cdf;
    }

    /// Relative intensity (in [0, 1]) at `gamma` from the nadir and horizontal angle `c`
    /// (radians).
    pub fn relative(&self, gamma: f32, c: f32) -> f32 {
        let g = &self.gamma;
        if !(gamma >= g[0] && gamma <= g[g.len() - 1]) {
            return 0.0;
        }
        let (gi, gt) = bracket(g, gamma);
        let row = |plane: usize| {
            let v = &self.values[plane * g.len()..(plane + 1) * g.len()];
            if gi + 1 < g.len() {
                v[gi] * (1.0 - gt) + v[gi + 1] * gt
            } else {
                v[gi]
            }
        };
        let c = c.rem_euclid(TAU);
        let folded = match self.symmetry {
            Symmetry::Axial => return row(0),
            Symmetry::Full => c,
            Symmetry::HalfC0 => {
                if c > PI {
                    TAU - c
                } else {
                    c
                }
            }
            Symmetry::HalfC90 => {
                // Mirror about the C90-C270 plane: C -> 180 - C.
                if !(0.5 * PI..=1.5 * PI).contains(&c) {
                    (PI - c).rem_euclid(TAU)
                } else {
                    c
                }
            }
            Symmetry::Quadrant => {
                let h = if c > PI { TAU - c } else { c };
                if h > 0.5 * PI {
                    PI - h
                } else {
                    h
                }
            }
        };
        let cs = &self.c;
        if self.symmetry == Symmetry::Full && folded > cs[cs.len() - 1] {
            // Between the last plane and the first one again, a full turn on.
            let span = cs[0] + TAU - cs[cs.len() - 1];
            let t = (folded - cs[cs.len() - 1]) / span;
            return row(cs.len() - 1) * (1.0 - t) + row(0) * t;
        }
        if folded <= cs[0] {
            return row(0);
        }
        let (ci, ct) = bracket(cs, folded);
        if ci + 1 < cs.len() {
            row(ci) * (1.0 - ct) + row(ci + 1) * ct
        } else {
            row(ci)
        }
    }

    /// Relative intensity towards world direction `dir` (unit) of a light pointing along
    /// `axis` (unit) with C0 reference `c0` (unit, perpendicular to `axis`).
    pub fn towards(&self, dir: Vec3, axis: Vec3, c0: Vec3) -> f32 {
        let (gamma, c) = angles(dir, axis, c0);
        self.relative(gamma, c)
    }

    /// Sample a direction in proportion to the relative intensity (to the grid's resolution):
    /// the world direction and its solid-angle density. `u` uniform in [0, 1)^3.
    pub fn sample(&self, axis: Vec3, c0: Vec3, u: [f32; 3]) -> (Vec3, f32) {
        let k = self.cdf.partition_point(|&x| x <= u[0]).min(self.cdf.len() - 1);
        let lo = if k == 0 { 0.0 } else { self.cdf[k - 1] };
        let (i, j) = (k / GRID_C, k % GRID_C);
        let z = 1.0 - 2.0 * (i as f32 + u[1]) / GRID_GAMMA as f32;
        let c = TAU * (j as f32 + u[2]) / GRID_C as f32;
        let cell = 2.0 / GRID_GAMMA as f32 * (TAU / GRID_C as f32);
        let pdf = (self.cdf[k] - lo) / cell;
        (direction(z.clamp(-1.0, 1.0), c, axis, c0), pdf)
    }

    /// Solid-angle density of [`Photometry::sample`] along `dir`.
    pub fn pdf(&self, dir: Vec3, axis: Vec3, c0: Vec3) -> f32 {
        let (gamma, c) = angles(dir, axis, c0);
        let z = gamma.cos();
        let i = (((1.0 - z) / 2.0 * GRID_GAMMA as f32) as usize).min(GRID_GAMMA - 1);
        let j = ((c.rem_euclid(TAU) / TAU * GRID_C as f32) as usize).min(GRID_C - 1);
        let k = i * GRID_C + j;
        let lo = if k == 0 { 0.0 } else { self.cdf[k - 1] };
        (self.cdf[k] - lo) / (2.0 / GRID_GAMMA as f32 * (TAU / GRID_C as f32))
    }

    /// Read an `.ies` or `.ldt` / `.eul` file, by its extension.
    pub fn load(path: &Path) -> Result<Photometry, PhotometryError> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let format = if ext == "ies" { "IES" } else { "EULUMDAT" };
        let bytes = std::fs::read(path)
            .map_err(|e| PhotometryError { format, what: format!("{}: {e}", path.display()) })?;
        // Photometric files are ASCII in practice, Latin-1 in old ones: keep what decodes.
        let text = String::from_utf8_lossy(&bytes);
        let parsed = match ext.as_str() {
            "ies" => parse_ies(&text),
            "ldt" | "eul" => parse_ldt(&text),
            _ => {
                return Err(PhotometryError {
                    format: "photometric",
                    what: format!("{}: expected a .ies, .ldt or .eul file", path.display()),
                })
            }
        };
        parsed.map_err(|e| PhotometryError {
            format: e.format,
            what: format!("{}: {}", path.display(), e.what),
        })
    }
}

/// (gamma from `axis`, C from `c0`) of unit `dir`, radians.
fn angles(dir: Vec3, axis: Vec3, c0: Vec3) -> (f32, f32) {
    let c90 = c0.cross(axis);
    let gamma = dir.dot(axis).clamp(-1.0, 1.0).acos();
    let c = dir.dot(c90).atan2(dir.dot(c0)).rem_euclid(TAU);
    (gamma, c)
}

/// The world direction at cos gamma `z` and horizontal angle `c`.
fn direction(z: f32, c: f32, axis: Vec3, c0: Vec3) -> Vec3 {
    let c90 = c0.cross(axis);
    let r = (1.0 - z * z).max(0.0).sqrt();
    (axis * z + c0 * (r * c.cos()) + c90 * (r * c.sin())).normalize()
}

/// Index i and fraction t with `a[i] <= x < a[i + 1]` (the last index at the end).
fn bracket(a: &[f32], x: f32) -> (usize, f32) {
    let i = a.partition_point(|&v| v <= x).saturating_sub(1).min(a.len() - 1);
    if i + 1 < a.len() {
        (i, ((x - a[i]) / (a[i + 1] - a[i])).clamp(0.0, 1.0))
    } else {
        (i, 0.0)
    }
}

/// Numbers separated by blanks or commas.
fn numbers<'a>(
    format: &'static str,
    text: impl Iterator<Item = &'a str>,
) -> Result<Vec<f32>, PhotometryError> {
    let mut out = Vec::new();
    for tok in text.flat_map(|l| l.split(|c: char| c.is_whitespace() || c == ',')).filter(|t| !t.is_empty()) {
        out.push(
            tok.parse::<f32>()
                .map_err(|_| PhotometryError { format, what: format!("'{tok}' is not a number") })?,
        );
    }
    Ok(out)
}

/// Parse an IES LM-63 file (1986, 1991, 1995, 2002, 2019), type C photometry.
pub fn parse_ies(text: &str) -> Result<Photometry, PhotometryError> {
    let bad = |what: String| PhotometryError { format: "IES", what };
    let lines: Vec<&str> = text.lines().collect();
    let tilt = lines
        .iter()
        .position(|l| l.trim_start().starts_with("TILT="))
        .ok_or_else(|| bad("no TILT= line".into()))?;
    let mut nums = numbers("IES", lines[tilt + 1..].iter().copied())?.into_iter();
    let mut next = |what: &str| nums.next().ok_or_else(|| bad(format!("the file ends before {what}")));
    if lines[tilt].trim() == "TILT=INCLUDE" {
        // Lamp-to-luminaire geometry, then n angles and n multipliers: not used (the lamp's
        // tilt in the luminaire is fixed for a game light).
        next("the tilt geometry")?;
        let n = next("the tilt angle count")?;
        if !(0.0..=1e4).contains(&n) {
            return Err(bad(format!("tilt angle count {n}")));
        }
        for _ in 0..2 * n as usize {
            next("the tilt table")?;
        }
    } else if lines[tilt].trim() != "TILT=NONE" {
        return Err(bad(format!("'{}': a tilt file of its own is not supported", lines[tilt].trim())));
    }
    let _lamps = next("the lamp count")?;
    let _lumens = next("the lumens per lamp")?;
    let multiplier = next("the candela multiplier")?;
    let nv = next("the vertical angle count")?;
    let nh = next("the horizontal angle count")?;
    let kind = next("the photometric type")?;
    for what in [
        "the units",
        "the width",
        "the length",
        "the height",
        "the ballast factor",
        "the file type",
        "the watts",
    ] {
        next(what)?;
    }
    if kind != 1.0 {
        return Err(bad(format!("photometric type {kind}: only type C (1) is supported")));
    }
    let count = |n: f32, what: &str| {
        if (1.0..=1e4).contains(&n) && n.fract() == 0.0 {
            Ok(n as usize)
        } else {
            Err(bad(format!("{what} count {n}")))
        }
    };
    let (nv, nh) = (count(nv, "vertical angle")?, count(nh, "horizontal angle")?);
    if !(multiplier.is_finite() && multiplier > 0.0) {
        return Err(bad(format!("candela multiplier {multiplier} must be positive")));
    }
    let take =
        |it: &mut dyn Iterator<Item = f32>, n: usize, what: &str| -> Result<Vec<f32>, PhotometryError> {
            let v: Vec<f32> = it.take(n).collect();
            if v.len() < n {
                return Err(bad(format!("the file ends in {what} ({} of {n})", v.len())));
            }
            Ok(v)
        };
    let gamma = take(&mut nums, nv, "the vertical angles")?;
    let c = take(&mut nums, nh, "the horizontal angles")?;
    let mut planes = Vec::with_capacity(nh);
    for k in 0..nh {
        planes.push(take(&mut nums, nv, &format!("the candela values of plane {k}"))?);
    }
    if nums.next().is_some() {
        return Err(bad("numbers left over after the candela table".into()));
    }
    // IES files list C = 360 for the full circle; the plane at 360 is the one at 0 again.
    let (c, planes) = if c.len() > 1 && c[c.len() - 1] == 360.0 && c[0] == 0.0 {
        (c[..c.len() - 1].to_vec(), planes[..planes.len() - 1].to_vec())
    } else {
        (c, planes)
    };
    Photometry::new("IES", &gamma, &c, &planes)
}

/// Parse a EULUMDAT file (type indicator 1-3, symmetry 0-4).
pub fn parse_ldt(text: &str) -> Result<Photometry, PhotometryError> {
    let bad = |what: String| PhotometryError { format: "EULUMDAT", what };
    let lines: Vec<&str> = text.lines().collect();
    let field = |k: usize, what: &str| -> Result<f32, PhotometryError> {
        let line = lines.get(k - 1).ok_or_else(|| bad(format!("the file ends before line {k} ({what})")))?;
        line.trim()
            .replace(',', ".")
            .parse()
            .map_err(|_| bad(format!("line {k} ({what}): '{}' is not a number", line.trim())))
    };
    let sym = field(3, "symmetry")?;
    let mc = field(4, "number of C planes")?;
    let ng = field(6, "number of gamma angles")?;
    let sets = field(26, "number of lamp sets")?;
    let count = |n: f32, what: &str, max: f32| {
        if (1.0..=max).contains(&n) && n.fract() == 0.0 {
            Ok(n as usize)
        } else {
            Err(bad(format!("{what} {n}")))
        }
    };
    let (mc, ng, sets) = (
        count(mc, "number of C planes", 721.0)?,
        count(ng, "number of gamma angles", 361.0)?,
        count(sets, "number of lamp sets", 100.0)?,
    );
    // After the 26 header lines: 6 lines per lamp set, then 10 direct ratios.
    let start = 26 + 6 * sets + 10;
    if lines.len() < start {
        return Err(bad(format!("the file ends in its header ({} of {start} lines)", lines.len())));
    }
    let nums = numbers("EULUMDAT", lines[start..].iter().map(|l| l.trim()))?;
    let (stored, first) = match sym as i32 {
        _ if sym.fract() != 0.0 => return Err(bad(format!("symmetry {sym}"))),
        0 => (mc, 0),
        1 => (1, 0),
        2 => (mc / 2 + 1, 0),
        3 => (mc / 2 + 1, mc / 4),
        4 => (mc / 4 + 1, 0),
        _ => return Err(bad(format!("symmetry {sym}: expected 0-4"))),
    };
    let need = mc + ng + stored * ng;
    if nums.len() < need {
        return Err(bad(format!("{} numbers after the header, {need} needed", nums.len())));
    }
    let (c_all, rest) = nums.split_at(mc);
    let (gamma, table) = rest.split_at(ng);
    if first + stored > mc {
        return Err(bad(format!("symmetry {sym} with {mc} C planes")));
    }
    let c = if sym as i32 == 1 { vec![0.0] } else { c_all[first..first + stored].to_vec() };
    let planes: Vec<Vec<f32>> = table[..stored * ng].chunks(ng).map(<[f32]>::to_vec).collect();
    Photometry::new("EULUMDAT", gamma, &c, &planes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An IES file of a downlight with I(gamma) = cos gamma below the horizon, given on
    /// `c` planes.
    fn cosine_ies(c: &[f32]) -> String {
        let gammas: Vec<f32> = (0..=18).map(|k| k as f32 * 5.0).collect();
        let row: Vec<String> =
            gammas.iter().map(|g| format!("{:.6}", 1000.0 * g.to_radians().cos().max(0.0))).collect();
        let mut s = String::from("IESNA:LM-63-2002\n[TEST] cosine\nTILT=NONE\n");
        s += &format!("1 1000 1 {} {} 1 2 0 0 0\n1 1 100\n", gammas.len(), c.len());
        s += &gammas.iter().map(|g| g.to_string()).collect::<Vec<_>>().join(" ");
        s += "\n";
        s += &c.iter().map(|g| g.to_string()).collect::<Vec<_>>().join(", ");
        s += "\n";
        for _ in c {
            s += &row.join(" ");
            s += "\n";
        }
        s
    }

    /// A Lambertian downlight's intensity integrates to pi sr (relative to its peak); the
    /// grid's cells are 2 degrees in gamma near the axis, so the bilinear cos and the 4 x 4
    /// cell average hold that to 0.5 %. Every symmetry gives the same table.
    #[test]
    fn a_cosine_downlight_integrates_to_pi_under_every_symmetry() {
        for c in [
            &[0.0][..],
            &[0.0, 45.0, 90.0],
            &[0.0, 90.0, 180.0],
            &[90.0, 180.0, 270.0],
            &[0.0, 90.0, 180.0, 270.0, 360.0],
        ] {
            let p = parse_ies(&cosine_ies(c)).unwrap();
            assert!((p.solid_integral - PI).abs() < 5e-3 * PI, "{c:?}: {}", p.solid_integral);
            for (g, cc) in [(0.3f32, 0.0f32), (1.0, 2.0), (1.2, 4.0), (0.7, 5.9)] {
                assert!((p.relative(g, cc) - g.cos()).abs() < 4e-3, "{c:?} {g} {cc}");
            }
            assert_eq!(p.relative(1.7, 1.0), 0.0, "nothing above the horizon");
        }
    }

    /// Sampling: the density is the intensity over its integral to the grid's resolution: a
    /// cell spans 2/90 in cos gamma, so cos (the relative intensity here) varies by at most
    /// that over a cell and the density by that over the integral.
    #[test]
    fn sampling_follows_the_intensity() {
        let p = parse_ies(&cosine_ies(&[0.0])).unwrap();
        let (axis, c0) = (-Vec3::Y, Vec3::X);
        let mut rng = 12345u64;
        let mut u = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..2000 {
            let (d, pdf) = p.sample(axis, c0, [u(), u(), u()]);
            assert!((d.length() - 1.0).abs() < 1e-5);
            assert!(d.dot(axis) >= -1e-6, "a downlight sends nothing up: {d}");
            let rel = p.towards(d, axis, c0);
            assert!((pdf - p.pdf(d, axis, c0)).abs() <= 1e-3 * pdf);
            // pdf = rel / solid_integral up to the cell's spread.
            let want = rel / p.solid_integral;
            let spread = 2.0 / GRID_GAMMA as f32 / p.solid_integral;
            assert!((pdf - want).abs() <= spread * 1.01, "{pdf} vs {want} at {d}");
        }
    }

    /// The same shape as a EULUMDAT file (cd/klm, symmetry 1 and 4) reads as the same table.
    #[test]
    fn eulumdat_reads_like_ies() {
        let gammas: Vec<f32> = (0..=18).map(|k| k as f32 * 5.0).collect();
        let ldt = |sym: u32, mc: usize| {
            let mut l = vec![
                "Maker".to_string(),
                "1".into(),
                sym.to_string(),
                mc.to_string(),
                (360 / mc).to_string(),
                gammas.len().to_string(),
                "5".into(),
            ];
            l.extend((8..=25).map(|_| "0".to_string()));
            l.push("1".into()); // lamp sets
            l.extend(["1", "LED", "1000", "3000", "80", "10"].map(String::from));
            l.extend((0..10).map(|_| "0.5".to_string()));
            l.extend((0..mc).map(|k| (k * 360 / mc).to_string()));
            l.extend(gammas.iter().map(|g| g.to_string()));
            let stored = if sym == 1 { 1 } else { mc / 4 + 1 };
            for _ in 0..stored {
                l.extend(gammas.iter().map(|g| format!("{}", 300.0 * g.to_radians().cos().max(0.0))));
            }
            l.join("\r\n")
        };
        for (sym, mc) in [(1, 1), (4, 8)] {
            let p = parse_ldt(&ldt(sym, mc)).unwrap();
            assert!((p.solid_integral - PI).abs() < 5e-3 * PI, "sym {sym}: {}", p.solid_integral);
            assert!((p.relative(0.9, 2.5) - 0.9f32.cos()).abs() < 4e-3);
        }
    }

    #[test]
    fn bad_files_are_named() {
        let good = cosine_ies(&[0.0]);
        let cases = [
            (good.replace("TILT=NONE", "TILT=lamp.tlt"), "tilt file"),
            (good.replace("TILT=NONE\n", ""), "no TILT"),
            (good.replace("1 1000 1 19 1 1", "1 1000 1 19 1 3"), "type C"),
            (good.replace("1 1000 1 19 1 1", "1 1000 1 0 1 1"), "vertical angle count"),
            (good[..good.len() - 40].to_string(), "ends in the candela values"),
            (good.replace("0 5 10", "0 10 5"), "must ascend"),
            (good.replace("1000.000000", "nan"), "not finite"),
            (good.replace("1000.000000", "-3"), "negative"),
            (good.replace("1000.000000", "1e3x"), "not a number"),
            (good.clone() + " 7", "left over"),
        ];
        for (text, want) in cases {
            let e = parse_ies(&text).unwrap_err();
            assert!(e.to_string().contains(want), "{e} should say {want}");
        }
        let dark = Photometry::new("IES", &[0.0, 90.0], &[0.0], &[vec![0.0, 0.0]]).unwrap_err();
        assert!(dark.to_string().contains("every intensity is zero"), "{dark}");
        let odd = Photometry::new("IES", &[0.0, 90.0], &[0.0, 45.0], &[vec![1.0, 0.0], vec![1.0, 0.0]]);
        assert!(odd.unwrap_err().to_string().contains("expected one plane"));
        assert!(parse_ldt("Maker\n1\n9\n1").unwrap_err().to_string().contains("line"));
        assert!(parse_ldt("").unwrap_err().to_string().contains("ends"));
    }
}
