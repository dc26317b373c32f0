//! Lit, shaded live frames (issue 56): a directional light and an ambient one, Lambert's
//! diffuse term and a Blinn-Phong highlight, on the rendering's surfaces. The renderer draws
//! the model's values unlit; the normals come from its depth, so every surface (planar faces,
//! a scanned shape) is shaded by the same light without a second pipeline. The light turns
//! about the vertical and dims during the run.

use camera::Pinhole;
use nalgebra::{UnitQuaternion, Vector3};

/// The scene's light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shading {
    /// Ambient share of a surface's value (lit from everywhere).
    pub ambient: f64,
    /// Diffuse share at full light, facing it.
    pub diffuse: f64,
    /// Highlight at its peak [grey levels].
    pub specular: f64,
    /// Blinn-Phong exponent: the larger, the smaller the highlight.
    pub shininess: f64,
    /// The light's elevation above the horizontal plane [rad].
    pub elevation: f64,
    /// Its azimuth at t = 0 [rad], and how fast it turns about the vertical [rad/s].
    pub azimuth: (f64, f64),
    /// How much the directional light dims and comes back, as a share of it, and the period
    /// [s] of that cycle (a cloud, a lamp dimmed by hand).
    pub dimming: (f64, f64),
}

impl Default for Shading {
    /// A lamp 50° up, turning 10° a second, its diffuse light dimming by 40 % every 6 s: faces
    /// towards it bright, those away from it dark, a highlight on curved surfaces.
    fn default() -> Self {
        Shading {
            ambient: 0.35,
            diffuse: 0.85,
            specular: 60.0,
            shininess: 24.0,
            elevation: 50f64.to_radians(),
            azimuth: (30f64.to_radians(), 10f64.to_radians()),
            dimming: (0.4, 6.0),
        }
    }
}

impl Shading {
    /// The unit direction towards the light in the world (z up) at `t` [s], and its diffuse
    /// strength then.
    pub fn light_at(&self, t: f64) -> (Vector3<f64>, f64) {
        let az = self.azimuth.0 + self.azimuth.1 * t;
        let (se, ce) = self.elevation.sin_cos();
        let dir = Vector3::new(ce * az.cos(), ce * az.sin(), se);
        let (amount, period) = self.dimming;
        let phase = if period > 0.0 {
            0.5 - 0.5 * (std::f64::consts::TAU * t / period).cos()
        } else {
            0.0
        };
        (dir, self.diffuse * (1.0 - amount * phase))
    }

    /// Shades `gray` (row-major, `width` wide) in place where `depth` [m, along the optical
    /// axis; 0 where nothing is] has a surface, seen by `pinhole` from a camera turned by
    /// `q_cw`, lit at `t` [s].
    pub fn apply(
        &self,
        gray: &mut [f32],
        depth: &[f32],
        width: usize,
        pinhole: &Pinhole,
        q_cw: &UnitQuaternion<f64>,
        t: f64,
    ) {
        let (light_w, diffuse) = self.light_at(t);
        let l = q_cw * light_w;
        let height = depth.len() / width.max(1);
        let point = |x: usize, y: usize| -> Option<Vector3<f64>> {
            let z = f64::from(depth[y * width + x]);
            (z > 0.0).then(|| {
                Vector3::new(
                    (x as f64 - pinhole.cx) / pinhole.fx * z,
                    (y as f64 - pinhole.cy) / pinhole.fy * z,
                    z,
                )
            })
        };
        for y in 0..height {
            for x in 0..width {
                let Some(p) = point(x, y) else { continue };
                let Some(n) = normal(&point, p, x, y, width, height) else {
                    continue;
                };
                let view = -p.normalize();
                let n = if n.dot(&view) < 0.0 { -n } else { n };
                let lambert = n.dot(&l).max(0.0);
                let highlight = if lambert > 0.0 {
                    let h = (l + view).normalize();
                    self.specular * n.dot(&h).max(0.0).powf(self.shininess)
                } else {
                    0.0
                };
                let g = &mut gray[y * width + x];
                *g = (f64::from(*g) * (self.ambient + diffuse * lambert) + highlight) as f32;
            }
        }
    }
}

/// The surface normal at `p` (pixel `x`, `y`) from its neighbours' points, each axis taking the
/// side whose depth differs less (so that a depth edge does not bend it); `None` at a pixel
/// without neighbours on the surface.
fn normal(
    point: &dyn Fn(usize, usize) -> Option<Vector3<f64>>,
    p: Vector3<f64>,
    x: usize,
    y: usize,
    width: usize,
    height: usize,
) -> Option<Vector3<f64>> {
    let nearer = |a: Option<Vector3<f64>>, b: Option<Vector3<f64>>| -> Option<Vector3<f64>> {
        match (a.map(|a| a - p), b.map(|b| p - b)) {
            (Some(da), Some(db)) => Some(if da.z.abs() <= db.z.abs() { da } else { db }),
            (da, db) => da.or(db),
        }
    };
    let dx = nearer(
        (x + 1 < width).then(|| point(x + 1, y)).flatten(),
        x.checked_sub(1).and_then(|x| point(x, y)),
    )?;
    let dy = nearer(
        (y + 1 < height).then(|| point(x, y + 1)).flatten(),
        y.checked_sub(1).and_then(|y| point(x, y)),
    )?;
    let n = dx.cross(&dy);
    (n.norm() > 0.0).then(|| n.normalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane at depth `z` facing the camera (a wall seen head-on), 9×9 pixels.
    fn wall(z: f32) -> Vec<f32> {
        vec![z; 81]
    }

    fn pinhole() -> Pinhole {
        Pinhole::new(100.0, 100.0, 4.0, 4.0)
    }

    #[test]
    fn a_face_towards_the_light_is_brighter_than_one_away_from_it() {
        let s = Shading {
            specular: 0.0,
            dimming: (0.0, 0.0),
            ..Shading::default()
        };
        let (light, diffuse) = s.light_at(0.0);
        // Camera looking along the light (towards the scene, the light behind it): the wall
        // faces the light. q_cw maps the world into the camera; choose it so that the
        // camera's +z (its view) is the world's −light.
        let towards = UnitQuaternion::rotation_between(&(-light), &Vector3::z()).unwrap();
        let away = UnitQuaternion::rotation_between(&light, &Vector3::z()).unwrap();
        let lit = |q: &UnitQuaternion<f64>| {
            let mut g = vec![100.0f32; 81];
            s.apply(&mut g, &wall(1.0), 9, &pinhole(), q, 0.0);
            g[40]
        };
        let facing = lit(&towards);
        assert!(
            (f64::from(facing) - 100.0 * (s.ambient + diffuse)).abs() < 1.0,
            "{facing}"
        );
        // Seen from the far side, the same wall faces away: ambient light only.
        assert!((f64::from(lit(&away)) - 100.0 * s.ambient).abs() < 1.0);
    }

    #[test]
    fn empty_pixels_stay_as_they_are_and_the_light_dims_and_turns() {
        let s = Shading::default();
        let mut g = vec![7.0f32; 81];
        s.apply(
            &mut g,
            &[0.0; 81],
            9,
            &pinhole(),
            &UnitQuaternion::identity(),
            0.0,
        );
        assert!(g.iter().all(|&v| v == 7.0));
        let (d0, k0) = s.light_at(0.0);
        let (d3, k3) = s.light_at(3.0);
        assert!((d0.norm() - 1.0).abs() < 1e-12 && (d3.norm() - 1.0).abs() < 1e-12);
        assert!((d0.angle(&d3) - 3.0 * s.azimuth.1 * s.elevation.cos()).abs() < 0.02);
        assert!((k3 - s.diffuse * (1.0 - s.dimming.0)).abs() < 1e-12 && k0 == s.diffuse);
    }

    #[test]
    fn a_depth_edge_does_not_bend_the_normal_of_the_nearer_surface() {
        // Left half at 1 m, right half at 2 m: the pixel left of the edge keeps the wall's
        // normal, so the head-on wall reads as the rest of it.
        let mut depth = wall(1.0);
        for y in 0..9 {
            for x in 5..9 {
                depth[y * 9 + x] = 2.0;
            }
        }
        let s = Shading {
            specular: 0.0,
            dimming: (0.0, 0.0),
            ..Shading::default()
        };
        let mut g = vec![100.0f32; 81];
        s.apply(
            &mut g,
            &depth,
            9,
            &pinhole(),
            &UnitQuaternion::identity(),
            0.0,
        );
        assert!(
            (g[4 * 9 + 4] - g[4 * 9 + 2]).abs() < 1e-3,
            "{} {}",
            g[4 * 9 + 4],
            g[4 * 9 + 2]
        );
    }
}
