//! Wavefront OBJ + MTL through `tobj`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{
    MAX_TRIANGLES, MAX_VERTICES, Material, Mesh, Model, ModelError, ReadFile, load_texture,
    read_from_disk,
};

/// Loads an OBJ file with its MTL libraries and diffuse (`map_Kd`) textures, resolved
/// relative to the OBJ's folder. Polygons are triangulated. A textured material's base colour
/// is white (the texture alone gives the colour); an untextured one uses `Kd`.
pub fn load_obj(path: &Path) -> Result<Model, ModelError> {
    let Some(bytes) = read_from_disk(path)? else {
        return Err(ModelError::MissingFile {
            path: path.to_owned(),
        });
    };
    parse_obj(&bytes, path, &read_from_disk)
}

/// Counts of an OBJ's text, for the limits before `tobj` allocates: `v`, `vt` and `vn` lines
/// and the triangles of its faces.
fn census(obj: &[u8]) -> (usize, usize, usize, usize) {
    let (mut v, mut vt, mut vn, mut triangles) = (0usize, 0usize, 0usize, 0usize);
    for line in obj.split(|&b| b == b'\n') {
        let line = line.trim_ascii_start();
        let mut words = line
            .split(|b| b.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => v += 1,
            Some(b"vt") => vt += 1,
            Some(b"vn") => vn += 1,
            // A polygon of k corners is k - 2 triangles.
            Some(b"f") => triangles += words.count().saturating_sub(2),
            _ => {}
        }
    }
    (v, vt, vn, triangles)
}

/// Parses an OBJ held in memory: `path` is its name in errors, and its folder the one MTL
/// libraries and textures are resolved in, read through `read`
/// ([`read_from_disk`](crate::read_from_disk) for [`load_obj`]). Limits: [`MAX_VERTICES`]
/// `v`/`vt`/`vn` lines each, [`MAX_TRIANGLES`] triangles, checked before parsing.
pub fn parse_obj(obj: &[u8], path: &Path, read: ReadFile) -> Result<Model, ModelError> {
    let (v, vt, vn, triangles) = census(obj);
    if v.max(vt).max(vn) > MAX_VERTICES || triangles > MAX_TRIANGLES {
        return Err(ModelError::TooLarge {
            what: path.display().to_string(),
            limit: format!(
                "{v} vertices, {vt} texture coordinates, {vn} normals, {triangles} triangles \
                 (at most {MAX_VERTICES} of each kind of vertex and {MAX_TRIANGLES} triangles)"
            ),
        });
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let (models, mtl) = tobj_load(obj, path, read)?;
    let mut out = Model {
        materials: load_materials(&mtl, dir, read)?,
        ..Model::default()
    };
    // Meshes without a material get a plain white one.
    let mut default_material = None;
    for model in models {
        let mesh = model.mesh;
        let material = match mesh.material_id {
            Some(id) if id < out.materials.len() => id,
            Some(id) => {
                return Err(ModelError::BadIndex {
                    mesh: model.name,
                    detail: format!("material {id} but only {} materials", out.materials.len()),
                });
            }
            None => *default_material.get_or_insert_with(|| {
                out.materials.push(Material {
                    name: "default".into(),
                    base_colour: [1.0; 4],
                    texture: None,
                });
                out.materials.len() - 1
            }),
        };
        let positions: Vec<[f32; 3]> = mesh
            .positions
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect();
        let uvs: Vec<[f32; 2]> = if mesh.texcoords.is_empty() {
            vec![[0.0; 2]; positions.len()]
        } else {
            // OBJ's v points up; ours points down the image.
            mesh.texcoords
                .chunks_exact(2)
                .map(|t| [t[0], 1.0 - t[1]])
                .collect()
        };
        out.meshes.push(Mesh {
            name: model.name,
            positions,
            uvs,
            indices: mesh.indices,
            material,
        });
    }
    out.validate(&path.display().to_string())
}

/// The colour lines `tobj` reads as three numbers (it panics on fewer): each must have three
/// words after its keyword, split as `tobj` splits them.
fn check_mtl(mtl: &[u8], path: &Path) -> Result<(), ModelError> {
    for (i, line) in mtl.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next()
            && words.take(3).count() < 3
        {
            return Err(ModelError::Syntax {
                path: path.to_owned(),
                line: i + 1,
                detail: format!("`{key}` needs three numbers (r g b)"),
            });
        }
    }
    Ok(())
}

/// `tobj`'s meshes and materials, with the MTL libraries read through `read`.
fn tobj_load(
    obj: &[u8],
    path: &Path,
    read: ReadFile,
) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>), ModelError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    // tobj's loader can only say "failed to open": the reason is kept for the error.
    let mtl_error = std::cell::RefCell::new(None);
    let loaded = tobj::load_obj_buf(&mut std::io::Cursor::new(obj), &options, |name| {
        let file = dir.join(name);
        match read(&file) {
            Ok(Some(bytes)) => match check_mtl(&bytes, &file) {
                Ok(()) => tobj::load_mtl_buf(&mut std::io::Cursor::new(bytes)),
                Err(e) => {
                    *mtl_error.borrow_mut() = Some(e);
                    Err(tobj::LoadError::MaterialParseError)
                }
            },
            Ok(None) => {
                *mtl_error.borrow_mut() = Some(ModelError::MissingFile { path: file });
                Err(tobj::LoadError::OpenFileFailed)
            }
            Err(e) => {
                *mtl_error.borrow_mut() = Some(e);
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    });
    let (models, materials) = loaded.map_err(|e| match e {
        tobj::LoadError::FaceVertexOutOfBounds
        | tobj::LoadError::FaceTexCoordOutOfBounds
        | tobj::LoadError::FaceNormalOutOfBounds
        | tobj::LoadError::FaceColorOutOfBounds => ModelError::BadIndex {
            mesh: path.display().to_string(),
            detail: e.to_string(),
        },
        _ => ModelError::Obj {
            path: path.to_owned(),
            source: e,
        },
    })?;
    let mtl = match materials {
        Ok(m) => m,
        Err(tobj::LoadError::OpenFileFailed | tobj::LoadError::MaterialParseError)
            if mtl_error.borrow().is_some() =>
        {
            return Err(mtl_error.into_inner().unwrap_or(ModelError::MissingFile {
                path: path.with_extension("mtl"),
            }));
        }
        Err(source) => {
            return Err(ModelError::Obj {
                path: path.to_owned(),
                source,
            });
        }
    };
    Ok((models, mtl))
}

/// The MTL's materials, with their diffuse textures loaded from `dir` (each file once).
fn load_materials(
    mtl: &[tobj::Material],
    dir: &Path,
    read: ReadFile,
) -> Result<Vec<Material>, ModelError> {
    let mut textures: HashMap<PathBuf, Arc<image::RgbaImage>> = HashMap::new();
    let mut materials = Vec::with_capacity(mtl.len());
    for m in mtl {
        let texture = match m.diffuse_texture.as_deref().filter(|t| !t.is_empty()) {
            None => None,
            Some(file) => {
                let tex_path = dir.join(file);
                if let Some(t) = textures.get(&tex_path) {
                    Some(t.clone())
                } else {
                    let t = Arc::new(load_texture(&m.name, &tex_path, read)?);
                    textures.insert(tex_path, t.clone());
                    Some(t)
                }
            }
        };
        let base_colour = match (&texture, m.diffuse) {
            (None, Some([r, g, b])) => [r, g, b, 1.0],
            _ => [1.0; 4],
        };
        materials.push(Material {
            name: m.name.clone(),
            base_colour,
            texture,
        });
    }
    Ok(materials)
}
