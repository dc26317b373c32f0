//! The viewpoint database (docs/notes/issue15-cold-start.md §2): the textured model rendered
//! from directions on a sphere at a few distances, ORB keypoints of each rendering on the
//! model's pixels, and their model points from the depth buffer. In-plane rotations need no
//! renderings: the descriptor is steered by its orientation.
//!
//! The database is cached in a folder (`--cache`), keyed by a CRC-64 of the model's geometry,
//! texture pixels and the settings; a cache of another model or other settings is rebuilt.
//!
//! The cache file `locate-KEY.db` ([`Database::to_bytes`]): a 28-byte header, then the
//! postcard body (the views and the entries).
//!
//! | bytes | what |
//! |---|---|
//! | 0..7 | `HVLOCDB`: the format's marker (another file is *foreign*) |
//! | 7 | the format version, an ASCII digit ([`FORMAT_VERSION`]) |
//! | 8..16 | the key, u64 little-endian |
//! | 16..24 | the body's length [bytes], u64 little-endian |
//! | 24..28 | CRC-32 (ISO-HDLC) of the body, little-endian |
//!
//! A file that is short, foreign, of another version, another key, of a wrong length or
//! checksum, or whose body does not decode is not trusted: [`Database::load_or_build`] rebuilds
//! it and says why ([`CacheError`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::orb::{Descriptor, Orb, OrbConfig};
use camera::{CameraPose, Pinhole};
use model::Model;
use render::{RenderError, RenderView, Renderer};

/// How the database is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DatabaseConfig {
    /// Rendering size [px].
    pub width: u32,
    /// Rendering size [px].
    pub height: u32,
    /// Horizontal field of view of the virtual camera [°].
    pub fov_deg: f64,
    /// Viewing directions, spread evenly on the sphere (a Fibonacci lattice).
    pub directions: usize,
    /// Sizes of the model in the renderings: its bounding sphere's diameter over the image
    /// height. Scales between them are left to the descriptor's pyramid.
    pub fills: [f64; 2],
    /// Keypoints per rendering, at most.
    pub per_view: usize,
    /// The descriptor.
    pub orb: OrbConfig,
}

impl Default for DatabaseConfig {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            fov_deg: 60.0,
            directions: 80,
            fills: [0.7, 0.35],
            per_view: 300,
            orb: OrbConfig::default(),
        }
    }
}

/// One keypoint of one rendering.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Its descriptor.
    pub descriptor: Descriptor,
    /// Its model point [m].
    pub point: [f32; 3],
    /// The rendering it came from.
    pub view: u16,
}

/// A rendering's camera, for reports.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct View {
    /// `q_cw` as `[w, x, y, z]`.
    pub q_cw: [f64; 4],
    /// Camera centre [m].
    pub c_w: [f64; 3],
}

/// The database.
#[derive(Debug, Clone, PartialEq)]
pub struct Database {
    /// CRC-64 of the model and the settings it was built from.
    pub key: u64,
    /// The renderings.
    pub views: Vec<View>,
    /// All keypoints.
    pub entries: Vec<Entry>,
}

/// Marker of the cache file's format, before the version digit.
const MAGIC: [u8; 7] = *b"HVLOCDB";

/// Version of the cache file's format (an ASCII digit after [`MAGIC`]; bump it when the format
/// changes). Version 1 was the postcard body alone, with no length or checksum.
pub const FORMAT_VERSION: u8 = b'2';

/// Bytes of the cache file's header.
pub const HEADER_LEN: usize = 28;

/// Largest cache file read, checked from its size before reading: the default settings make
/// about 2 MB (160 renderings of up to 300 keypoints of 46 bytes), so 1 GiB holds settings
/// hundreds of times denser.
pub const MAX_CACHE_BYTES: u64 = 1 << 30;

/// The body of the cache file.
#[derive(Serialize)]
struct BodyRef<'a> {
    views: &'a [View],
    entries: &'a [Entry],
}

/// The body of the cache file, read.
#[derive(Deserialize)]
struct Body {
    views: Vec<View>,
    entries: Vec<Entry>,
}

/// Why a cache file is not used (it is rebuilt).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CacheError {
    /// Shorter than its header, or than the body its header announces.
    #[error("truncated: {found} bytes, expected {expected}")]
    Truncated {
        /// Bytes expected.
        expected: u64,
        /// Bytes found.
        found: u64,
    },
    /// Not a database of this program.
    #[error("not a locate database (foreign file)")]
    Foreign,
    /// Another version of the format.
    #[error("format version {found}, this build reads version {expected}")]
    Version {
        /// The file's version.
        found: char,
        /// This build's.
        expected: char,
    },
    /// A database of another model or other settings.
    #[error("of another model or other settings (key {found:016x})")]
    OtherKey {
        /// The file's key.
        found: u64,
    },
    /// Longer than its header says.
    #[error("{extra} bytes after the body")]
    TrailingBytes {
        /// Bytes past the body.
        extra: u64,
    },
    /// Over [`MAX_CACHE_BYTES`].
    #[error("too large: {bytes} bytes (at most {MAX_CACHE_BYTES})")]
    TooLarge {
        /// The file's size.
        bytes: u64,
    },
    /// The body's checksum differs from the header's.
    #[error("checksum mismatch: body CRC-32 {found:08x}, header {expected:08x}")]
    Checksum {
        /// In the header.
        expected: u32,
        /// Of the body.
        found: u32,
    },
    /// The body does not decode, or holds what a database cannot.
    #[error("corrupt body: {0}")]
    Corrupt(String),
}

const BODY_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why the database could not be built or read.
#[derive(Debug, thiserror::Error)]
pub enum DatabaseError {
    /// Rendering failed.
    #[error("rendering the viewpoints: {0}")]
    Render(#[from] RenderError),
    /// The model has no texture: its renderings have nothing to describe.
    #[error(
        "the model has no textured material: its renderings show flat colours, with no keypoints to find it by"
    )]
    Untextured,
    /// The renderings gave no keypoints.
    #[error(
        "no keypoints in any of the {views} renderings of the model (too little texture, or too small)"
    )]
    NoKeypoints {
        /// Renderings made.
        views: usize,
    },
    /// The cache folder or file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
}

/// Where the database came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Provenance {
    /// Read from this cache file.
    Cached(PathBuf),
    /// Built, and written to this cache file; `why` says why the cache was not used.
    Built {
        /// Cache file written.
        path: PathBuf,
        /// Why it was rebuilt.
        why: String,
    },
}

/// The default cache folder: `$XDG_CACHE_HOME/host-vision`, else `~/.cache/host-vision`,
/// else the temporary folder's `host-vision-cache`.
pub fn default_cache_dir() -> PathBuf {
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME").filter(|x| !x.is_empty()) {
        return PathBuf::from(x).join("host-vision");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h).join(".cache").join("host-vision");
    }
    std::env::temp_dir().join("host-vision-cache")
}

/// CRC-64 of what the database depends on: every mesh's positions, texture coordinates and
/// indices, every material's colour and texture pixels, and the settings.
pub fn database_key(model: &Model, config: &DatabaseConfig) -> u64 {
    let crc = crc::Crc::<u64>::new(&crc::CRC_64_ECMA_182);
    let mut d = crc.digest();
    for m in &model.meshes {
        for p in &m.positions {
            p.iter().for_each(|c| d.update(&c.to_le_bytes()));
        }
        for t in &m.uvs {
            t.iter().for_each(|c| d.update(&c.to_le_bytes()));
        }
        m.indices.iter().for_each(|i| d.update(&i.to_le_bytes()));
        d.update(&(m.material as u64).to_le_bytes());
    }
    for mat in &model.materials {
        mat.base_colour
            .iter()
            .for_each(|c| d.update(&c.to_le_bytes()));
        if let Some(t) = &mat.texture {
            d.update(&t.width().to_le_bytes());
            d.update(&t.height().to_le_bytes());
            d.update(t.as_raw());
        }
    }
    d.update(format!("{config:?}").as_bytes());
    d.update(&MAGIC);
    d.finalize()
}

/// Centre and radius of the model's bounding sphere (of its vertices' bounding box).
pub fn bounding_sphere(model: &Model) -> (Vector3<f64>, f64) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in model.meshes.iter().flat_map(|m| &m.positions) {
        let v = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    ((lo + hi) / 2.0, ((hi - lo) / 2.0).norm())
}

/// The `n` directions of a Fibonacci lattice on the unit sphere.
fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f64;
            Vector3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

impl DatabaseConfig {
    /// The virtual camera's intrinsics.
    pub fn pinhole(&self) -> Pinhole {
        let f = f64::from(self.width) / 2.0 / (self.fov_deg.to_radians() / 2.0).tan();
        Pinhole::new(
            f,
            f,
            (f64::from(self.width) - 1.0) / 2.0,
            (f64::from(self.height) - 1.0) / 2.0,
        )
    }

    /// The renderings' views of a model with bounding sphere `(centre, radius)`.
    pub fn views(&self, centre: Vector3<f64>, radius: f64) -> Vec<RenderView> {
        let pin = self.pinhole();
        let mut out = Vec::new();
        for fill in self.fills {
            // The sphere's diameter spans `fill` of the image height: d = r f / (fill h / 2).
            let distance = radius * pin.fy / (fill * f64::from(self.height) / 2.0);
            for dir in fibonacci_sphere(self.directions) {
                let eye = centre + dir * distance;
                let up = if dir.z.abs() < 0.9 {
                    Vector3::z()
                } else {
                    Vector3::x()
                };
                let Ok(pose) = CameraPose::look_at(eye, centre, up) else {
                    continue;
                };
                out.push(RenderView {
                    pinhole: pin,
                    pose,
                    near: (distance - 2.0 * radius).max(distance * 0.05),
                    far: distance + 2.0 * radius,
                });
            }
        }
        out
    }
}

impl Database {
    /// Renders `model` from every view of `config` and collects the keypoints; `progress` is
    /// told `(done, total)` after each rendering.
    pub fn build(
        model: &Model,
        config: &DatabaseConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, DatabaseError> {
        if !model.materials.iter().any(|m| m.texture.is_some()) {
            return Err(DatabaseError::Untextured);
        }
        let mut renderer = Renderer::new(config.width, config.height)?;
        renderer.set_model(model)?;
        let (centre, radius) = bounding_sphere(model);
        let views = config.views(centre, radius);
        let orb = Orb::new(OrbConfig {
            max_keypoints: config.per_view,
            ..config.orb
        });
        let mut entries = Vec::new();
        let mut kept_views = Vec::with_capacity(views.len());
        for (i, view) in views.iter().enumerate() {
            let frame = renderer.render(view)?;
            let index = kept_views.len() as u16;
            for k in orb.detect(&frame.gray, Some(&frame.mask)) {
                let (u, v) = (k.x.round(), k.y.round());
                if u < 0.0 || v < 0.0 {
                    continue;
                }
                let Some(b) = frame.backproject(u as u32, v as u32) else {
                    continue;
                };
                entries.push(Entry {
                    descriptor: k.descriptor,
                    point: [b.p_w.x as f32, b.p_w.y as f32, b.p_w.z as f32],
                    view: index,
                });
            }
            let q = view.pose.q_cw;
            kept_views.push(View {
                q_cw: [q.w, q.i, q.j, q.k],
                c_w: view.pose.c_w.into(),
            });
            progress(i + 1, views.len());
        }
        if entries.is_empty() {
            return Err(DatabaseError::NoKeypoints { views: views.len() });
        }
        Ok(Self {
            key: database_key(model, config),
            views: kept_views,
            entries,
        })
    }

    /// The cache file of a database with `key` in `dir`.
    pub fn cache_path(dir: &Path, key: u64) -> PathBuf {
        dir.join(format!("locate-{key:016x}.db"))
    }

    /// The database of `model` and `config` from `dir`, or built (and written there) when
    /// the cache has none, or one that is unreadable or of other settings.
    pub fn load_or_build(
        model: &Model,
        config: &DatabaseConfig,
        dir: &Path,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(Self, Provenance), DatabaseError> {
        let key = database_key(model, config);
        let path = Self::cache_path(dir, key);
        let why = match Self::read_cache(&path, key) {
            Ok(Some(db)) => return Ok((db, Provenance::Cached(path))),
            Ok(None) => None,
            Err(CacheError::OtherKey { .. }) => Some(format!(
                "{} is of another model or other settings",
                path.display()
            )),
            Err(e) => Some(format!("{} is unreadable ({e})", path.display())),
        };
        let why = match why {
            Some(why) => why,
            None => {
                let others = std::fs::read_dir(dir).map_or(0, |entries| {
                    entries
                        .filter_map(Result::ok)
                        .filter(|e| {
                            let name = e.file_name();
                            let name = name.to_string_lossy();
                            name.starts_with("locate-") && name.ends_with(".db")
                        })
                        .count()
                });
                if others > 0 {
                    format!(
                        "the {others} database(s) in {} are of other models or other settings",
                        dir.display()
                    )
                } else {
                    format!("no database in {} yet", dir.display())
                }
            }
        };
        let db = Self::build(model, config, progress)?;
        db.write(&path)?;
        Ok((db, Provenance::Built { path, why }))
    }

    /// Writes the database to `path` (through a temporary file, so that an interrupted write
    /// leaves no half a database behind).
    pub fn write(&self, path: &Path) -> Result<(), DatabaseError> {
        let io = |source| DatabaseError::Io {
            path: path.to_owned(),
            source,
        };
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let bytes = self
            .to_bytes()
            .map_err(|e| io(std::io::Error::other(e.to_string())))?;
        // A name of its own per writer: two processes building the same database at once
        // each rename a whole file into place.
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let tmp = path.with_extension(format!("partial-{}-{nanos}", std::process::id()));
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)?;
        Ok(())
    }

    /// The cache file of `key` at `path`: `Ok(None)` when there is none, an error when it is
    /// not to be trusted.
    fn read_cache(path: &Path, key: u64) -> Result<Option<Self>, CacheError> {
        let Ok(meta) = std::fs::metadata(path) else {
            return Ok(None);
        };
        if meta.len() > MAX_CACHE_BYTES {
            return Err(CacheError::TooLarge { bytes: meta.len() });
        }
        match std::fs::read(path) {
            Ok(bytes) => Self::from_bytes(&bytes, key).map(Some),
            Err(e) => Err(CacheError::Corrupt(format!("cannot read: {e}"))),
        }
    }

    /// The cache file's bytes: header and body (see the module's text).
    pub fn to_bytes(&self) -> Result<Vec<u8>, postcard::Error> {
        let body = postcard::to_stdvec(&BodyRef {
            views: &self.views,
            entries: &self.entries,
        })?;
        let mut out = Vec::with_capacity(HEADER_LEN + body.len());
        out.extend_from_slice(&MAGIC);
        out.push(FORMAT_VERSION);
        out.extend_from_slice(&self.key.to_le_bytes());
        out.extend_from_slice(&(body.len() as u64).to_le_bytes());
        out.extend_from_slice(&BODY_CRC.checksum(&body).to_le_bytes());
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// Reads a cache file's bytes, checking the header (marker, version, `key`, length,
    /// checksum) before decoding the body, and the body's entries after: any doubt is an error.
    pub fn from_bytes(bytes: &[u8], key: u64) -> Result<Self, CacheError> {
        let found = bytes.len() as u64;
        if found > MAX_CACHE_BYTES {
            return Err(CacheError::TooLarge { bytes: found });
        }
        let u64_at = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&bytes[i..i + 8]);
            u64::from_le_bytes(b)
        };
        if bytes.len() < MAGIC.len() + 1 || bytes[..MAGIC.len()] != MAGIC {
            return Err(if MAGIC.starts_with(bytes) {
                CacheError::Truncated {
                    expected: HEADER_LEN as u64,
                    found,
                }
            } else {
                CacheError::Foreign
            });
        }
        if bytes[MAGIC.len()] != FORMAT_VERSION {
            return Err(CacheError::Version {
                found: char::from(bytes[MAGIC.len()]),
                expected: char::from(FORMAT_VERSION),
            });
        }
        if bytes.len() < HEADER_LEN {
            return Err(CacheError::Truncated {
                expected: HEADER_LEN as u64,
                found,
            });
        }
        let file_key = u64_at(8);
        if file_key != key {
            return Err(CacheError::OtherKey { found: file_key });
        }
        let body = &bytes[HEADER_LEN..];
        let announced = u64_at(16);
        let have = body.len() as u64;
        if have < announced {
            return Err(CacheError::Truncated {
                expected: (HEADER_LEN as u64).saturating_add(announced),
                found,
            });
        }
        if have > announced {
            return Err(CacheError::TrailingBytes {
                extra: have - announced,
            });
        }
        let mut crc = [0u8; 4];
        crc.copy_from_slice(&bytes[24..28]);
        let expected = u32::from_le_bytes(crc);
        let actual = BODY_CRC.checksum(body);
        if actual != expected {
            return Err(CacheError::Checksum {
                expected,
                found: actual,
            });
        }
        let body: Body = match postcard::take_from_bytes(body) {
            Ok((b, [])) => b,
            Ok((_, rest)) => {
                return Err(CacheError::Corrupt(format!(
                    "{} bytes left after the entries",
                    rest.len()
                )));
            }
            Err(e) => return Err(CacheError::Corrupt(e.to_string())),
        };
        if body.entries.is_empty() {
            return Err(CacheError::Corrupt("no entries".into()));
        }
        if let Some((i, e)) = body.entries.iter().enumerate().find(|(_, e)| {
            usize::from(e.view) >= body.views.len() || !e.point.iter().all(|c| c.is_finite())
        }) {
            return Err(CacheError::Corrupt(format!(
                "entry {i}: view {} of {} or a non-finite point",
                e.view,
                body.views.len()
            )));
        }
        let finite_view = |v: &View| v.q_cw.iter().chain(&v.c_w).all(|c| c.is_finite());
        if let Some(i) = body.views.iter().position(|v| !finite_view(v)) {
            return Err(CacheError::Corrupt(format!("view {i} is not finite")));
        }
        Ok(Self {
            key,
            views: body.views,
            entries: body.entries,
        })
    }

    /// Descriptors of all entries, in order.
    pub fn descriptors(&self) -> Vec<Descriptor> {
        self.entries.iter().map(|e| e.descriptor).collect()
    }

    /// Model points of all entries, in order.
    pub fn points(&self) -> Vec<[f32; 3]> {
        self.entries.iter().map(|e| e.point).collect()
    }
}
