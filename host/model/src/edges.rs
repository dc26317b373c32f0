//! The model's edges as a person would draw them: creases, where the two triangles that share
//! an edge turn by more than an angle, and open boundaries, where only one triangle has it.
//! Vertices are matched by position, since a texture seam splits a vertex in two.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::Model;

/// A vertex position's key: its bits, so that split vertices at one position are one.
type Key = [u32; 3];

/// An edge's ends, and the normals of the triangles that have it.
type Edge = ([[f32; 3]; 2], Vec<Vector3<f32>>);

fn key(p: [f32; 3]) -> Key {
    // +0.0 and -0.0 are one position.
    p.map(|c| (c + 0.0).to_bits())
}

fn normal(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> Option<Vector3<f32>> {
    let (a, b, c) = (Vector3::from(a), Vector3::from(b), Vector3::from(c));
    (b - a).cross(&(c - a)).try_normalize(0.0)
}

impl Model {
    /// Its crease and boundary edges (see the module's text), as segments in the model's
    /// frame [m]: edges whose two triangles' normals differ by more than `min_angle_rad`,
    /// edges of one triangle, and edges of three or more.
    pub fn crease_edges(&self, min_angle_rad: f32) -> Vec<[[f32; 3]; 2]> {
        // Each edge (its ends' keys in order) → its ends and its triangles' normals.
        let mut edges: HashMap<(Key, Key), Edge> = HashMap::new();
        for mesh in &self.meshes {
            for tri in mesh.indices.chunks_exact(3) {
                let p = [tri[0], tri[1], tri[2]].map(|i| mesh.positions[i as usize]);
                let Some(n) = normal(p[0], p[1], p[2]) else {
                    continue;
                };
                for (a, b) in [(p[0], p[1]), (p[1], p[2]), (p[2], p[0])] {
                    let (ka, kb) = (key(a), key(b));
                    let (k, ends) = if ka <= kb {
                        ((ka, kb), [a, b])
                    } else {
                        ((kb, ka), [b, a])
                    };
                    edges
                        .entry(k)
                        .or_insert_with(|| (ends, Vec::new()))
                        .1
                        .push(n);
                }
            }
        }
        let cos_min = min_angle_rad.cos();
        let mut out: Vec<[[f32; 3]; 2]> = edges
            .into_values()
            .filter(|(_, normals)| match normals[..] {
                [a, b] => a.dot(&b) < cos_min,
                _ => true,
            })
            .map(|(ends, _)| ends)
            .collect();
        // A stable order for the same model.
        out.sort_by(|a, b| {
            a.as_flattened()
                .partial_cmp(b.as_flattened())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::procedural;

    #[test]
    fn a_cube_has_twelve_edges_and_a_square_four() {
        let texture = Arc::new(procedural::checker_texture(4, 8));
        let cube = procedural::cube([0.0; 3], 0.05, texture.clone());
        let e = cube.crease_edges(30f32.to_radians());
        // Each face is two triangles: its diagonal is no crease; the 12 cube edges are.
        assert_eq!(e.len(), 12, "{e:?}");
        for [a, b] in &e {
            let d = (Vector3::from(*a) - Vector3::from(*b)).norm();
            assert!((d - 0.1).abs() < 1e-6, "edge of length {d}");
        }
        // A flat square: its four sides are open boundaries, its diagonal no crease.
        assert_eq!(
            procedural::plane(0.2, 0.1, texture).crease_edges(0.1).len(),
            4
        );
    }
}
