//! Model loading from small files each test writes into a temporary folder.

use std::path::Path;

use host_vision::camera::{CameraPose, Pinhole};
use host_vision::model::{ModelError, load_gltf, load_obj};
use host_vision::render::{RenderView, Renderer};
use image::{Rgba, RgbaImage};
use nalgebra::Vector3;

fn write_png(path: &Path, colour: [u8; 4]) {
    RgbaImage::from_pixel(8, 8, Rgba(colour))
        .save(path)
        .unwrap();
}

/// Two quads side by side in z = 0 (x < 0 red texture, x > 0 blue texture), a triangle with a
/// plain material, and one unused textured material sharing the red file.
const OBJ: &str = "mtllib scene.mtl
v -1 -0.5 0
v 0 -0.5 0
v 0 0.5 0
v -1 0.5 0
v 0 -0.5 0
v 1 -0.5 0
v 1 0.5 0
v 0 0.5 0
v 0 0 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
o red_quad
usemtl red
f 1/1 2/2 3/3 4/4
o blue_quad
usemtl blue
f 5/1 6/2 7/3 8/4
o plain_tri
usemtl plain
f 1 2 9
";

const MTL: &str = "newmtl red
Kd 0.8 0.8 0.8
map_Kd red.png
newmtl blue
map_Kd textures/blue.png
newmtl plain
Kd 0.2 0.4 0.6
newmtl red_again
map_Kd red.png
";

fn write_obj_scene(dir: &Path) -> std::path::PathBuf {
    std::fs::create_dir_all(dir.join("textures")).unwrap();
    write_png(&dir.join("red.png"), [255, 0, 0, 255]);
    write_png(&dir.join("textures/blue.png"), [0, 0, 255, 255]);
    std::fs::write(dir.join("scene.mtl"), MTL).unwrap();
    let obj = dir.join("scene.obj");
    std::fs::write(&obj, OBJ).unwrap();
    obj
}

#[test]
fn obj_with_several_textured_materials() {
    let dir = tempfile::tempdir().unwrap();
    let model = load_obj(&write_obj_scene(dir.path())).unwrap();
    assert_eq!(model.triangle_count(), 5);
    assert_eq!(model.meshes.len(), 3);
    let names: Vec<_> = model.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["red", "blue", "plain", "red_again"]);
    let red = &model.materials[0];
    assert_eq!(
        red.texture.as_ref().unwrap().get_pixel(0, 0).0,
        [255, 0, 0, 255]
    );
    assert_eq!(
        red.base_colour, [1.0; 4],
        "textured: the texture gives the colour"
    );
    // The same file is decoded once and shared.
    assert!(std::sync::Arc::ptr_eq(
        red.texture.as_ref().unwrap(),
        model.materials[3].texture.as_ref().unwrap()
    ));
    assert_eq!(model.materials[2].base_colour, [0.2, 0.4, 0.6, 1.0]);
    assert!(model.materials[2].texture.is_none());
    // OBJ v = 0 is the image's bottom row: v is flipped to our top-left origin.
    let quad = &model.meshes[0];
    assert_eq!(model.materials[quad.material].name, "red");
    let i = quad
        .positions
        .iter()
        .position(|p| *p == [-1.0, -0.5, 0.0])
        .unwrap();
    assert_eq!(quad.uvs[i], [0.0, 1.0]);
}

#[test]
fn obj_errors_are_typed() {
    let dir = tempfile::tempdir().unwrap();
    let obj = write_obj_scene(dir.path());

    assert!(matches!(
        load_obj(&dir.path().join("absent.obj")),
        Err(ModelError::MissingFile { .. })
    ));

    std::fs::remove_file(dir.path().join("textures/blue.png")).unwrap();
    match load_obj(&obj) {
        Err(ModelError::MissingTexture { material, path }) => {
            assert_eq!(material, "blue");
            assert!(path.ends_with("textures/blue.png"));
        }
        other => panic!("expected MissingTexture, got {other:?}"),
    }
    std::fs::write(dir.path().join("textures/blue.png"), b"not a png").unwrap();
    assert!(matches!(load_obj(&obj), Err(ModelError::Texture { .. })));

    std::fs::remove_file(dir.path().join("scene.mtl")).unwrap();
    match load_obj(&obj) {
        Err(e @ ModelError::MissingFile { .. }) => assert!(e.to_string().contains("scene.mtl")),
        other => panic!("expected MissingFile, got {other:?}"),
    }

    let bad = dir.path().join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n").unwrap();
    let e = load_obj(&bad).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");

    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    assert!(matches!(load_obj(&bad), Err(ModelError::Empty { .. })));
    std::fs::write(&bad, "").unwrap();
    assert!(matches!(load_obj(&bad), Err(ModelError::Empty { .. })));
}

/// One textured triangle (0,0,0), (1,0,0), (0,1,0) under a node translated by (1, 2, 3).
fn write_gltf(dir: &Path, mode: u32, index: u16, view0_len: usize) -> std::path::PathBuf {
    let mut bin = Vec::new();
    for p in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        p.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for t in [[0f32, 0.0], [1.0, 0.0], [0.0, 1.0]] {
        t.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for i in [0u16, 1, index, 0] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(dir.join("mesh.bin"), &bin).unwrap();
    write_png(&dir.join("tex.png"), [0, 255, 0, 255]);
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [{{"mesh": 0, "translation": [1.0, 2.0, 3.0]}}],
  "meshes": [{{"name": "tri", "primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 1}},
      "indices": 2, "material": 0, "mode": {mode}}}]}}],
  "materials": [{{"name": "green", "pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}},
      "baseColorFactor": [1.0, 0.5, 1.0, 1.0]}}}}],
  "textures": [{{"source": 0}}],
  "images": [{{"uri": "tex.png"}}],
  "buffers": [{{"uri": "mesh.bin", "byteLength": {len}}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": {view0_len}}},
    {{"buffer": 0, "byteOffset": 36, "byteLength": 24}},
    {{"buffer": 0, "byteOffset": 60, "byteLength": 6}}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
      "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}},
    {{"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}}]
}}"#,
        len = bin.len()
    );
    let path = dir.join("tri.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

#[test]
fn gltf_with_texture_node_transform_and_z_up() {
    let dir = tempfile::tempdir().unwrap();
    let model = load_gltf(&write_gltf(dir.path(), 4, 2, 36)).unwrap();
    assert_eq!(model.triangle_count(), 1);
    let mesh = &model.meshes[0];
    // glTF (x, y, z) + (1, 2, 3), then y-up → z-up: (x, −z, y).
    assert_eq!(
        mesh.positions,
        vec![[1.0, -3.0, 2.0], [2.0, -3.0, 2.0], [1.0, -3.0, 3.0]]
    );
    assert_eq!(mesh.uvs, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    let m = &model.materials[mesh.material];
    assert_eq!(m.name, "green");
    assert_eq!(m.base_colour, [1.0, 0.5, 1.0, 1.0]);
    assert_eq!(
        m.texture.as_ref().unwrap().get_pixel(3, 3).0,
        [0, 255, 0, 255]
    );
}

#[test]
fn gltf_errors_are_typed() {
    let dir = tempfile::tempdir().unwrap();
    let e = load_gltf(&write_gltf(dir.path(), 4, 7, 36)).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
    // An accessor reaching past its buffer view.
    let e = load_gltf(&write_gltf(dir.path(), 4, 2, 24)).unwrap_err();
    assert!(
        matches!(e, ModelError::BadIndex { .. } | ModelError::Gltf { .. }),
        "{e:?}"
    );
    // Lines are not triangles.
    let e = load_gltf(&write_gltf(dir.path(), 1, 2, 36)).unwrap_err();
    assert!(
        matches!(e, ModelError::UnsupportedPrimitive { .. }),
        "{e:?}"
    );

    let path = write_gltf(dir.path(), 4, 2, 36);
    std::fs::remove_file(dir.path().join("tex.png")).unwrap();
    match load_gltf(&path) {
        Err(ModelError::MissingTexture { material, .. }) => assert_eq!(material, "green"),
        other => panic!("expected MissingTexture, got {other:?}"),
    }
    assert!(matches!(
        load_gltf(&dir.path().join("absent.gltf")),
        Err(ModelError::MissingFile { .. })
    ));
    std::fs::write(&path, "{ not json").unwrap();
    assert!(matches!(load_gltf(&path), Err(ModelError::Gltf { .. })));
    std::fs::write(&path, r#"{"asset": {"version": "2.0"}}"#).unwrap();
    assert!(matches!(load_gltf(&path), Err(ModelError::Empty { .. })));
}

/// End to end: the OBJ's two textures appear where their quads are (GPU).
#[test]
fn obj_materials_render_with_their_textures() {
    let dir = tempfile::tempdir().unwrap();
    let model = load_obj(&write_obj_scene(dir.path())).unwrap();
    let mut r = Renderer::new(160, 120)
        .unwrap_or_else(|e| panic!("the GPU tests need a wgpu adapter: {e}"));
    r.set_model(&model).unwrap();
    let pose =
        CameraPose::look_at(Vector3::new(0.0, 0.0, 2.0), Vector3::zeros(), Vector3::y()).unwrap();
    let frame = r
        .render(&RenderView {
            pinhole: Pinhole::new(100.0, 100.0, 79.5, 59.5),
            pose,
            near: 0.1,
            far: 10.0,
        })
        .unwrap();
    // World −x is image left (x right, y up seen from above): red left, blue right.
    assert_eq!(frame.rgba.get_pixel(50, 59).0, [255, 0, 0, 255]);
    assert_eq!(frame.rgba.get_pixel(110, 59).0, [0, 0, 255, 255]);
    assert_eq!(frame.mask.get_pixel(2, 2).0, [0]);
    assert!((frame.depth_at(50, 59).unwrap() - 2.0).abs() < 1e-5);
}
