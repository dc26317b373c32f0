//! A scenario's scene as renderable models: the CAD model (modelled surfaces only), the live
//! world (modelled + unmodelled surfaces), the occluders in their own frames; and the model
//! folder writer (OBJ + MTL + PNG).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use firmware_sim::sim::scenario::{Quad, Scene};
use image::RgbaImage;

use super::SynthError;
use super::texture;
use crate::model::{Material, Mesh, Model};

/// Where textures come from.
#[derive(Debug, Clone, Default)]
pub struct TextureOptions {
    /// Multiplies every surface's texel density (below 1 for quick tests).
    pub scale: f64,
    /// Largest texture side [texels].
    pub max_side: u32,
    /// User images for the modelled surfaces, used in turn instead of generated ones.
    pub user_images: Vec<PathBuf>,
    /// Explicit textures by quad name (tests).
    pub overrides: HashMap<String, Arc<RgbaImage>>,
    /// The modelled surfaces in this one linear RGB colour, with no texture: an object
    /// without texture (issue 37). The unmodelled surroundings keep theirs.
    pub untextured: Option<[f32; 3]>,
}

/// The solid colour of `synth --untextured`: an orange whose grey (BT.601 luma 0.53) lies
/// between the generated textures' dark and bright grey levels, so that only its statistics
/// beside the contour, not a brightness threshold, tell it from its surroundings.
pub const UNTEXTURED_COLOUR: [f32; 3] = [0.85, 0.45, 0.15];

impl TextureOptions {
    /// Generated textures at full density, up to 4096 texels per side.
    pub fn generated() -> Self {
        TextureOptions {
            scale: 1.0,
            max_side: 4096,
            ..Default::default()
        }
    }
}

/// Renderable models of a scene.
#[derive(Debug, Clone)]
pub struct SceneModels {
    /// The CAD model: what the tracker knows.
    pub model: Model,
    /// What the camera sees (without the occluders).
    pub live: Model,
    /// Each occluder in its own frame (centred at its origin).
    pub occluders: Vec<Model>,
}

fn quad_mesh(name: &str, corners: [[f32; 3]; 4], material: usize) -> Mesh {
    Mesh {
        name: name.into(),
        positions: corners.to_vec(),
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        material,
    }
}

fn f32x3(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl SceneModels {
    /// Builds the models, generating (or loading) one texture per surface.
    pub fn build(scene: &Scene, options: &TextureOptions) -> Result<Self, SynthError> {
        Self::build_with(scene, options, None)
    }

    /// [`Self::build`], with `object` (a mesh in metres, y up, its origin at the centre of
    /// its base, as `../shared/data/meshes/bunny` is) in place of the modelled surfaces: stood
    /// upright where they stand, in the untextured colour where one is given, else in its
    /// own materials.
    pub fn build_with(
        scene: &Scene,
        options: &TextureOptions,
        object: Option<&Model>,
    ) -> Result<Self, SynthError> {
        if !(options.scale.is_finite() && options.scale > 0.0 && options.scale <= 16.0) {
            return Err(SynthError::BadOption(format!(
                "texture scale must be in (0, 16], got {}",
                options.scale
            )));
        }
        let mut users = Vec::new();
        for p in &options.user_images {
            let img = camera::read_frame(p)
                .map_err(|source| SynthError::Texture {
                    path: p.clone(),
                    source,
                })?
                .to_rgba8();
            users.push(Arc::new(img));
        }
        let texture_of = |q: &Quad, user: Option<&Arc<RgbaImage>>| -> Arc<RgbaImage> {
            if let Some(t) = options.overrides.get(&q.name) {
                return t.clone();
            }
            if let Some(u) = user {
                return u.clone();
            }
            let size = q.size();
            let (w, h) =
                texture::texture_size(size, q.texels_per_metre * options.scale, options.max_side);
            Arc::new(texture::generate(q.surface, q.texture_seed, size, w, h))
        };
        let mut model = Model::default();
        if let Some(object) = object {
            model = placed(object, scene, options.untextured)?;
        } else {
            for (i, q) in scene.modelled.iter().enumerate() {
                match options.untextured {
                    Some([r, g, b]) => add_quad(&mut model, q, None, [r, g, b, 1.0]),
                    None => {
                        let user = (!users.is_empty()).then(|| &users[i % users.len()]);
                        add_quad(&mut model, q, Some(texture_of(q, user)), [1.0; 4]);
                    }
                }
            }
        }
        let mut live = model.clone();
        for q in &scene.unmodelled {
            add_quad(&mut live, q, Some(texture_of(q, None)), [1.0; 4]);
        }
        let occluders = scene
            .occluders
            .iter()
            .map(|o| {
                let mut m = Model::default();
                add_quad(&mut m, &o.quad, Some(texture_of(&o.quad, None)), [1.0; 4]);
                m
            })
            .collect();
        Ok(SceneModels {
            model,
            live,
            occluders,
        })
    }
}

/// `object` (y up, origin at its base's centre) turned z up and stood on the floor of the
/// scene's modelled surfaces, at their centre; its materials in `colour` where given.
fn placed(object: &Model, scene: &Scene, colour: Option<[f32; 3]>) -> Result<Model, SynthError> {
    let corners = || scene.modelled.iter().flat_map(|q| q.corners.iter());
    let lowest = corners().map(|c| c.z).fold(f64::INFINITY, f64::min);
    let (lo, hi) = corners().fold(
        (
            nalgebra::Vector3::repeat(f64::INFINITY),
            nalgebra::Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), c| (lo.inf(c), hi.sup(c)),
    );
    if !lowest.is_finite() {
        return Err(SynthError::BadOption(
            "the scenario has no modelled surface to stand an object on".into(),
        ));
    }
    let base = [(lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0, lowest].map(|v| v as f32);
    let mut m = object.clone();
    for p in m
        .meshes
        .iter_mut()
        .flat_map(|mesh| mesh.positions.iter_mut())
    {
        // y up → z up: (x, y, z) ↦ (x, −z, y), a rotation about x.
        *p = [p[0] + base[0], -p[2] + base[1], p[1] + base[2]];
    }
    if let Some([r, g, b]) = colour {
        for mat in &mut m.materials {
            mat.base_colour = [r, g, b, 1.0];
            mat.texture = None;
        }
    }
    Ok(m)
}

fn add_quad(model: &mut Model, q: &Quad, texture: Option<Arc<RgbaImage>>, base_colour: [f32; 4]) {
    let material = model.materials.len();
    model.materials.push(Material {
        name: q.name.clone(),
        base_colour,
        texture,
    });
    let c = q.corners.map(|p| f32x3(&p));
    model.meshes.push(quad_mesh(&q.name, c, material));
}

/// Writes `model` as `dir/scene.obj` + `dir/scene.mtl` + one PNG per material; returns the
/// OBJ's path. Texture `v` is flipped to OBJ's bottom-up convention.
pub fn write_obj(dir: &Path, model: &Model) -> Result<PathBuf, SynthError> {
    std::fs::create_dir_all(dir).map_err(|e| SynthError::io(dir, e))?;
    let mut obj = String::from(
        "# Synthetic scene model (host-vision synth): metres, world frame, z up.\nmtllib scene.mtl\n",
    );
    let mut mtl = String::from("# Materials of scene.obj\n");
    let mut base = 1usize;
    for mesh in &model.meshes {
        let mat = &model.materials[mesh.material];
        let _ = writeln!(obj, "o {}", mesh.name);
        for p in &mesh.positions {
            let _ = writeln!(obj, "v {} {} {}", p[0], p[1], p[2]);
        }
        for t in &mesh.uvs {
            let _ = writeln!(obj, "vt {} {}", t[0], 1.0 - t[1]);
        }
        let _ = writeln!(obj, "usemtl {}", mat.name);
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| i as usize + base);
            let _ = writeln!(obj, "f {a}/{a} {b}/{b} {c}/{c}");
        }
        base += mesh.positions.len();
    }
    for mat in &model.materials {
        let [r, g, b, _] = mat.base_colour;
        let _ = writeln!(
            mtl,
            "newmtl {}\nKa 1 1 1\nKd {r} {g} {b}\nKs 0 0 0\nillum 1",
            mat.name
        );
        if let Some(tex) = &mat.texture {
            let file = format!("{}.png", mat.name);
            let path = dir.join(&file);
            tex.save(&path).map_err(|source| SynthError::Image {
                path: path.clone(),
                source,
            })?;
            let _ = writeln!(mtl, "map_Kd {file}");
        }
        mtl.push('\n');
    }
    let obj_path = dir.join("scene.obj");
    std::fs::write(&obj_path, obj).map_err(|e| SynthError::io(&obj_path, e))?;
    let mtl_path = dir.join("scene.mtl");
    std::fs::write(&mtl_path, mtl).map_err(|e| SynthError::io(&mtl_path, e))?;
    Ok(obj_path)
}
