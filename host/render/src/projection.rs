//! The clip-space projection built from the intrinsics, and the depth-buffer encoding.
//!
//! A camera point `(x, y, z)` lands on the pixel the pinhole model predicts:
//! `u = (fx x + s y)/z + cx`, `v = fy y/z + cy`, with integer pixels at pixel centres. wgpu's
//! framebuffer has its origin at the top-left *corner* with y down, so pixel `u` sits at
//! framebuffer `u + 0.5`, i.e. `x_ndc = 2 (u + 0.5)/W − 1` and `y_ndc = 1 − 2 (v + 0.5)/H`.
//!
//! Depth is reversed (`near → 1`, `far → 0`), the most precise use of a `Depth32Float` buffer:
//! `d = A + B/z` with `A = −n/(f−n)`, `B = n f/(f−n)`, inverted by [`depth_to_z`].

use nalgebra::Matrix4;

use camera::Pinhole;

/// Camera frame → clip space for an image of `width × height` pixels.
pub fn projection_matrix(
    k: &Pinhole,
    width: u32,
    height: u32,
    near: f64,
    far: f64,
) -> Matrix4<f64> {
    let (w, h) = (width as f64, height as f64);
    let a = -near / (far - near);
    let b = near * far / (far - near);
    Matrix4::new(
        2.0 * k.fx / w,
        2.0 * k.skew / w,
        2.0 * (k.cx + 0.5) / w - 1.0,
        0.0,
        //
        0.0,
        -2.0 * k.fy / h,
        1.0 - 2.0 * (k.cy + 0.5) / h,
        0.0,
        //
        0.0,
        0.0,
        a,
        b,
        //
        0.0,
        0.0,
        1.0,
        0.0,
    )
}

/// Depth-buffer value → camera-frame `z` in metres (`None` for the cleared background).
pub fn depth_to_z(d: f32, near: f64, far: f64) -> Option<f64> {
    if d <= 0.0 || !d.is_finite() {
        return None;
    }
    Some(near * far / ((far - near) * d as f64 + near))
}

/// Camera-frame `z` → depth-buffer value.
pub fn z_to_depth(z: f64, near: f64, far: f64) -> f64 {
    near * (far - z) / (z * (far - near))
}

/// Standard deviation of `z` caused by the depth buffer's resolution at depth `z`.
///
/// The buffer stores `d` in `f32`; we take one unit in the last place of `f32` at 0.5
/// (2⁻²⁴, which also covers GL's [−1, 1] remapping) as the step and `step/√12` as the
/// quantisation noise, mapped through `|dz/dd| = (f−n) z²/(n f)`.
pub fn depth_sigma(z: f64, near: f64, far: f64) -> f64 {
    let step = 2f64.powi(-24);
    let dz_dd = (far - near) * z * z / (near * far);
    dz_dd * step / 12f64.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, Vector4};

    #[test]
    fn clip_space_matches_pinhole_and_depth_round_trips() {
        let k = Pinhole::new(520.0, 500.0, 170.3, 118.7).with_skew(1.5);
        let (w, h, n, f) = (320, 240, 0.05, 20.0);
        let p = projection_matrix(&k, w, h, n, f);
        for c in [
            Vector3::new(0.1, -0.2, 1.0),
            Vector3::new(-0.3, 0.25, 2.5),
            Vector3::new(0.0, 0.0, 0.4),
        ] {
            let clip = p * Vector4::new(c.x, c.y, c.z, 1.0);
            let ndc = clip.xyz() / clip.w;
            // Back to pixel-centre coordinates.
            let u = (ndc.x + 1.0) / 2.0 * w as f64 - 0.5;
            let v = (1.0 - ndc.y) / 2.0 * h as f64 - 0.5;
            let want = k.to_pixel(nalgebra::Vector2::new(c.x / c.z, c.y / c.z));
            assert!((u - want.x).abs() < 1e-9 && (v - want.y).abs() < 1e-9);
            let z = depth_to_z(ndc.z as f32, n, f).unwrap();
            assert!((z - c.z).abs() < 1e-6 * c.z * c.z, "{z} vs {}", c.z);
            assert!((z_to_depth(c.z, n, f) - ndc.z).abs() < 1e-12);
        }
        assert!((depth_to_z(1.0, n, f).unwrap() - n).abs() < 1e-9);
        assert!((depth_to_z(f32::MIN_POSITIVE, n, f).unwrap() - f).abs() < 1e-3);
        assert!(depth_to_z(0.0, n, f).is_none());
    }
}
