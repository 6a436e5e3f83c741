//! Light rigs (DESIGN.md §8): the lights of a level over time, as JSON.
//!
//! ```json
//! {
//!   "duration": 2.0,
//!   "lights": [
//!     { "name": "nave_lamp",
//!       "keyframes": [ { "time": 0.0, "position": [-3, 5, -3] },
//!                      { "time": 2.0, "position": [3, 5, -3], "intensity": 30 } ] },
//!     { "name": "torch", "type": "point", "position": [1, 1, 0],
//!       "color": [1, 0.6, 0.3], "intensity": 5 },
//!     { "name": "dais_spot", "enabled": false }
//!   ]
//! }
//! ```
//!
//! - A light whose `name` is one of the level's glTF lights starts from that light; any of
//!   `type`, `position`, `direction`, `color`, `intensity`, `inner_cone_deg`, `outer_cone_deg`,
//!   `range` overrides it. A light with a new name must give `type` (`point`, `spot`,
//!   `directional`) and what that type needs. Units as in glTF (DESIGN.md §3): point and spot
//!   `color x intensity` in W/sr, directional in W/m²; cone angles in degrees.
//! - `keyframes` (times in seconds, strictly increasing) animate `position`, `direction`,
//!   `color`, `intensity`; values are linear between keyframes (directions renormalised) and
//!   held before the first and after the last. A keyframe gives only what changes.
//! - glTF lights the rig does not name keep their glTF values; `"enabled": false` switches one
//!   off.
//! - `objects` move the level's movable nodes (glTF node extras `{"prm": {"movable": true}}`):
//!   `{ "name": NODE, "keyframes": [ { "time": s, "translation": [x, y, z], "rotation":
//!   [x, y, z, w] } ] }`. The motion is in the node's own frame, on top of its transform in the
//!   file (a rotation turns the object about the node's origin: put a door's node on its
//!   hinge); translation is linear and rotation slerped between keyframes, held outside them.
//!   An unknown node, a node not marked movable, a rotation that is not a unit quaternion or a
//!   motion that is not rigid in world space is an error naming the object
//!   ([`Rig::object_motion`] checks it against the level).
//! - Frame i of F samples time `duration x i / (F - 1)` (`duration` defaults to the last
//!   keyframe time, or 0).
//!
//! Errors name the light and field: an unknown light without a type, non-finite numbers,
//! negative intensity or colour, bad cone angles, keyframes out of order, more than
//! [`MAX_LIGHTS`] lights.

use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};
use serde::Deserialize;

use crate::light::{Light, LightKind};

/// Most lights a rig (with the level's) may have; the runtime sizes its buffers for it.
pub const MAX_LIGHTS: usize = 64;

#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("{path}: cannot read the rig: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a valid rig: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("{path}: light '{light}': {what}")]
    Light { path: PathBuf, light: String, what: String },
    #[error("{path}: {count} lights; the limit is {MAX_LIGHTS}")]
    TooMany { path: PathBuf, count: usize },
    #[error("{path}: object '{object}': {what}")]
    Object { path: PathBuf, object: String, what: String },
    #[error("{path}: a rig is a JSON object with \"lights\" and/or \"objects\"")]
    NotAnObject { path: PathBuf },
    #[error("{path}: duration {value} must be finite and >= 0")]
    Duration { path: PathBuf, value: f64 },
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    #[serde(default)]
    duration: Option<f64>,
    #[serde(default)]
    lights: Vec<RigLight>,
    #[serde(default)]
    objects: Vec<RigObject>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigObject {
    name: String,
    keyframes: Vec<ObjectKeyframe>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectKeyframe {
    time: f64,
    #[serde(default)]
    translation: Option<[f64; 3]>,
    #[serde(default)]
    rotation: Option<[f64; 4]>,
}

#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct State {
    #[serde(default)]
    position: Option<[f64; 3]>,
    #[serde(default)]
    direction: Option<[f64; 3]>,
    #[serde(default)]
    color: Option<[f64; 3]>,
    #[serde(default)]
    intensity: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigLight {
    name: String,
    #[serde(default, rename = "type")]
    kind: Option<String>,
    #[serde(default = "yes")]
    enabled: bool,
    #[serde(default)]
    inner_cone_deg: Option<f64>,
    #[serde(default)]
    outer_cone_deg: Option<f64>,
    #[serde(default)]
    range: Option<f64>,
    #[serde(flatten)]
    state: State,
    #[serde(default)]
    keyframes: Vec<Keyframe>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
struct Keyframe {
    time: f64,
    #[serde(flatten)]
    state: State,
}

/// One light of a rig with its animation.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimatedLight {
    /// The light at rest (time before the first keyframe uses the first keyframe).
    pub base: Light,
    /// (time, position, direction, colour x intensity) samples, time strictly increasing.
    pub keys: Vec<(f64, Vec3, Vec3, Vec3)>,
}

/// One movable object of a rig with its keyframes, in the node's own frame (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct AnimatedObject {
    /// The glTF node's name ([`crate::scene::Movable::name`]).
    pub name: String,
    /// (time, translation, unit rotation), time strictly increasing.
    pub keys: Vec<(f64, Vec3, Quat)>,
}

/// The lights (and movable objects) of a level over time.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub lights: Vec<AnimatedLight>,
    /// Movable objects the rig moves, by node name; checked against a level by
    /// [`Rig::object_motion`].
    pub objects: Vec<AnimatedObject>,
    pub duration: f64,
}

impl Rig {
    /// The level's own lights, unanimated.
    pub fn from_lights(lights: &[Light]) -> Rig {
        Rig {
            lights: lights.iter().map(|l| AnimatedLight { base: l.clone(), keys: Vec::new() }).collect(),
            objects: Vec::new(),
            duration: 0.0,
        }
    }

    /// Read a rig file against the level's glTF lights.
    pub fn load(path: &Path, level: &[Light]) -> Result<Rig, RigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| RigError::Io { path: path.into(), source })?;
        Self::parse(path, &text, level)
    }

    /// Parse rig JSON (`path` only for messages).
    pub fn parse(path: &Path, text: &str, level: &[Light]) -> Result<Rig, RigError> {
        // serde reads a struct from an array too, so `[]` would be a rig that changes nothing.
        if !text.trim_start().starts_with('{') {
            return Err(RigError::NotAnObject { path: path.into() });
        }
        let file: RigFile =
            serde_json::from_str(text).map_err(|source| RigError::Json { path: path.into(), source })?;
        let mut out: Vec<Option<AnimatedLight>> =
            level.iter().map(|l| Some(AnimatedLight { base: l.clone(), keys: Vec::new() })).collect();
        let mut last_key = 0.0f64;
        for rl in &file.lights {
            let bad = |what: String| RigError::Light { path: path.into(), light: rl.name.clone(), what };
            let slot = level.iter().position(|l| l.name == rl.name);
            let mut light = match (slot, &rl.kind) {
                (Some(i), _) => level[i].clone(),
                (None, Some(_)) => Light::point(&rl.name, Vec3::ZERO, Vec3::ONE),
                (None, None) => {
                    let names: Vec<&str> = level.iter().map(|l| l.name.as_str()).collect();
                    return Err(bad(format!(
                        "no such light in the level (it has: {}) and no \"type\" to make a new one",
                        names.join(", ")
                    )));
                }
            };
            if let Some(k) = &rl.kind {
                light.kind = match k.as_str() {
                    "point" => LightKind::Point,
                    "directional" => LightKind::Directional,
                    "spot" => LightKind::Spot { inner: 0.0, outer: std::f32::consts::FRAC_PI_4 },
                    other => return Err(bad(format!("unknown type '{other}' (point, spot or directional)"))),
                };
            }
            if let LightKind::Spot { inner, outer } = light.kind {
                let inner = rl.inner_cone_deg.map_or(inner as f64, f64::to_radians);
                let outer = rl.outer_cone_deg.map_or(outer as f64, f64::to_radians);
                if !(inner.is_finite()
                    && outer.is_finite()
                    && 0.0 <= inner
                    && inner <= outer
                    && outer <= std::f64::consts::FRAC_PI_2 + 1e-9)
                {
                    return Err(bad(format!(
                        "cone angles inner {:.3} / outer {:.3} degrees must satisfy 0 <= \
                        inner <= outer <= 90",
                        inner.to_degrees(),
                        outer.to_degrees()
                    )));
                }
                light.kind = LightKind::Spot {
                    inner: inner as f32,
                    outer: (outer as f32).min(std::f32::consts::FRAC_PI_2),
                };
            } else if rl.inner_cone_deg.is_some() || rl.outer_cone_deg.is_some() {
                return Err(bad("cone angles given for a light that is not a spot".into()));
            }
            if let Some(r) = rl.range {
                if !(r.is_finite() && r > 0.0) {
                    return Err(bad(format!("range {r} must be positive")));
                }
                light.range = Some(r as f32);
            }
            let colour = apply(&mut light, &rl.state, None).map_err(&bad)?;
            let mut keys = Vec::new();
            let mut prev = f64::NEG_INFINITY;
            let mut current = light.clone();
            let mut current_colour = colour;
            for (k, kf) in rl.keyframes.iter().enumerate() {
                if !(kf.time.is_finite() && kf.time > prev) {
                    return Err(bad(format!(
                        "keyframe {k}: time {} must be finite and later than the one before",
                        kf.time
                    )));
                }
                prev = kf.time;
                current_colour = apply(&mut current, &kf.state, Some(current_colour))
                    .map_err(|w| bad(format!("keyframe {k}: {w}")))?;
                keys.push((kf.time, current.position, current.direction, current.intensity));
            }
            last_key = last_key.max(prev.max(0.0));
            let anim = if rl.enabled { Some(AnimatedLight { base: light, keys }) } else { None };
            match slot {
                Some(i) => out[i] = anim,
                None => out.push(anim),
            }
        }
        let objects = file.objects.iter().map(|o| parse_object(path, o)).collect::<Result<Vec<_>, _>>()?;
        for o in &objects {
            last_key = last_key.max(o.keys.last().map_or(0.0, |k| k.0));
        }
        let lights: Vec<AnimatedLight> = out.into_iter().flatten().collect();
        if lights.len() > MAX_LIGHTS {
            return Err(RigError::TooMany { path: path.into(), count: lights.len() });
        }
        let duration = file.duration.unwrap_or(last_key);
        if !(duration.is_finite() && duration >= 0.0) {
            return Err(RigError::Duration { path: path.into(), value: duration });
        }
        Ok(Rig { lights, objects, duration })
    }

    /// The rig's object motion bound to a level's movables: an unknown node, a node not marked
    /// movable, one named twice, or a motion that is not rigid in world space (a node with a
    /// non-uniform scale turned by a rotation) is an error naming it.
    pub fn object_motion(&self, path: &Path, scene: &crate::Scene) -> Result<Motion, RigError> {
        let mut per_movable: Vec<Vec<(f64, Vec3, Quat)>> = vec![Vec::new(); scene.movables.len()];
        for o in &self.objects {
            let bad = |what: String| RigError::Object { path: path.into(), object: o.name.clone(), what };
            let Some(k) = scene.movables.iter().position(|m| m.name == o.name) else {
                let movables: Vec<&str> = scene.movables.iter().map(|m| m.name.as_str()).collect();
                let listed = if movables.is_empty() { "none".into() } else { movables.join(", ") };
                return Err(bad(if scene.node_names.contains(&o.name) {
                    format!(
                        "the node is not marked movable (extras {{\"prm\": {{\"movable\": true}}}}); \
                        movable nodes: {listed}"
                    )
                } else {
                    format!("no such node in the level (movable nodes: {listed})")
                }));
            };
            if !per_movable[k].is_empty() {
                return Err(bad("named twice".into()));
            }
            let rest = scene.movables[k].rest;
            for (i, key) in o.keys.iter().enumerate() {
                let delta = world_delta(rest, key.1, key.2);
                if !is_rigid(delta) {
                    return Err(bad(format!(
                        "keyframe {i}: the motion is not rigid in world space (the node's own \
                        transform has a non-uniform scale or shear)"
                    )));
                }
            }
            per_movable[k] = o.keys.clone();
        }
        let rests = scene.movables.iter().map(|m| m.rest).collect();
        Ok(Motion { keys: per_movable, rests })
    }

    /// The lights at time `t` (seconds).
    pub fn at_time(&self, t: f64) -> Vec<Light> {
        self.lights.iter().map(|a| a.at_time(t)).collect()
    }

    /// The lights of frame `i` of `frames`.
    pub fn frame(&self, i: usize, frames: usize) -> Vec<Light> {
        self.at_time(self.frame_time(i, frames))
    }

    /// The time of frame `i` of `frames`, seconds.
    pub fn frame_time(&self, i: usize, frames: usize) -> f64 {
        if frames > 1 {
            self.duration * i as f64 / (frames - 1) as f64
        } else {
            0.0
        }
    }
}

/// Parse one object's keyframes: times strictly increasing, translation finite, rotation a unit
/// quaternion (within 1e-3; renormalised). A keyframe without one holds the one before.
fn parse_object(path: &Path, o: &RigObject) -> Result<AnimatedObject, RigError> {
    let bad = |what: String| RigError::Object { path: path.into(), object: o.name.clone(), what };
    if o.keyframes.is_empty() {
        return Err(bad("no keyframes".into()));
    }
    let mut keys = Vec::with_capacity(o.keyframes.len());
    let (mut prev, mut t, mut r) = (f64::NEG_INFINITY, Vec3::ZERO, Quat::IDENTITY);
    for (k, kf) in o.keyframes.iter().enumerate() {
        if !(kf.time.is_finite() && kf.time > prev) {
            return Err(bad(format!(
                "keyframe {k}: time {} must be finite and later than the one before",
                kf.time
            )));
        }
        prev = kf.time;
        if let Some(v) = kf.translation {
            if !v.iter().all(|x| x.is_finite() && x.abs() < 1e9) {
                return Err(bad(format!("keyframe {k}: translation {v:?} is not finite")));
            }
            t = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32);
        }
        if let Some(q) = kf.rotation {
            let len = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(q.iter().all(|x| x.is_finite()) && (len - 1.0).abs() <= 1e-3) {
                return Err(bad(format!(
                    "keyframe {k}: rotation {q:?} is not a unit quaternion [x, y, z, w] (length {len:.4})"
                )));
            }
            r = Quat::from_xyzw(q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32).normalize();
        }
        keys.push((kf.time, t, r));
    }
    Ok(AnimatedObject { name: o.name.clone(), keys })
}

/// The world-space motion of an object at rest at `rest` moved by `translation` and `rotation`
/// in its own frame: rest x T x R x rest⁻¹.
fn world_delta(rest: Mat4, translation: Vec3, rotation: Quat) -> Mat4 {
    rest * Mat4::from_rotation_translation(rotation, translation) * rest.inverse()
}

/// Whether a transform's linear part is a rotation (orthonormal, no mirror) within 1e-3.
fn is_rigid(m: Mat4) -> bool {
    let l = glam::Mat3::from_mat4(m);
    let g = l.transpose() * l;
    m.is_finite()
        && (g - glam::Mat3::IDENTITY).to_cols_array().iter().all(|x| x.abs() < 1e-3)
        && l.determinant() > 0.0
}

/// The movable objects' motion over time, bound to a level ([`Rig::object_motion`]).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Motion {
    /// Per movable, its keyframes (empty: it stays at rest).
    pub keys: Vec<Vec<(f64, Vec3, Quat)>>,
    rests: Vec<Mat4>,
}

impl Motion {
    /// No object moves (a level's movables at rest).
    pub fn at_rest(scene: &crate::Scene) -> Motion {
        Motion {
            keys: vec![Vec::new(); scene.movables.len()],
            rests: scene.movables.iter().map(|m| m.rest).collect(),
        }
    }

    /// Whether any object moves.
    pub fn moves(&self) -> bool {
        self.keys.iter().any(|k| !k.is_empty())
    }

    /// Per movable, the rigid world-space transform from its rest pose to its pose at time `t`:
    /// translation linear and rotation slerped between keyframes, held outside them.
    pub fn at_time(&self, t: f64) -> Vec<Mat4> {
        self.keys
            .iter()
            .zip(&self.rests)
            .map(|(keys, &rest)| {
                let Some(first) = keys.first() else { return Mat4::IDENTITY };
                let (tr, rot) = if t <= first.0 {
                    (first.1, first.2)
                } else if let Some(w) = keys.windows(2).find(|w| t <= w[1].0) {
                    let s = ((t - w[0].0) / (w[1].0 - w[0].0)) as f32;
                    (w[0].1.lerp(w[1].1, s), w[0].2.slerp(w[1].2, s))
                } else {
                    let last = keys[keys.len() - 1];
                    (last.1, last.2)
                };
                world_delta(rest, tr, rot)
            })
            .collect()
    }
}

impl AnimatedLight {
    /// This light at time `t`.
    pub fn at_time(&self, t: f64) -> Light {
        let mut l = self.base.clone();
        let Some(first) = self.keys.first() else { return l };
        let (pos, dir, int) = if t <= first.0 {
            (first.1, first.2, first.3)
        } else if let Some(k) = self.keys.windows(2).find(|w| t <= w[1].0) {
            let (a, b) = (&k[0], &k[1]);
            let s = ((t - a.0) / (b.0 - a.0)) as f32;
            (a.1.lerp(b.1, s), a.2.lerp(b.2, s).try_normalize().unwrap_or(b.2), a.3.lerp(b.3, s))
        } else {
            let last = self.keys[self.keys.len() - 1];
            (last.1, last.2, last.3)
        };
        l.position = pos;
        l.direction = dir;
        l.intensity = int;
        l
    }
}

/// Apply a state's fields to a light; returns the colour in use (intensity is stored as
/// colour x intensity, so the colour must be remembered to rescale).
fn apply(light: &mut Light, s: &State, colour: Option<Vec3>) -> Result<Vec3, String> {
    // Finite in f32 too: 1e39 passes as an f64 and is infinite once stored.
    let v3 = |name: &str, v: [f64; 3]| -> Result<Vec3, String> {
        let f = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32);
        if f.is_finite() {
            Ok(f)
        } else {
            Err(format!("{name} {v:?} is not finite (as a 32-bit float)"))
        }
    };
    if let Some(p) = s.position {
        light.position = v3("position", p)?;
    }
    if let Some(d) = s.direction {
        light.direction = v3("direction", d)?.try_normalize().ok_or("direction is zero")?;
    }
    // Split the stored colour x intensity into the two so either can change alone.
    let old_colour = colour.unwrap_or_else(|| {
        let m = light.intensity.max_element();
        if m > 0.0 {
            light.intensity / m
        } else {
            Vec3::ONE
        }
    });
    let old_intensity = light.intensity.max_element() / old_colour.max_element().max(f32::MIN_POSITIVE);
    let new_colour = match s.color {
        Some(c) => {
            let c = v3("color", c)?;
            if c.min_element() < 0.0 {
                return Err(format!("color {c} is negative"));
            }
            c
        }
        None => old_colour,
    };
    let new_intensity = match s.intensity {
        Some(i) if !((i as f32).is_finite() && i >= 0.0) => {
            return Err(format!("intensity {i} is negative or not finite (as a 32-bit float)"))
        }
        Some(i) => i as f32,
        None => old_intensity,
    };
    light.intensity = new_colour * new_intensity;
    light.check()?;
    Ok(new_colour)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level() -> Vec<Light> {
        vec![Light {
            name: "lamp".into(),
            kind: LightKind::Point,
            position: Vec3::new(0.0, 2.0, 0.0),
            direction: -Vec3::Y,
            intensity: Vec3::new(10.0, 5.0, 2.5),
            range: None,
            aperture: Default::default(),
            profile: None,
        }]
    }

    fn parse(text: &str) -> Result<Rig, RigError> {
        Rig::parse(Path::new("rig.json"), text, &level())
    }

    #[test]
    fn keyframes_interpolate_and_hold() {
        let rig = parse(
            r#"{"lights": [{"name": "lamp", "keyframes": [
            {"time": 0, "position": [-1, 2, 0]}, {"time": 2, "position": [1, 2, 0], "intensity": 20}]}]}"#,
        )
        .unwrap();
        assert_eq!(rig.duration, 2.0);
        let mid = rig.at_time(1.0);
        assert!((mid[0].position - Vec3::new(0.0, 2.0, 0.0)).length() < 1e-6);
        // Colour (1, 0.5, 0.25) kept; intensity 10 -> 20 halfway is 15.
        assert!((mid[0].intensity - Vec3::new(15.0, 7.5, 3.75)).length() < 1e-4, "{}", mid[0].intensity);
        assert_eq!(rig.at_time(-5.0)[0].position, Vec3::new(-1.0, 2.0, 0.0));
        assert_eq!(rig.at_time(9.0)[0].position, Vec3::new(1.0, 2.0, 0.0));
        let frames: Vec<Vec3> = (0..3).map(|i| rig.frame(i, 3)[0].position).collect();
        assert_eq!(frames[1], Vec3::new(0.0, 2.0, 0.0));
    }

    #[test]
    fn new_lights_overrides_and_switching_off() {
        let rig = parse(r#"{"lights": [
            {"name": "spot", "type": "spot", "position": [0, 3, 0], "direction": [0, -2, 0], "inner_cone_deg": 10, "outer_cone_deg": 20, "intensity": 4},
            {"name": "lamp", "color": [0, 1, 0]}]}"#).unwrap();
        assert_eq!(rig.lights.len(), 2);
        assert_eq!(rig.lights[0].base.intensity, Vec3::new(0.0, 10.0, 0.0));
        let spot = &rig.lights[1].base;
        assert!(
            matches!(spot.kind, LightKind::Spot { inner, outer } if (inner - 10f32.to_radians()).abs() < 1e-6 && (outer - 20f32.to_radians()).abs() < 1e-6)
        );
        assert_eq!(spot.direction, -Vec3::Y);
        let off = parse(r#"{"lights": [{"name": "lamp", "enabled": false}]}"#).unwrap();
        assert!(off.lights.is_empty());
        // Without a rig entry the level's light stays as it is.
        assert_eq!(parse(r#"{"lights": []}"#).unwrap().lights[0].base, level()[0]);
    }

    #[test]
    fn bad_rigs_name_the_light_and_the_field() {
        let cases = [
            (r#"{"lights": [{"name": "ghost"}]}"#, "no such light"),
            ("[]", "a rig is a JSON object"),
            (r#"[{"name": "lamp"}]"#, "a rig is a JSON object"),
            (r#"{"lights": [{"name": "lamp", "position": [1, 1e999, 0]}]}"#, "not a valid rig"),
            (r#"{"lights": [{"name": "lamp", "intensity": -3}]}"#, "intensity -3"),
            (r#"{"lights": [{"name": "lamp", "keyframes": [{"time": 1}, {"time": 1}]}]}"#, "keyframe 1"),
            (
                r#"{"lights": [{"name": "s", "type": "spot", "inner_cone_deg": 30, "outer_cone_deg": 20}]}"#,
                "cone angles",
            ),
            (r#"{"lights": [{"name": "s", "type": "laser"}]}"#, "unknown type"),
            (r#"{"lights": [{"name": "lamp", "direction": [0, 0, 0]}]}"#, "direction is zero"),
            (r#"{"lights": [{"name": "lamp", "colour": [1, 1, 1]}]}"#, "unknown field"),
            (r#"{"lights": "#, "not a valid rig"),
            // Finite as f64, infinite as the f32 a light holds: refused, not baked to infinity.
            (r#"{"lights": [{"name": "lamp", "intensity": 1e39}]}"#, "not finite (as a 32-bit float)"),
            (r#"{"lights": [{"name": "lamp", "position": [1e39, 0, 0]}]}"#, "position"),
            (r#"{"lights": [{"name": "lamp", "direction": [1e300, 1e300, 0]}]}"#, "not finite"),
            (r#"{"lights": [{"name": "lamp", "intensity": 2e9}]}"#, "beyond 1e9"),
            (r#"{"lights": [{"name": "lamp", "position": [2e7, 0, 0]}]}"#, "beyond 1e7 m"),
        ];
        for (text, want) in cases {
            let err = parse(text).unwrap_err().to_string();
            assert!(err.contains(want) && err.contains("rig.json"), "{text}: {err}");
        }
        let many: Vec<String> = (0..70).map(|i| format!(r#"{{"name": "l{i}", "type": "point"}}"#)).collect();
        let err = parse(&format!(r#"{{"lights": [{}]}}"#, many.join(","))).unwrap_err();
        assert!(matches!(err, RigError::TooMany { count: 71, .. }), "{err}");
    }
}
