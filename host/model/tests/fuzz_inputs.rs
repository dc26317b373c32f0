//! The model loaders on arbitrary and mutated files (issue 40): every input gives a model that
//! passes its checks or a typed error, never a panic. The cargo-fuzz targets in `../fuzz` run
//! the same parsers for longer; the crashes they found are the regression tests at the end.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use model::{
    MAX_TEXTURE_SIDE, MAX_TRIANGLES, Model, ModelError, decode_texture, parse_gltf, parse_obj,
};
use proptest::prelude::*;

/// Files in memory, by path, as the loaders' `read` sees them.
struct Memory(HashMap<PathBuf, Vec<u8>>);

impl Memory {
    fn read(&self, path: &Path) -> Result<Option<Vec<u8>>, ModelError> {
        Ok(self.0.get(path).cloned())
    }
}

fn png(width: u32, height: u32) -> Vec<u8> {
    let img = image::RgbaImage::from_pixel(width, height, image::Rgba([200, 10, 10, 255]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// A textured quad and a plain triangle, with negative (relative) indices too.
const OBJ: &str = "mtllib scene.mtl
v -1 -0.5 0
v 0 -0.5 0
v 0 0.5 0
v -1 0.5 0
v 0 0 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
o quad
usemtl red
f 1/1/1 2/2/1 3/3/1 4/4/1
o tri
usemtl plain
f -5 -4 -1
";

const MTL: &str = "newmtl red
Kd 0.8 0.8 0.8
map_Kd red.png
newmtl plain
Kd 0.2 0.4 0.6
";

fn obj_files(mtl: &[u8], texture: &[u8]) -> Memory {
    Memory(HashMap::from([
        (PathBuf::from("m/scene.mtl"), mtl.to_vec()),
        (PathBuf::from("m/red.png"), texture.to_vec()),
    ]))
}

fn load_obj_bytes(obj: &[u8], files: &Memory) -> Result<Model, ModelError> {
    parse_obj(obj, Path::new("m/scene.obj"), &|p| files.read(p))
}

/// The shared data's real cube (6144 faces) and its MTL, when the folder is there.
fn real_obj() -> Option<(Vec<u8>, Memory)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/visp-cube/model");
    let text = std::fs::read(dir.join("cube.obj")).ok()?;
    let mtl = std::fs::read(dir.join("cube.mtl")).ok()?;
    let files = Memory(HashMap::from([
        (PathBuf::from("m/cube.mtl"), mtl),
        (PathBuf::from("m/color.jpg"), png(2, 2)),
    ]));
    Some((text, files))
}

/// One textured triangle with its buffer and PNG embedded as data URIs.
fn gltf_json() -> String {
    let mut bin = Vec::new();
    for c in [
        0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0,
    ] {
        bin.extend_from_slice(&c.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
  "nodes": [{{"mesh": 0, "translation": [1.0, 2.0, 3.0], "children": [1]}}, {{"mesh": 0}}],
  "meshes": [{{"name": "tri", "primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 1}},
      "indices": 2, "material": 0}}]}}],
  "materials": [{{"name": "green", "pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}],
  "textures": [{{"source": 0}}],
  "images": [{{"uri": "data:image/png;base64,{png}"}}],
  "buffers": [{{"uri": "data:application/octet-stream;base64,{buf}", "byteLength": {len}}}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 36}},
    {{"buffer": 0, "byteOffset": 36, "byteLength": 24}},
    {{"buffer": 0, "byteOffset": 60, "byteLength": 6}}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
      "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}},
    {{"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}}]}}"#,
        png = base64(&png(2, 2)),
        buf = base64(&bin),
        len = bin.len()
    )
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk
            .iter()
            .enumerate()
            .fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
        for i in 0..=chunk.len() {
            out.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
        }
    }
    out
}

fn load_gltf_bytes(bytes: &[u8]) -> Result<Model, ModelError> {
    let none = Memory(HashMap::new());
    parse_gltf(bytes, Path::new("m/scene.gltf"), &|p| none.read(p))
}

/// Bit flips, truncations, insertions and overwrites with bytes that matter to text formats.
fn mutated(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    fuzz_support::mutated(seed, b"0-9/. \n%e")
}

/// A loaded model satisfies its own checks (a parser never hands out a broken one).
fn sound(result: Result<Model, ModelError>) {
    if let Ok(m) = result {
        m.check("fuzzed").expect("a loaded model passes its checks");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn obj_of_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        sound(load_obj_bytes(&bytes, &obj_files(MTL.as_bytes(), &png(2, 2))));
    }

    #[test]
    fn obj_mutated(bytes in mutated(OBJ.as_bytes().to_vec())) {
        sound(load_obj_bytes(&bytes, &obj_files(MTL.as_bytes(), &png(2, 2))));
    }

    #[test]
    fn mtl_mutated(bytes in mutated(MTL.as_bytes().to_vec())) {
        sound(load_obj_bytes(OBJ.as_bytes(), &obj_files(&bytes, &png(2, 2))));
    }

    #[test]
    fn texture_mutated(bytes in mutated(png(4, 3))) {
        if let Ok(t) = decode_texture(Path::new("t.png"), &bytes) {
            prop_assert!(t.width() <= MAX_TEXTURE_SIDE && t.height() <= MAX_TEXTURE_SIDE);
        }
    }

    #[test]
    fn gltf_of_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        sound(load_gltf_bytes(&bytes));
    }

    #[test]
    fn gltf_mutated(bytes in mutated(gltf_json().into_bytes())) {
        sound(load_gltf_bytes(&bytes));
    }
}

proptest! {
    // Each case parses the whole 610 KiB file.
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn real_obj_mutated(cut in any::<prop::sample::Index>(), flip in any::<prop::sample::Index>(), bit in 0u8..8) {
        let Some((mut bytes, files)) = real_obj() else { return Ok(()) };
        let i = flip.index(bytes.len());
        bytes[i] ^= 1 << bit;
        bytes.truncate(cut.index(bytes.len() + 1));
        sound(load_obj_bytes(&bytes, &files));
    }
}

#[test]
fn the_seeds_load() {
    let m = load_obj_bytes(OBJ.as_bytes(), &obj_files(MTL.as_bytes(), &png(2, 2))).unwrap();
    assert_eq!(m.triangle_count(), 3);
    let g = load_gltf_bytes(gltf_json().as_bytes()).unwrap();
    // The mesh under the root and again under its child.
    assert_eq!(g.triangle_count(), 2);
    assert!(g.materials[0].texture.is_some());
    if let Some((real, files)) = real_obj() {
        load_obj_bytes(&real, &files).unwrap();
    }
}

#[test]
fn an_obj_face_index_of_2_pow_32_is_a_bad_index() {
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4294967296\n";
    let e = load_obj_bytes(obj, &obj_files(b"", b"")).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4294967296\n";
    let e = load_obj_bytes(obj, &obj_files(b"", b"")).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
}

#[test]
fn too_many_triangles_are_refused_before_parsing() {
    // One polygon of MAX_TRIANGLES + 3 corners: MAX_TRIANGLES + 1 triangles.
    let mut obj = String::from("v 0 0 0\nf");
    obj.extend(std::iter::repeat_n(" 1", MAX_TRIANGLES + 3));
    let e = load_obj_bytes(obj.as_bytes(), &obj_files(b"", b"")).unwrap_err();
    assert!(matches!(e, ModelError::TooLarge { .. }), "{e:?}");
    assert!(e.to_string().contains("at most"), "{e}");
}

#[test]
fn a_texture_past_the_side_limit_is_refused_from_its_header() {
    // A valid PNG whose header claims 20000 x 20000 px (1.6 GB of RGBA8).
    let mut bytes = png(1, 1);
    bytes[16..20].copy_from_slice(&20000u32.to_be_bytes());
    bytes[20..24].copy_from_slice(&20000u32.to_be_bytes());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    let e = decode_texture(Path::new("big.png"), &bytes).unwrap_err();
    assert!(matches!(e, ModelError::TooLarge { .. }), "{e:?}");
    assert!(e.to_string().contains("16384x16384"), "{e}");
}

#[test]
fn gltf_uris_and_accessors_the_reader_would_misread_are_refused() {
    let json = gltf_json();
    // Invalid percent-encoding: the gltf crate's own import panics on it.
    let bad = json.replace("data:application/octet-stream;base64,", "%FF");
    let e = load_gltf_bytes(bad.as_bytes()).unwrap_err();
    assert!(matches!(e, ModelError::BadUri { .. }), "{e:?}");
    // POSITION as scalars (a debug assertion in the gltf reader).
    let bad = json.replacen(r#""type": "VEC3""#, r#""type": "SCALAR""#, 1);
    let e = load_gltf_bytes(bad.as_bytes()).unwrap_err();
    assert!(
        matches!(e, ModelError::UnsupportedPrimitive { .. }),
        "{e:?}"
    );
    // No elements (`count - 1` underflows in the reader).
    let bad = json.replacen(r#""count": 3"#, r#""count": 0"#, 1);
    let e = load_gltf_bytes(bad.as_bytes()).unwrap_err();
    assert!(
        matches!(e, ModelError::UnsupportedPrimitive { .. }),
        "{e:?}"
    );
    // A buffer view past its buffer.
    let bad = json.replacen(r#""byteLength": 36"#, r#""byteLength": 3600"#, 1);
    let e = load_gltf_bytes(bad.as_bytes()).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
    // A non-finite colour.
    let bad = json.replace(
        r#""baseColorTexture""#,
        r#""baseColorFactor": [1e999, 0, 0, 1], "baseColorTexture""#,
    );
    assert!(load_gltf_bytes(bad.as_bytes()).is_err());
}

/// Found by `mtl_mutated`: `tobj` unwraps three numbers after `Kd` (a panic for fewer).
#[test]
fn an_mtl_colour_of_one_number_is_a_syntax_error() {
    let mtl = b"newmtl red\nKd 0.8\nmap_Kd red.png\n";
    let e = load_obj_bytes(OBJ.as_bytes(), &obj_files(mtl, &png(2, 2))).unwrap_err();
    assert!(matches!(e, ModelError::Syntax { line: 2, .. }), "{e:?}");
    // Split on any Unicode white space, as tobj splits.
    let mtl = "newmtl red\nKd\u{3000}1 2\n";
    let e = load_obj_bytes(OBJ.as_bytes(), &obj_files(mtl.as_bytes(), &png(2, 2))).unwrap_err();
    assert!(e.to_string().contains("three numbers"), "{e}");
}

/// Found by `gltf_mutated`: gltf-json's validation indexes the accessors by POSITION's index
/// before checking it.
#[test]
fn a_gltf_position_accessor_past_the_accessors_is_a_bad_index() {
    let json = gltf_json().replace(r#""POSITION": 0"#, r#""POSITION": 9"#);
    let e = load_gltf_bytes(json.as_bytes()).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
}

/// Found by the `gltf` fuzz target (crash-f589177e…): a GLB header whose length field is under
/// its own 12 bytes (gltf's reader subtracts unchecked).
#[test]
fn a_glb_length_under_its_header_is_a_gltf_error() {
    let bytes = b"glTF\x02\x02\0\0\0\0\0\0\0y\x82";
    let e = load_gltf_bytes(bytes).unwrap_err();
    assert!(matches!(e, ModelError::Gltf { .. }), "{e:?}");
}

/// Found by the `gltf` fuzz target (crash-5822e911…, a GLB whose image lost its `bufferView`
/// key): gltf's `Image::source` unwraps the URI it then expects.
#[test]
fn a_gltf_image_without_uri_or_view_is_a_bad_index() {
    let json = gltf_json();
    let start = json.find(r#""images""#).unwrap();
    let end = start + json[start..].find(']').unwrap() + 1;
    let no_source = format!(
        "{}\"images\": [{{\"name\": \"x\"}}]{}",
        &json[..start],
        &json[end..]
    );
    let e = load_gltf_bytes(no_source.as_bytes()).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
    let view_no_mime = format!(
        "{}\"images\": [{{\"bufferView\": 0}}]{}",
        &json[..start],
        &json[end..]
    );
    let e = load_gltf_bytes(view_no_mime.as_bytes()).unwrap_err();
    assert!(matches!(e, ModelError::BadIndex { .. }), "{e:?}");
}
