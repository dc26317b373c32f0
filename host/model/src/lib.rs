#![deny(missing_docs)]
//! Textured triangle models in metres: Wavefront OBJ + MTL ([`load_obj`]), glTF 2.0
//! ([`load_gltf`]) and procedural test scenes ([`procedural`]); the edges a person would draw
//! ([`Model::crease_edges`]).
//!
//! Conventions: positions are in the world frame `w` in metres (OBJ files are taken as
//! metres as they are; use [`Model::scale`] otherwise). Texture coordinates have their
//! origin at the image's top-left corner (`u` right, `v` down: texel row = `v · height`), as
//! glTF; OBJ's bottom-left `v` is flipped on load.

mod edges;
mod gltf;
mod obj;
pub mod procedural;

pub use gltf::{load_gltf, parse_gltf};
pub use obj::{load_obj, parse_obj};

use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::RgbaImage;

/// Largest file a model reads (the OBJ, MTL, glTF, its buffers and textures), checked from the
/// file's size before reading it: 1 GiB holds an OBJ of about 20 million triangles, twice
/// [`MAX_TRIANGLES`].
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// Most vertices of a model: `v`, `vt` and `vn` lines of an OBJ each, glTF vertices over all
/// mesh instances. Ten million is a detailed 3D scan; its positions and texture coordinates
/// take 200 MB, and the renderer uploads them whole.
pub const MAX_VERTICES: usize = 10_000_000;

/// Most triangles of a model (after triangulating OBJ polygons; glTF over all mesh instances):
/// ten million, 120 MB of indices.
pub const MAX_TRIANGLES: usize = 10_000_000;

/// Largest texture side [px]: 16384 is the largest 2D texture most GPUs take (and Vulkan's
/// common limit); decoded RGBA8 it is 1 GiB, the most a texture may take while decoding
/// ([`MAX_TEXTURE_BYTES`]).
pub const MAX_TEXTURE_SIDE: u32 = 16384;

/// Most bytes a texture's decoding may allocate: a 16384² RGBA8 image.
pub const MAX_TEXTURE_BYTES: u64 = 16384 * 16384 * 4;

/// Loads an OBJ (`.obj`) or glTF (`.gltf`, `.glb`) model, by the file's extension.
pub fn load(path: &Path) -> Result<Model, ModelError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => load_obj(path),
        Some("gltf" | "glb") => load_gltf(path),
        _ => Err(ModelError::UnknownFormat {
            path: path.to_owned(),
        }),
    }
}

/// Why a model could not be loaded or is unusable.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A model or material file does not exist or cannot be opened.
    #[error("{path}: file not found or unreadable")]
    MissingFile {
        /// File.
        path: PathBuf,
    },
    /// A material's texture file does not exist.
    #[error("material `{material}`: texture {path} not found")]
    MissingTexture {
        /// Material name.
        material: String,
        /// Texture file looked for.
        path: PathBuf,
    },
    /// A texture exists but cannot be decoded.
    #[error("texture {path}: {source}")]
    Texture {
        /// Texture file.
        path: PathBuf,
        /// Cause.
        #[source]
        source: image::ImageError,
    },
    /// A texture in a pixel format we do not convert.
    #[error("texture {what}: unsupported pixel format {format}")]
    TextureFormat {
        /// Which texture.
        what: String,
        /// The format.
        format: String,
    },
    /// The OBJ/MTL parser failed.
    #[error("{path}: OBJ/MTL: {source}")]
    Obj {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: tobj::LoadError,
    },
    /// The glTF reader failed.
    #[error("{path}: glTF: {source}")]
    Gltf {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: ::gltf::Error,
    },
    /// A face or accessor refers outside the data.
    #[error("mesh `{mesh}`: bad index: {detail}")]
    BadIndex {
        /// Mesh name.
        mesh: String,
        /// What is out of range.
        detail: String,
    },
    /// Geometry that is not a triangle list.
    #[error("mesh `{mesh}`: unsupported primitive: {detail}")]
    UnsupportedPrimitive {
        /// Mesh name.
        mesh: String,
        /// What was found.
        detail: String,
    },
    /// A vertex with a NaN or infinite coordinate.
    #[error("mesh `{mesh}`: non-finite vertex data")]
    NonFinite {
        /// Mesh name.
        mesh: String,
    },
    /// A file that is neither OBJ nor glTF.
    #[error("{path}: unknown model format (expected .obj, .gltf or .glb)")]
    UnknownFormat {
        /// File.
        path: PathBuf,
    },
    /// The input is past one of the documented limits ([`MAX_FILE_BYTES`], [`MAX_VERTICES`],
    /// [`MAX_TRIANGLES`], [`MAX_TEXTURE_SIDE`], [`MAX_TEXTURE_BYTES`]); checked before
    /// allocating for it.
    #[error("{what}: too large: {limit}")]
    TooLarge {
        /// File, mesh or texture.
        what: String,
        /// The count found and the limit passed.
        limit: String,
    },
    /// A line of a text file that is not what its format says.
    #[error("{path}:{line}: {detail}")]
    Syntax {
        /// File.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        detail: String,
    },
    /// A glTF URI that cannot be resolved (bad percent-encoding or base64, unsupported scheme).
    #[error("{path}: glTF: bad URI `{uri}`: {detail}")]
    BadUri {
        /// The glTF file.
        path: PathBuf,
        /// The URI, at most 100 characters of it.
        uri: String,
        /// What is wrong.
        detail: String,
    },
    /// No triangle at all.
    #[error("{what}: the model has no triangles")]
    Empty {
        /// File or model name.
        what: String,
    },
}

/// A material: a base colour multiplied by an optional texture.
#[derive(Debug, Clone)]
pub struct Material {
    /// Name.
    pub name: String,
    /// Linear RGBA multiplier in `[0, 1]` (white when a texture is given in OBJ).
    pub base_colour: [f32; 4],
    /// RGBA8 texture, top row first; shared between materials that use the same file.
    pub texture: Option<Arc<RgbaImage>>,
}

/// An indexed triangle list with one material.
#[derive(Debug, Clone)]
pub struct Mesh {
    /// Name (for errors and debugging).
    pub name: String,
    /// Vertex positions in the world frame, metres.
    pub positions: Vec<[f32; 3]>,
    /// Texture coordinates per vertex (top-left origin); same length as `positions`.
    pub uvs: Vec<[f32; 2]>,
    /// Three indices per triangle into `positions`.
    pub indices: Vec<u32>,
    /// Index into [`Model::materials`].
    pub material: usize,
}

impl Mesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// A textured triangle model.
#[derive(Debug, Clone, Default)]
pub struct Model {
    /// Meshes, each with one material.
    pub meshes: Vec<Mesh>,
    /// Materials referred to by the meshes.
    pub materials: Vec<Material>,
}

impl Model {
    /// Total number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(Mesh::triangle_count).sum()
    }

    /// The corners `(lowest, highest)` of the axis-aligned box around every position [m];
    /// `None` without a finite position.
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in self.meshes.iter().flat_map(|m| m.positions.iter()) {
            for k in 0..3 {
                lo[k] = lo[k].min(f64::from(p[k]));
                hi[k] = hi[k].max(f64::from(p[k]));
            }
        }
        lo.iter()
            .chain(hi.iter())
            .all(|v| v.is_finite())
            .then_some((lo, hi))
    }

    /// The model's size: the diagonal of [`Self::bounds`] [m] (0 without a position).
    pub fn diagonal(&self) -> f64 {
        self.bounds().map_or(0.0, |(lo, hi)| {
            lo.iter()
                .zip(&hi)
                .map(|(a, b)| (b - a) * (b - a))
                .sum::<f64>()
                .sqrt()
        })
    }

    /// Multiplies all positions by `factor` (e.g. 0.001 for a model in millimetres).
    pub fn scale(&mut self, factor: f32) {
        for p in self.meshes.iter_mut().flat_map(|m| m.positions.iter_mut()) {
            *p = p.map(|c| c * factor);
        }
    }

    /// Drops meshes without triangles, then checks indices, materials and finiteness, and
    /// that some triangle is left. Every loader calls it; call it after editing a model.
    pub fn validate(mut self, what: &str) -> Result<Self, ModelError> {
        self.meshes.retain(|m| !m.indices.is_empty());
        self.check(what)?;
        Ok(self)
    }

    /// Checks indices, materials and finiteness, and that there is a triangle.
    pub fn check(&self, what: &str) -> Result<(), ModelError> {
        for m in &self.meshes {
            let bad = |detail: String| ModelError::BadIndex {
                mesh: m.name.clone(),
                detail,
            };
            if m.indices.len() % 3 != 0 {
                return Err(ModelError::UnsupportedPrimitive {
                    mesh: m.name.clone(),
                    detail: format!(
                        "{} indices is not a whole number of triangles",
                        m.indices.len()
                    ),
                });
            }
            if m.uvs.len() != m.positions.len() {
                return Err(bad(format!(
                    "{} texture coordinates for {} vertices",
                    m.uvs.len(),
                    m.positions.len()
                )));
            }
            if let Some(&i) = m.indices.iter().find(|&&i| i as usize >= m.positions.len()) {
                return Err(bad(format!(
                    "vertex index {i} but only {} vertices",
                    m.positions.len()
                )));
            }
            if m.positions.len() > MAX_VERTICES || m.triangle_count() > MAX_TRIANGLES {
                return Err(ModelError::TooLarge {
                    what: format!("mesh `{}`", m.name),
                    limit: format!(
                        "{} vertices and {} triangles (at most {MAX_VERTICES} and {MAX_TRIANGLES})",
                        m.positions.len(),
                        m.triangle_count()
                    ),
                });
            }
            if m.material >= self.materials.len() {
                return Err(bad(format!(
                    "material {} but only {} materials",
                    m.material,
                    self.materials.len()
                )));
            }
            let finite = m.positions.iter().flatten().chain(m.uvs.iter().flatten());
            if !finite.clone().all(|c| c.is_finite()) {
                return Err(ModelError::NonFinite {
                    mesh: m.name.clone(),
                });
            }
        }
        if let Some(m) = self
            .materials
            .iter()
            .find(|m| !m.base_colour.iter().all(|c| c.is_finite()))
        {
            return Err(ModelError::NonFinite {
                mesh: format!("material `{}`", m.name),
            });
        }
        if self.triangle_count() == 0 {
            return Err(ModelError::Empty { what: what.into() });
        }
        Ok(())
    }
}

/// Reads a file the model names, refusing one over [`MAX_FILE_BYTES`] before reading it.
pub fn read_file(path: &Path) -> Result<Vec<u8>, ModelError> {
    let missing = || ModelError::MissingFile {
        path: path.to_owned(),
    };
    let len = std::fs::metadata(path).map_err(|_| missing())?.len();
    if len > MAX_FILE_BYTES {
        return Err(ModelError::TooLarge {
            what: path.display().to_string(),
            limit: format!("{len} bytes (at most {MAX_FILE_BYTES})"),
        });
    }
    std::fs::read(path).map_err(|_| missing())
}

/// The files beside a model, as the loaders read them: `Ok(None)` when `path` does not exist.
/// Tests and fuzzers give their own (files in memory).
pub type ReadFile<'a> = &'a dyn Fn(&Path) -> Result<Option<Vec<u8>>, ModelError>;

/// [`ReadFile`] on the file system, with [`read_file`]'s size limit.
pub fn read_from_disk(path: &Path) -> Result<Option<Vec<u8>>, ModelError> {
    if !path.is_file() {
        return Ok(None);
    }
    read_file(path).map(Some)
}

/// The decoder limits of a texture: [`MAX_TEXTURE_SIDE`] and [`MAX_TEXTURE_BYTES`].
pub fn texture_limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    limits.max_alloc = Some(MAX_TEXTURE_BYTES);
    limits
}

/// Decodes a PNG or JPEG texture (`path` names it in errors) to RGBA8, within
/// [`texture_limits`]: the size is checked from the header, before the pixels are allocated.
pub fn decode_texture(path: &Path, bytes: &[u8]) -> Result<RgbaImage, ModelError> {
    let texture_err = |source| ModelError::Texture {
        path: path.to_owned(),
        source,
    };
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| texture_err(image::ImageError::IoError(e)))?;
    reader.limits(texture_limits());
    let image = reader.decode().map_err(|e| match e {
        image::ImageError::Limits(l) => ModelError::TooLarge {
            what: format!("texture {}", path.display()),
            limit: format!(
                "{l} (at most {MAX_TEXTURE_SIDE}x{MAX_TEXTURE_SIDE} px, {MAX_TEXTURE_BYTES} bytes decoded)"
            ),
        },
        e => texture_err(e),
    })?;
    // The RGBA8 copy is at most MAX_TEXTURE_BYTES: the sides were checked.
    Ok(image.into_rgba8())
}

/// Loads a texture file as RGBA8, with typed errors for a missing or broken file.
fn load_texture(material: &str, path: &Path, read: ReadFile) -> Result<RgbaImage, ModelError> {
    let Some(bytes) = read(path)? else {
        return Err(ModelError::MissingTexture {
            material: material.into(),
            path: path.to_owned(),
        });
    };
    decode_texture(path, &bytes)
}
