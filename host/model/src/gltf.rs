//! glTF 2.0 (`.gltf` with external or embedded buffers, `.glb`) through the `gltf` crate.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::gltf::mesh::Mode;
use image::RgbaImage;
use nalgebra::{Matrix4, Vector4};

use super::{
    MAX_TRIANGLES, MAX_VERTICES, Material, Mesh, Model, ModelError, ReadFile, decode_texture,
    read_from_disk,
};

/// Loads the default scene (else the first) of a glTF file, applying node transforms, with
/// each material's base colour factor and base colour texture.
///
/// glTF is metres with +Y up; the world frame has +Z up (docs/FILTER.md §2), so positions are
/// rotated by +90° about x: `(x, y, z)_gltf → (x, −z, y)_w`.
pub fn load_gltf(path: &Path) -> Result<Model, ModelError> {
    let Some(bytes) = read_from_disk(path)? else {
        return Err(ModelError::MissingFile {
            path: path.to_owned(),
        });
    };
    parse_gltf(&bytes, path, &read_from_disk)
}

/// Parses a glTF (JSON) or GLB file held in memory, as [`load_gltf`]: `path` names it in
/// errors and its folder is where external buffers and images are read, through `read`.
/// Limits: [`MAX_VERTICES`] and [`MAX_TRIANGLES`] over all mesh instances, checked from the
/// accessors' counts before reading them; textures as [`crate::decode_texture`].
pub fn parse_gltf(bytes: &[u8], path: &Path, read: ReadFile) -> Result<Model, ModelError> {
    let (document, blob) = validated(bytes, path)?;
    check_accessors(&document)?;
    let files = Files { path, read };
    let buffers = files.buffers(&document, blob)?;
    check_ranges(&document, &buffers)?;

    let mut model = Model {
        materials: materials(&document, &buffers, &files)?,
        ..Model::default()
    };
    let default_material = model.materials.len();
    model.materials.push(Material {
        name: "default".into(),
        base_colour: [1.0; 4],
        texture: None,
    });

    // y-up → z-up.
    let up = Matrix4::new(
        1.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, -1.0, 0.0, //
        0.0, 1.0, 0.0, 0.0, //
        0.0, 0.0, 0.0, 1.0,
    );
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next());
    let mut stack: Vec<(::gltf::Node, Matrix4<f32>)> = match scene {
        Some(s) => s.nodes().map(|n| (n, up)).collect(),
        None => Vec::new(),
    };
    let mut visited = 0usize;
    let (mut vertices, mut triangles) = (0usize, 0usize);
    while let Some((node, parent)) = stack.pop() {
        // glTF nodes form a forest, so each is visited at most once; more means a cycle.
        visited += 1;
        if visited > document.nodes().len() {
            return Err(ModelError::BadIndex {
                mesh: path.display().to_string(),
                detail: "node hierarchy too deep or cyclic".into(),
            });
        }
        let local = Matrix4::from(node.transform().matrix());
        let global = parent * local;
        if let Some(mesh) = node.mesh() {
            for (p, prim) in mesh.primitives().enumerate() {
                let name = format!("{}#{p}", mesh.name().unwrap_or("mesh"));
                if prim.mode() != Mode::Triangles {
                    return Err(ModelError::UnsupportedPrimitive {
                        mesh: name,
                        detail: format!("{:?} (only triangle lists)", prim.mode()),
                    });
                }
                // Counted before reading: a mesh used by many nodes is loaded once per node.
                let count = |s: &::gltf::Semantic| prim.get(s).map_or(0, |a| a.count());
                let corners = prim
                    .indices()
                    .map_or(count(&::gltf::Semantic::Positions), |a| a.count());
                vertices = vertices.saturating_add(count(&::gltf::Semantic::Positions));
                triangles = triangles.saturating_add(corners / 3);
                if vertices > MAX_VERTICES || triangles > MAX_TRIANGLES {
                    return Err(ModelError::TooLarge {
                        what: path.display().to_string(),
                        limit: format!(
                            "{vertices} vertices and {triangles} triangles by mesh `{name}` \
                             (at most {MAX_VERTICES} and {MAX_TRIANGLES})"
                        ),
                    });
                }
                let mut mesh = read_primitive(&prim, &global, &buffers, name)?;
                mesh.material = prim.material().index().unwrap_or(default_material);
                model.meshes.push(mesh);
            }
        }
        stack.extend(node.children().map(|c| (c, global)));
    }
    model.validate(&path.display().to_string())
}

/// The document and GLB blob of `bytes`, validated, with the checks gltf lacks first.
fn validated(bytes: &[u8], path: &Path) -> Result<(::gltf::Document, Option<Vec<u8>>), ModelError> {
    let gltf_err = |source| ModelError::Gltf {
        path: path.to_owned(),
        source,
    };
    // gltf's GLB reader subtracts the 12-byte header from the length field unchecked (a
    // panic for a length under 12; found by the `gltf` fuzz target).
    if let Some(length) = bytes
        .strip_prefix(b"glTF")
        .and_then(|rest| rest.get(4..8))
        .map(|l| u32::from_le_bytes([l[0], l[1], l[2], l[3]]))
        && length < 12
    {
        return Err(gltf_err(::gltf::Error::Binary(
            ::gltf::binary::Error::Length {
                length,
                length_read: bytes.len(),
            },
        )));
    }
    let ::gltf::Gltf { document, blob } =
        ::gltf::Gltf::from_slice_without_validation(bytes).map_err(gltf_err)?;
    // gltf-json's validation indexes the accessors by POSITION's index before checking it
    // (a panic for an index past them): checked here first.
    let accessors = document.as_json().accessors.len();
    for (m, mesh) in document.as_json().meshes.iter().enumerate() {
        for prim in &mesh.primitives {
            let position = ::gltf::json::validation::Checked::Valid(::gltf::Semantic::Positions);
            if let Some(i) = prim.attributes.get(&position)
                && i.value() >= accessors
            {
                return Err(ModelError::BadIndex {
                    mesh: format!("mesh {m}"),
                    detail: format!("POSITION accessor {} of {accessors}", i.value()),
                });
            }
        }
    }
    let document = ::gltf::Document::from_json(document.into_json()).map_err(gltf_err)?;
    Ok((document, blob))
}

/// A triangle primitive's vertices (transformed by `global`), texture coordinates and indices;
/// its material is left to the caller.
fn read_primitive(
    prim: &::gltf::Primitive,
    global: &Matrix4<f32>,
    buffers: &[Vec<u8>],
    name: String,
) -> Result<Mesh, ModelError> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let positions: Vec<[f32; 3]> = reader
        .read_positions()
        .ok_or_else(|| ModelError::UnsupportedPrimitive {
            mesh: name.clone(),
            detail: "no POSITION attribute".into(),
        })?
        .map(|q| {
            let v = global * Vector4::new(q[0], q[1], q[2], 1.0);
            [v.x, v.y, v.z]
        })
        .collect();
    let set = prim
        .material()
        .pbr_metallic_roughness()
        .base_color_texture()
        .map_or(0, |t| t.tex_coord());
    let uvs = match reader.read_tex_coords(set) {
        Some(t) => t.into_f32().collect(),
        None => vec![[0.0; 2]; positions.len()],
    };
    let indices = match reader.read_indices() {
        Some(i) => i.into_u32().collect(),
        None => (0..positions.len() as u32).collect(),
    };
    Ok(Mesh {
        name,
        positions,
        uvs,
        indices,
        material: 0,
    })
}

/// The files of a glTF: its own path (for errors and the folder) and how to read the others.
struct Files<'a> {
    path: &'a Path,
    read: ReadFile<'a>,
}

impl Files<'_> {
    fn bad_uri(&self, uri: &str, detail: &str) -> ModelError {
        ModelError::BadUri {
            path: self.path.to_owned(),
            uri: uri.chars().take(100).collect(),
            detail: detail.into(),
        }
    }

    /// The bytes of a URI: `data:…;base64,…`, or a file relative to the glTF's folder
    /// (percent-decoded; `file:` URIs as they are). `Ok(None)`: the file does not exist.
    fn uri(&self, uri: &str) -> Result<(Option<Vec<u8>>, PathBuf), ModelError> {
        if let Some(rest) = uri.strip_prefix("data:") {
            let (_, data) = rest
                .split_once(";base64,")
                .ok_or_else(|| self.bad_uri(uri, "a data URI without `;base64,`"))?;
            let bytes = base64(data).ok_or_else(|| self.bad_uri(uri, "invalid base64"))?;
            return Ok((Some(bytes), PathBuf::new()));
        }
        let file = if let Some(rest) = uri.strip_prefix("file:") {
            PathBuf::from(rest.strip_prefix("//").unwrap_or(rest))
        } else if uri.contains(':') {
            return Err(self.bad_uri(uri, "unsupported scheme (only data: and files)"));
        } else {
            let name =
                percent_decode(uri).ok_or_else(|| self.bad_uri(uri, "invalid percent-encoding"))?;
            self.path.parent().unwrap_or(Path::new(".")).join(name)
        };
        Ok(((self.read)(&file)?, file))
    }

    /// Every buffer's bytes, at least as many as its `byteLength`.
    fn buffers(
        &self,
        document: &::gltf::Document,
        mut blob: Option<Vec<u8>>,
    ) -> Result<Vec<Vec<u8>>, ModelError> {
        let gltf_err = |source| ModelError::Gltf {
            path: self.path.to_owned(),
            source,
        };
        let mut out = Vec::new();
        for buffer in document.buffers() {
            let data = match buffer.source() {
                ::gltf::buffer::Source::Bin => {
                    blob.take().ok_or(gltf_err(::gltf::Error::MissingBlob))?
                }
                ::gltf::buffer::Source::Uri(uri) => match self.uri(uri)? {
                    (Some(data), _) => data,
                    (None, path) => return Err(ModelError::MissingFile { path }),
                },
            };
            if data.len() < buffer.length() {
                return Err(gltf_err(::gltf::Error::BufferLength {
                    buffer: buffer.index(),
                    expected: buffer.length(),
                    actual: data.len(),
                }));
            }
            out.push(data);
        }
        Ok(out)
    }

    /// A base colour texture, decoded within the texture limits.
    fn texture(
        &self,
        material: &str,
        image: &::gltf::Image,
        buffers: &[Vec<u8>],
    ) -> Result<RgbaImage, ModelError> {
        match image.source() {
            ::gltf::image::Source::View { view, .. } => {
                // Views were checked against their buffers (check_ranges).
                let bytes = buffers
                    .get(view.buffer().index())
                    .and_then(|b| b.get(view.offset()..view.offset() + view.length()))
                    .ok_or_else(|| ModelError::BadIndex {
                        mesh: material.into(),
                        detail: format!("image {} reads past its buffer", image.index()),
                    })?;
                let name = format!("{}#image{}", self.path.display(), image.index());
                decode_texture(Path::new(&name), bytes)
            }
            ::gltf::image::Source::Uri { uri, .. } => match self.uri(uri)? {
                (Some(bytes), file) if file.as_os_str().is_empty() => {
                    let name = format!("{}#image{}", self.path.display(), image.index());
                    decode_texture(Path::new(&name), &bytes)
                }
                (Some(bytes), file) => decode_texture(&file, &bytes),
                (None, path) => Err(ModelError::MissingTexture {
                    material: material.into(),
                    path,
                }),
            },
        }
    }
}

/// Standard base64 (`=` padding optional); `None` on any other character.
fn base64(text: &str) -> Option<Vec<u8>> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let text = text.trim_end_matches('=').as_bytes();
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for &c in text {
        acc = (acc << 6) | u32::from(value(c)?);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

/// `%XX` escapes of a relative URI decoded; `None` for a bad escape or non-UTF-8 result (the
/// `gltf` crate's own import panics on the latter).
fn percent_decode(uri: &str) -> Option<String> {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = std::str::from_utf8(bytes.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Refuses accessors the reader would misread: sparse ones, element types other than the
/// attribute's, strides shorter than an element and empty ones (`gltf` checks these only with
/// debug assertions, or not at all).
fn check_accessors(document: &::gltf::Document) -> Result<(), ModelError> {
    use ::gltf::Semantic;
    use ::gltf::accessor::{DataType as D, Dimensions as N};
    for mesh in document.meshes() {
        for (p, prim) in mesh.primitives().enumerate() {
            let name = format!("{}#{p}", mesh.name().unwrap_or("mesh"));
            let mut used: Vec<(&str, ::gltf::Accessor, bool)> = Vec::new();
            for (semantic, acc) in prim.attributes() {
                let ok = match semantic {
                    Semantic::Positions => (acc.data_type(), acc.dimensions()) == (D::F32, N::Vec3),
                    Semantic::TexCoords(_) => {
                        matches!(acc.data_type(), D::F32 | D::U8 | D::U16)
                            && acc.dimensions() == N::Vec2
                    }
                    // Not read.
                    _ => continue,
                };
                used.push(("vertex attribute", acc, ok));
            }
            if let Some(acc) = prim.indices() {
                let ok = matches!(acc.data_type(), D::U8 | D::U16 | D::U32)
                    && acc.dimensions() == N::Scalar;
                used.push(("index", acc, ok));
            }
            for (what, acc, ok) in used {
                let bad = |detail: String| ModelError::UnsupportedPrimitive {
                    mesh: name.clone(),
                    detail,
                };
                if !ok {
                    return Err(bad(format!(
                        "{what} accessor {} of type {:?} {:?}",
                        acc.index(),
                        acc.dimensions(),
                        acc.data_type()
                    )));
                }
                if acc.sparse().is_some() {
                    return Err(bad(format!(
                        "sparse accessor {} (not supported)",
                        acc.index()
                    )));
                }
                if acc.count() == 0 {
                    return Err(bad(format!("accessor {} has no elements", acc.index())));
                }
                if acc.view().is_none() {
                    return Err(bad(format!("accessor {} has no buffer view", acc.index())));
                }
                if let Some(stride) = acc.view().and_then(|v| v.stride())
                    && stride < acc.size()
                {
                    return Err(bad(format!(
                        "accessor {}: stride {stride} shorter than its {}-byte elements",
                        acc.index(),
                        acc.size()
                    )));
                }
            }
        }
    }
    Ok(())
}

/// Rejects buffer views and accessors that reach past their data (the reader would panic).
fn check_ranges(document: &::gltf::Document, buffers: &[Vec<u8>]) -> Result<(), ModelError> {
    let bad = |detail: String| ModelError::BadIndex {
        mesh: "buffers".into(),
        detail,
    };
    for view in document.views() {
        let len = buffers.get(view.buffer().index()).map_or(0, Vec::len);
        let end = view.offset().checked_add(view.length());
        if end.is_none_or(|e| e > len) {
            return Err(bad(format!(
                "buffer view {} ends past its buffer ({len} bytes)",
                view.index()
            )));
        }
    }
    for acc in document.accessors() {
        let Some(view) = acc.view() else { continue };
        let elem = acc.size();
        let stride = view.stride().unwrap_or(elem);
        let need = match acc.count() {
            0 => Some(0),
            n => (n - 1)
                .checked_mul(stride)
                .and_then(|s| s.checked_add(elem))
                .and_then(|s| s.checked_add(acc.offset())),
        };
        if need.is_none_or(|n| n > view.length()) {
            return Err(bad(format!(
                "accessor {} reads past its buffer view",
                acc.index()
            )));
        }
    }
    Ok(())
}

/// The document's materials, with their base colour textures (each image decoded once).
fn materials(
    document: &::gltf::Document,
    buffers: &[Vec<u8>],
    files: &Files,
) -> Result<Vec<Material>, ModelError> {
    let mut materials = Vec::new();
    let mut decoded: Vec<Option<Arc<RgbaImage>>> = vec![None; document.images().len()];
    for (i, m) in document.materials().enumerate() {
        let name = m
            .name()
            .map_or_else(|| format!("material{i}"), str::to_owned);
        let pbr = m.pbr_metallic_roughness();
        let texture = match pbr.base_color_texture() {
            None => None,
            Some(info) => {
                let image = info.texture().source();
                // gltf's `Image::source` unwraps a URI when there is no buffer view, and a MIME
                // type when there is one (panics; found by the `gltf` fuzz target).
                let json = document.as_json().images.get(image.index());
                if json.is_none_or(|j| {
                    if j.buffer_view.is_some() {
                        j.mime_type.is_none()
                    } else {
                        j.uri.is_none()
                    }
                }) {
                    return Err(ModelError::BadIndex {
                        mesh: name,
                        detail: format!(
                            "image {}: neither a URI nor a buffer view with a MIME type",
                            image.index()
                        ),
                    });
                }
                let slot = decoded
                    .get_mut(image.index())
                    .ok_or_else(|| ModelError::BadIndex {
                        mesh: name.clone(),
                        detail: format!("image {}", image.index()),
                    })?;
                if slot.is_none() {
                    *slot = Some(Arc::new(files.texture(&name, &image, buffers)?));
                }
                slot.clone()
            }
        };
        materials.push(Material {
            name,
            base_colour: pbr.base_color_factor(),
            texture,
        });
    }
    Ok(materials)
}
