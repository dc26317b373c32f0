//! Wavefront OBJ + MTL through `tobj`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{Material, Mesh, Model, ModelError, load_texture};

/// Loads an OBJ file with its MTL libraries and diffuse (`map_Kd`) textures, resolved
/// relative to the OBJ's folder. Polygons are triangulated. A textured material's base colour
/// is white (the texture alone gives the colour); an untextured one uses `Kd`.
pub fn load_obj(path: &Path) -> Result<Model, ModelError> {
    if !path.is_file() {
        return Err(ModelError::MissingFile {
            path: path.to_owned(),
        });
    }
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let (models, materials) = tobj::load_obj(path, &options).map_err(|e| match e {
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
    let dir = path.parent().unwrap_or(Path::new("."));
    let mtl = match materials {
        Ok(m) => m,
        Err(tobj::LoadError::OpenFileFailed) => {
            return Err(ModelError::MissingFile {
                path: mtllib(path).unwrap_or_else(|| path.with_extension("mtl")),
            });
        }
        Err(source) => {
            return Err(ModelError::Obj {
                path: path.to_owned(),
                source,
            });
        }
    };

    let mut out = Model {
        materials: load_materials(&mtl, dir)?,
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

/// The MTL's materials, with their diffuse textures loaded from `dir` (each file once).
fn load_materials(mtl: &[tobj::Material], dir: &Path) -> Result<Vec<Material>, ModelError> {
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
                    let t = Arc::new(load_texture(&m.name, &tex_path)?);
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

/// The first `mtllib` the OBJ names (for the error message when it is missing).
fn mtllib(obj: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string(obj).ok()?;
    let name = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("mtllib "))?
        .trim();
    Some(obj.parent().unwrap_or(Path::new(".")).join(name))
}
