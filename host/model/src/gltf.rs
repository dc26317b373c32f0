//! glTF 2.0 (`.gltf` with external or embedded buffers, `.glb`) through the `gltf` crate.

use std::path::Path;
use std::sync::Arc;

use ::gltf::image::Format;
use ::gltf::mesh::Mode;
use image::RgbaImage;
use nalgebra::{Matrix4, Vector4};

use super::{Material, Mesh, Model, ModelError};

/// Loads the default scene (else the first) of a glTF file, applying node transforms, with
/// each material's base colour factor and base colour texture.
///
/// glTF is metres with +Y up; the world frame has +Z up (docs/FILTER.md §2), so positions are
/// rotated by +90° about x: `(x, y, z)_gltf → (x, −z, y)_w`.
pub fn load_gltf(path: &Path) -> Result<Model, ModelError> {
    if !path.is_file() {
        return Err(ModelError::MissingFile {
            path: path.to_owned(),
        });
    }
    let gltf_err = |source| ModelError::Gltf {
        path: path.to_owned(),
        source,
    };
    let ::gltf::Gltf { document, blob } = ::gltf::Gltf::open(path).map_err(gltf_err)?;
    let base = path.parent().unwrap_or(Path::new("."));
    check_texture_files(&document, base)?;
    let buffers = ::gltf::import_buffers(&document, Some(base), blob).map_err(gltf_err)?;
    check_ranges(&document, &buffers)?;
    let images = ::gltf::import_images(&document, Some(base), &buffers).map_err(gltf_err)?;

    let mut model = Model {
        materials: materials(&document, &images)?,
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
                let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
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
                model.meshes.push(Mesh {
                    name,
                    positions,
                    uvs,
                    indices,
                    material: prim.material().index().unwrap_or(default_material),
                });
            }
        }
        stack.extend(node.children().map(|c| (c, global)));
    }
    model.validate(&path.display().to_string())
}

/// Names a missing external texture before the generic import would fail on it.
fn check_texture_files(document: &::gltf::Document, base: &Path) -> Result<(), ModelError> {
    for m in document.materials() {
        let Some(info) = m.pbr_metallic_roughness().base_color_texture() else {
            continue;
        };
        let ::gltf::image::Source::Uri { uri, .. } = info.texture().source().source() else {
            continue;
        };
        let file = base.join(uri);
        if !uri.starts_with("data:") && !file.is_file() {
            return Err(ModelError::MissingTexture {
                material: m.name().unwrap_or("unnamed").into(),
                path: file,
            });
        }
    }
    Ok(())
}

/// Rejects buffer views and accessors that reach past their data (the reader would panic).
fn check_ranges(
    document: &::gltf::Document,
    buffers: &[::gltf::buffer::Data],
) -> Result<(), ModelError> {
    let bad = |detail: String| ModelError::BadIndex {
        mesh: "buffers".into(),
        detail,
    };
    for view in document.views() {
        let len = buffers.get(view.buffer().index()).map_or(0, |b| b.0.len());
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

/// The document's materials, with their base colour textures from `images`.
fn materials(
    document: &::gltf::Document,
    images: &[::gltf::image::Data],
) -> Result<Vec<Material>, ModelError> {
    let mut materials = Vec::new();
    for (i, m) in document.materials().enumerate() {
        let name = m
            .name()
            .map_or_else(|| format!("material{i}"), str::to_owned);
        let pbr = m.pbr_metallic_roughness();
        let texture = match pbr.base_color_texture() {
            None => None,
            Some(info) => {
                let index = info.texture().source().index();
                let data = images.get(index).ok_or_else(|| ModelError::BadIndex {
                    mesh: name.clone(),
                    detail: format!("image {index} of {}", images.len()),
                })?;
                Some(Arc::new(to_rgba(&name, data)?))
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

fn to_rgba(name: &str, data: &::gltf::image::Data) -> Result<RgbaImage, ModelError> {
    let px = data.width as usize * data.height as usize;
    let channels = match data.format {
        Format::R8 => 1,
        Format::R8G8 => 2,
        Format::R8G8B8 => 3,
        Format::R8G8B8A8 => 4,
        other => {
            return Err(ModelError::TextureFormat {
                what: name.into(),
                format: format!("{other:?}"),
            });
        }
    };
    if data.pixels.len() < px * channels {
        return Err(ModelError::TextureFormat {
            what: name.into(),
            format: "truncated pixel data".into(),
        });
    }
    let mut rgba = Vec::with_capacity(px * 4);
    for p in data.pixels.chunks_exact(channels).take(px) {
        rgba.extend_from_slice(&match *p {
            [l] => [l, l, l, 255],
            [l, a] => [l, l, l, a],
            [r, g, b] => [r, g, b, 255],
            [r, g, b, a] => [r, g, b, a],
            _ => [0, 0, 0, 255],
        });
    }
    RgbaImage::from_raw(data.width, data.height, rgba).ok_or_else(|| ModelError::TextureFormat {
        what: name.into(),
        format: "inconsistent size".into(),
    })
}
