//! Procedural textured models for tests, benchmarks and demos (no files needed).

use std::sync::Arc;

use image::{Rgba, RgbaImage};

use super::{Material, Mesh, Model};

/// A checkerboard of `cells × cells` squares of `cell_px` pixels. Cell `(i, j)` (column,
/// row, from the top-left) has red 220 or 30 alternating, green `20 + 200·i/(cells−1)` and
/// blue `20 + 200·j/(cells−1)`, so every cell's colour says where it is.
pub fn checker_texture(cells: u32, cell_px: u32) -> RgbaImage {
    let cells = cells.max(2);
    let cell_px = cell_px.max(1);
    RgbaImage::from_fn(cells * cell_px, cells * cell_px, |x, y| {
        Rgba(checker_colour(cells, x / cell_px, y / cell_px))
    })
}

/// The colour of cell `(i, j)` in [`checker_texture`].
pub fn checker_colour(cells: u32, i: u32, j: u32) -> [u8; 4] {
    let cells = cells.max(2);
    let ramp = |k: u32| (20 + 200 * k.min(cells - 1) / (cells - 1)) as u8;
    let red = if (i + j) & 1 == 0 { 220 } else { 30 };
    [red, ramp(i), ramp(j), 255]
}

fn textured(name: &str, texture: Arc<RgbaImage>) -> Material {
    Material {
        name: name.into(),
        base_colour: [1.0; 4],
        texture: Some(texture),
    }
}

/// A `size_x × size_y` rectangle in the world plane z = 0 centred at the origin, textured
/// once over its whole area; texture up (row 0) is +y, texture right is +x.
pub fn plane(size_x: f32, size_y: f32, texture: Arc<RgbaImage>) -> Model {
    let (hx, hy) = (size_x / 2.0, size_y / 2.0);
    Model {
        meshes: vec![Mesh {
            name: "plane".into(),
            positions: vec![
                [-hx, -hy, 0.0],
                [hx, -hy, 0.0],
                [hx, hy, 0.0],
                [-hx, hy, 0.0],
            ],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
            indices: vec![0, 1, 2, 0, 2, 3],
            material: 0,
        }],
        materials: vec![textured("plane", texture)],
    }
}

/// An axis-aligned cube with half-side `half` centred at `centre`, each face textured once.
pub fn cube(centre: [f32; 3], half: f32, texture: Arc<RgbaImage>) -> Model {
    let mut positions = Vec::with_capacity(24);
    let mut uvs = Vec::with_capacity(24);
    let mut indices = Vec::with_capacity(36);
    // For each face: normal axis and sign; the two in-face axes span the texture.
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = positions.len() as u32;
            for (su, sv) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = centre;
                p[axis] += sign * half;
                p[a] += su * half;
                p[b] += sv * half;
                positions.push(p);
                uvs.push([(su + 1.0) / 2.0, (1.0 - sv) / 2.0]);
            }
            indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
    Model {
        meshes: vec![Mesh {
            name: "cube".into(),
            positions,
            uvs,
            indices,
            material: 0,
        }],
        materials: vec![textured("cube", texture)],
    }
}

/// A wavy `size × size` height field of `n × n` quads (`2n²` textured triangles) centred at
/// the origin in the plane z = 0, with heights up to ±`amplitude`.
pub fn terrain(n: u32, size: f32, amplitude: f32, texture: Arc<RgbaImage>) -> Model {
    let n = n.max(1);
    let verts = n + 1;
    let mut positions = Vec::with_capacity((verts * verts) as usize);
    let mut uvs = Vec::with_capacity(positions.capacity());
    for j in 0..verts {
        for i in 0..verts {
            let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
            let (x, y) = ((s - 0.5) * size, (0.5 - t) * size);
            let z = amplitude * (7.0 * s).sin() * (5.0 * t).cos();
            positions.push([x, y, z]);
            uvs.push([s * 4.0, t * 4.0]);
        }
    }
    let mut indices = Vec::with_capacity((6 * n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let k = j * verts + i;
            indices.extend_from_slice(&[k, k + 1, k + verts + 1, k, k + verts + 1, k + verts]);
        }
    }
    Model {
        meshes: vec![Mesh {
            name: "terrain".into(),
            positions,
            uvs,
            indices,
            material: 0,
        }],
        materials: vec![textured("terrain", texture)],
    }
}

/// The standard test scene: a 2 m × 2 m checkered floor (z = 0) with a 0.5 m checkered cube
/// standing at its centre.
pub fn test_scene() -> Model {
    let mut scene = plane(2.0, 2.0, Arc::new(checker_texture(8, 32)));
    scene.append(cube(
        [0.0, 0.0, 0.25],
        0.25,
        Arc::new(checker_texture(4, 32)),
    ));
    scene
}

impl Model {
    /// Appends another model's meshes and materials.
    pub fn append(&mut self, other: Model) {
        let offset = self.materials.len();
        self.materials.extend(other.materials);
        self.meshes.extend(other.meshes.into_iter().map(|m| Mesh {
            material: m.material + offset,
            ..m
        }));
    }
}
