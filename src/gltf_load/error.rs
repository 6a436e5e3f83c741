//! What can be wrong with a level file, and where in the file it is.

use std::path::PathBuf;

/// Where in the file a problem is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Place {
    pub mesh: usize,
    pub mesh_name: String,
    pub primitive: usize,
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "mesh {} ('{}') primitive {}", self.mesh, self.mesh_name, self.primitive)
    }
}

/// Everything that can be wrong with a level file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: cannot read file: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a valid glTF 2.0 file: {source}")]
    Gltf { path: PathBuf, source: gltf::Error },
    #[error("{path}: {place}: has no POSITION attribute")]
    MissingPositions { path: PathBuf, place: Place },
    #[error("{path}: {place}: {attribute} accessor reads past the end of its buffer")]
    AccessorOutOfBounds { path: PathBuf, place: Place, attribute: &'static str },
    #[error("{path}: {place}: {attribute} of vertex {vertex} is not finite ({value})")]
    NonFinite { path: PathBuf, place: Place, attribute: &'static str, vertex: usize, value: String },
    #[error("{path}: {place}: vertex {vertex} lies at {value}, beyond 1e7 m of the origin (squared distances overflow)")]
    TooFar { path: PathBuf, place: Place, vertex: usize, value: String },
    #[error("{path}: {place}: index {position} is {value}, but the primitive has {vertex_count} vertices")]
    IndexOutOfRange { path: PathBuf, place: Place, position: usize, value: u32, vertex_count: usize },
    #[error("{path}: {place}: {count} indices is not a whole number of triangles")]
    PartialTriangle { path: PathBuf, place: Place, count: usize },
    #[error("{path}: material {material} ('{name}'): albedo {value:?} is outside [0, 1]")]
    AlbedoOutOfRange { path: PathBuf, material: usize, name: String, value: [f32; 3] },
    #[error(
        "{path}: material {material} ('{name}'): emissive {value:?} is negative, not finite or beyond 1e9"
    )]
    BadEmissive { path: PathBuf, material: usize, name: String, value: [f32; 3] },
    #[error("{path}: light {light} ('{name}'): {what}")]
    BadLight { path: PathBuf, light: usize, name: String, what: String },
    #[error("{path}: node {node}: transform is not finite or is singular")]
    BadTransform { path: PathBuf, node: usize },
    #[error("{path}: {place}: no TEXCOORD_1 (lightmap UVs) and --require-uv1 was given")]
    MissingUv1 { path: PathBuf, place: Place },
    #[error(
        "{path}: lightmap UVs overlap: {first} and {second} share UV area ({pairs} overlapping pairs in \
        all); two surfaces would share texels. Fix the UVs or pass --allow-overlap"
    )]
    UvOverlap { path: PathBuf, first: String, second: String, pairs: usize },
    #[error("{path}: lightmap UV generation failed: {reason}")]
    Unwrap { path: PathBuf, reason: String },
    #[error("{path}: texture {texture}: {what}")]
    BadTexture { path: PathBuf, texture: usize, what: String },
    #[error("{path}: the scene has no triangles")]
    NoGeometry { path: PathBuf },
    #[error("{path}: movable node '{node}': {what}")]
    Movable { path: PathBuf, node: String, what: String },
    #[error("{path}: malformed glTF: {what}")]
    Malformed { path: PathBuf, what: String },
}
