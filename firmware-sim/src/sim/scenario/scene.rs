//! What a scenario's scene contains, independent of any renderer: textured rectangles (some in
//! the model, some only in the live images), moving occluders and the lighting over time.
//! The vision host turns this into meshes, textures and frames.

use nalgebra::{UnitQuaternion, Vector2, Vector3};

use super::path::{Signal, sum};
use crate::sim::camera::Pinhole;
use crate::sim::trajectory::Ramp;

/// The look of a surface; the host generates a texture of this kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Surface {
    /// A small tracking target: dense, high-contrast detail at all scales.
    Target,
    /// A wall with `posters` posters (large detailed rectangles) on plaster.
    Wall {
        /// Number of posters.
        posters: u32,
    },
    /// A floor: mottled, medium contrast.
    Floor,
    /// A ceiling: nearly plain.
    Ceiling,
    /// Clutter: furniture, shelves and the like (unmodelled surroundings).
    Clutter,
    /// A person or object crossing the view.
    Occluder,
}

/// A textured rectangle. Corners go top-left, top-right, bottom-right, bottom-left as seen
/// from the side that faces the camera; the texture's top-left corner is at `corners[0]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Quad {
    /// Name (mesh and material name in the model).
    pub name: String,
    /// Corners in the world frame [m].
    pub corners: [Vector3<f64>; 4],
    /// Look of the texture.
    pub surface: Surface,
    /// Seed of the procedural texture (fixed per scenario: the scene is the same for every
    /// run seed).
    pub texture_seed: u64,
    /// Texture resolution [texels per metre].
    pub texels_per_metre: f64,
}

impl Quad {
    /// Width (top edge) and height (left edge) [m].
    pub fn size(&self) -> (f64, f64) {
        (
            (self.corners[1] - self.corners[0]).norm(),
            (self.corners[3] - self.corners[0]).norm(),
        )
    }

    /// World point at texture coordinates `(s, t)` in `[0, 1]²` (bilinear in the corners).
    pub fn point(&self, s: f64, t: f64) -> Vector3<f64> {
        let top = self.corners[0] * (1.0 - s) + self.corners[1] * s;
        let bottom = self.corners[3] * (1.0 - s) + self.corners[2] * s;
        top * (1.0 - t) + bottom * t
    }
}

/// A vertical rectangle at `centre` facing `normal_yaw` (the direction its front faces, as a
/// yaw angle about world z), `width × height` [m].
pub fn vertical_quad(
    name: &str,
    centre: Vector3<f64>,
    normal_yaw: f64,
    (width, height): (f64, f64),
    surface: Surface,
    texture_seed: u64,
    texels_per_metre: f64,
) -> Quad {
    let n = Vector3::new(normal_yaw.cos(), normal_yaw.sin(), 0.0);
    let up = Vector3::z();
    // A viewer in front looks along −n; their right is (−n) × up = up × n.
    let right = up.cross(&n);
    let (hw, hh) = (width / 2.0, height / 2.0);
    Quad {
        name: name.into(),
        corners: [
            centre - right * hw + up * hh,
            centre + right * hw + up * hh,
            centre + right * hw - up * hh,
            centre - right * hw - up * hh,
        ],
        surface,
        texture_seed,
        texels_per_metre,
    }
}

/// A rigid panel that moves with a smooth step from `from` to `to` (its centre) and is
/// rendered into the live images only.
#[derive(Clone, Debug, PartialEq)]
pub struct Occluder {
    /// Shape and look, in the occluder's own frame (centred at the origin).
    pub quad: Quad,
    /// Centre before the crossing [m].
    pub from: Vector3<f64>,
    /// Centre after the crossing [m].
    pub to: Vector3<f64>,
    /// When the crossing starts [s].
    pub start: f64,
    /// How long it takes [s].
    pub duration: f64,
}

impl Occluder {
    /// Pose at `t`: rotation occluder → world (fixed) and the centre's position.
    pub fn pose_at(&self, t: f64) -> (UnitQuaternion<f64>, Vector3<f64>) {
        let r = Ramp {
            start: self.start,
            length: self.duration,
        }
        .eval(t)[0];
        (
            UnitQuaternion::identity(),
            self.from + (self.to - self.from) * r,
        )
    }
}

/// Photometric state of the live camera at one instant.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LightState {
    /// Multiplies the model's texture values.
    pub gain: f64,
    /// Added after the gain [grey levels of 255].
    pub offset: f64,
    /// Relative brightness change from the image centre to the right edge.
    pub gradient_u: f64,
    /// Relative brightness change from the image centre to the bottom edge.
    pub gradient_v: f64,
}

/// How the lighting of the live images differs from the model's textures over time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lighting {
    /// Added to a gain of 1.
    pub gain: Vec<Signal>,
    /// Added to an offset of 0 [grey levels].
    pub offset: Vec<Signal>,
    /// Added to a horizontal gradient of 0.
    pub gradient_u: Vec<Signal>,
    /// Added to a vertical gradient of 0.
    pub gradient_v: Vec<Signal>,
}

impl Lighting {
    /// The state at `t`.
    pub fn at(&self, t: f64) -> LightState {
        LightState {
            gain: 1.0 + sum(&self.gain, t)[0],
            offset: sum(&self.offset, t)[0],
            gradient_u: sum(&self.gradient_u, t)[0],
            gradient_v: sum(&self.gradient_v, t)[0],
        }
    }
}

/// A scenario's scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Surfaces in the CAD model (and in the live images).
    pub modelled: Vec<Quad>,
    /// Surfaces only in the live images (the world is larger than the model).
    pub unmodelled: Vec<Quad>,
    /// Moving occluders (live images only).
    pub occluders: Vec<Occluder>,
    /// Lighting of the live images.
    pub lighting: Lighting,
    /// Near and far clip distances for rendering [m].
    pub clip: (f64, f64),
}

impl Scene {
    /// Share of a grid of points on the modelled surfaces (`n × n` per quad) that a camera
    /// at pose `(c_w, q_cw)` sees inside its image, ignoring occlusion: a cheap geometric
    /// stand-in for "the model is in view".
    pub fn model_points_in_view(
        &self,
        c_w: &Vector3<f64>,
        q_cw: &UnitQuaternion<f64>,
        cam: &Pinhole,
        n: usize,
    ) -> f64 {
        let mut seen = 0usize;
        let mut total = 0usize;
        for q in &self.modelled {
            for i in 0..n {
                for j in 0..n {
                    let s = (i as f64 + 0.5) / n as f64;
                    let t = (j as f64 + 0.5) / n as f64;
                    let p = q_cw * (q.point(s, t) - c_w);
                    total += 1;
                    if p.z > self.clip.0 {
                        let m = Vector2::new(p.x / p.z, p.y / p.z);
                        seen += usize::from(cam.pixel(&m).is_some());
                    }
                }
            }
        }
        if total == 0 {
            0.0
        } else {
            seen as f64 / total as f64
        }
    }
}
