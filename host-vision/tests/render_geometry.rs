//! Rendered geometry against the camera model, on whichever backend `WGPU_BACKEND` selects
//! (CI runs this file on Vulkan/lavapipe and on GL/llvmpipe). Without any adapter these tests
//! fail with the packages to install: they never skip silently.

use std::sync::Arc;

use host_vision::camera::{CameraPose, Pinhole};
use host_vision::model::{Model, procedural};
use host_vision::render::{
    DepthReadback, Frame, RenderError, RenderView, Renderer, RendererOptions,
};
use nalgebra::{Matrix3, SymmetricEigen, Vector2, Vector3};

const W: u32 = 320;
const H: u32 = 240;

/// Intrinsics with an off-centre principal point and skew, to exercise all of `K`.
fn pinhole() -> Pinhole {
    Pinhole::new(300.0, 295.0, 161.3, 118.6).with_skew(0.8)
}

fn renderer(options: RendererOptions) -> Renderer {
    let r = Renderer::with_options(options)
        .unwrap_or_else(|e| panic!("the GPU tests need a wgpu adapter: {e}"));
    eprintln!(
        "adapter: {} — depth readback {:?}",
        r.adapter_summary(),
        r.depth_readback()
    );
    r
}

fn default_renderer() -> Renderer {
    renderer(RendererOptions {
        width: W,
        height: H,
        force_depth_resolve: false,
        whole_image: false,
    })
}

fn view(eye: [f64; 3], target: [f64; 3], up: [f64; 3]) -> RenderView {
    RenderView {
        pinhole: pinhole(),
        pose: CameraPose::look_at(eye.into(), target.into(), up.into()).unwrap(),
        near: 0.05,
        far: 20.0,
    }
}

fn render(r: &mut Renderer, model: &Model, v: &RenderView) -> Frame {
    r.set_model(model).unwrap();
    r.render(v).unwrap()
}

/// World ray through pixel `(u, v)`: camera centre and direction with camera-frame z = 1.
fn ray(v: &RenderView, u: u32, row: u32) -> (Vector3<f64>, Vector3<f64>) {
    let n = v.pinhole.to_normalised(Vector2::new(u as f64, row as f64));
    let d = v.pose.q_cw.inverse() * Vector3::new(n.x, n.y, 1.0);
    (v.pose.c_w, d)
}

#[test]
fn plane_depth_mask_and_texture_match_the_analytic_plane() {
    let mut r = default_renderer();
    let model = procedural::plane(2.0, 2.0, Arc::new(procedural::checker_texture(8, 32)));
    let views = [
        view([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        view([0.3, -0.8, 0.6], [0.05, 0.1, 0.0], [0.0, 0.0, 1.0]),
        view([-0.9, 0.5, 0.35], [0.2, -0.1, 0.0], [0.0, 0.0, 1.0]),
    ];
    let (mut max_depth_err, mut max_plane_err) = (0.0f64, 0.0f64);
    let mut checked_colours = 0;
    for v in &views {
        let f = render(&mut r, &model, v);
        for row in 0..H {
            for u in 0..W {
                let (c, d) = ray(v, u, row);
                // Analytic hit with z_w = 0; t is the camera-frame depth since d has z_c = 1.
                let t = -c.z / d.z;
                let hit = c + d * t;
                let inside = t > 0.0 && hit.x.abs().max(hit.y.abs()) < 1.0;
                let margin = 1.0 - hit.x.abs().max(hit.y.abs());
                let rendered = f.backproject(u, row);
                match rendered {
                    None => assert!(
                        !(inside && margin > 0.01),
                        "pixel ({u}, {row}) should see the plane"
                    ),
                    Some(b) => {
                        assert!(inside || margin > -0.01, "pixel ({u}, {row}) off the plane");
                        max_depth_err = max_depth_err.max((b.p_c.z - t).abs() / t);
                        max_plane_err = max_plane_err.max(b.p_w.z.abs());
                        // Texture: compare well inside checker cells, where the pixel
                        // footprint is small (mip blending blurs grazing or far views). A
                        // flipped or shifted mapping would be off by a whole cell.
                        let (s, q) = ((hit.x + 1.0) / 2.0 * 8.0, (1.0 - hit.y) / 2.0 * 8.0);
                        let edge = (s - s.round()).abs().min((q - q.round()).abs());
                        let range = t * d.norm();
                        let facing = d.z.abs() / d.norm() > 0.5;
                        if inside && edge > 0.25 && facing && range < 1.5 {
                            let want = procedural::checker_colour(8, s as u32, q as u32);
                            let got = f.rgba.get_pixel(u, row).0;
                            for k in 0..3 {
                                assert!(
                                    (got[k] as i32 - want[k] as i32).abs() <= 8,
                                    "colour at ({u}, {row}): {got:?} vs {want:?}"
                                );
                            }
                            checked_colours += 1;
                        }
                    }
                }
            }
        }
    }
    println!(
        "plane: max depth error {:.4} mm per m, max distance to plane {:.4} mm, {checked_colours} texels checked",
        max_depth_err * 1e3,
        max_plane_err * 1e3
    );
    assert!(max_depth_err < 1e-3, "depth error {max_depth_err} m per m");
    assert!(max_plane_err < 1e-3);
    assert!(checked_colours > 10_000);
}

/// Least-squares plane `nᵀx = d` through points.
fn fit_plane(points: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let cov = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>();
    let eig = SymmetricEigen::new(cov);
    let i = eig.eigenvalues.imin();
    let n: Vector3<f64> = eig.eigenvectors.column(i).into();
    (n, n.dot(&mean))
}

/// Renders a cube; checks every rendered point lies on the cube and measures where its
/// nearest corner was rendered: each visible face's rendered depth gives a plane (in the
/// frame the renderer's projection implies), the three planes meet at the rendered corner,
/// and `K` maps it to the corner's rendered pixel.
fn cube_check(eye: [f64; 3]) -> (f64, f64) {
    let h = 0.25;
    let mut r = default_renderer();
    let model = procedural::cube(
        [0.0; 3],
        h as f32,
        Arc::new(procedural::checker_texture(4, 16)),
    );
    let v = view(eye, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    let f = render(&mut r, &model, &v);

    let mut max_surface_err = 0.0f64;
    let mut faces: [Vec<Vector3<f64>>; 3] = Default::default();
    let sign = Vector3::from(eye).map(f64::signum);
    for row in 0..H {
        for u in 0..W {
            let Some(b) = f.backproject(u, row) else {
                continue;
            };
            let p = b.p_w;
            let inf = p.abs().max();
            max_surface_err = max_surface_err.max((inf - h).abs());
            // Face samples away from the edges, in the camera frame.
            for axis in 0..3 {
                let on_face = (p[axis] - sign[axis] * h).abs() < 2e-3;
                let inner = (0..3).filter(|&a| a != axis).all(|a| p[a].abs() < h - 0.01);
                if on_face && inner {
                    faces[axis].push(b.p_c);
                }
            }
        }
    }
    for (axis, pts) in faces.iter().enumerate() {
        assert!(
            pts.len() > 300,
            "face {axis} has only {} samples",
            pts.len()
        );
    }
    let planes: Vec<_> = faces.iter().map(|p| fit_plane(p)).collect();
    let a = Matrix3::from_rows(&[
        planes[0].0.transpose(),
        planes[1].0.transpose(),
        planes[2].0.transpose(),
    ]);
    let corner_c = a.try_inverse().unwrap() * Vector3::new(planes[0].1, planes[1].1, planes[2].1);
    let rendered_px = v.pinhole.to_pixel(corner_c.xy() / corner_c.z);
    let corner_w = sign * h;
    let p_c = v.pose.world_to_camera(&corner_w);
    let predicted_px = v.pinhole.to_pixel(p_c.xy() / p_c.z);
    let vertex_err = (rendered_px - predicted_px).norm();
    println!(
        "cube from {eye:?}: corner predicted {predicted_px:?}, rendered {rendered_px:?}: \
         {vertex_err:.1e} px; max distance to surface {:.4} mm at {:.2} m",
        max_surface_err * 1e3,
        p_c.z
    );
    (vertex_err, max_surface_err)
}

#[test]
fn cube_surface_and_vertex_reprojection() {
    for eye in [[0.75, -0.6, 0.7], [-0.5, -0.8, 0.45], [0.6, 0.9, -0.5]] {
        let (vertex_err, surface_err) = cube_check(eye);
        assert!(vertex_err < 0.1, "vertex reprojection {vertex_err} px");
        assert!(surface_err < 1e-3, "surface error {surface_err} m");
    }
}

#[test]
fn depth_resolve_pass_matches_direct_copy() {
    let model = procedural::test_scene();
    let v = view([1.2, -1.0, 0.9], [0.0, 0.0, 0.2], [0.0, 0.0, 1.0]);
    let mut resolved = renderer(RendererOptions {
        width: W,
        height: H,
        force_depth_resolve: true,
        whole_image: false,
    });
    assert_eq!(resolved.depth_readback(), DepthReadback::ShaderResolve);
    let a = render(&mut resolved, &model, &v);
    let mut plain = default_renderer();
    let b = render(&mut plain, &model, &v);
    assert_eq!(a.depth, b.depth, "resolved and copied depth differ");
    assert_eq!(a.rgba, b.rgba);
    assert_eq!(a.mask, b.mask);
    let valid = a.mask.pixels().filter(|p| p.0[0] == 255).count();
    assert!(valid > (W * H / 2) as usize, "only {valid} model pixels");
}

#[test]
fn renderer_is_reused_across_frames_and_rejects_bad_input() {
    let mut r = default_renderer();
    let v = view([1.2, -1.0, 0.9], [0.0, 0.0, 0.2], [0.0, 0.0, 1.0]);
    assert!(matches!(r.render(&v), Err(RenderError::EmptyModel)));
    r.set_model(&procedural::test_scene()).unwrap();
    assert_eq!(r.triangle_count(), 14);
    let first = r.render(&v).unwrap();
    let other = view([-1.0, -1.0, 1.5], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    let second = r.render(&other).unwrap();
    assert_ne!(first.gray, second.gray);
    let again = r.render(&v).unwrap();
    assert_eq!(first.gray, again.gray);
    assert_eq!(first.depth, again.depth);

    let bad = RenderView {
        near: 1.0,
        far: 0.5,
        ..v
    };
    assert!(matches!(r.render(&bad), Err(RenderError::BadView(_))));
    let bad_k = RenderView {
        pinhole: Pinhole::new(0.0, 1.0, 0.0, 0.0),
        ..v
    };
    assert!(matches!(r.render(&bad_k), Err(RenderError::BadView(_))));
    let mut broken = procedural::test_scene();
    broken.meshes[0].indices[0] = 99;
    assert!(matches!(r.set_model(&broken), Err(RenderError::Model(_))));
    assert!(
        r.render(&v).is_ok(),
        "a rejected model keeps the previous one"
    );
    assert!(matches!(
        Renderer::new(0, 10),
        Err(RenderError::BadSize { .. })
    ));
    assert!(matches!(
        Renderer::new(1 << 20, 10),
        Err(RenderError::BadSize { .. })
    ));
}

/// The focused read-back (only the rectangle the model can cover, `render::region`) gives the
/// whole-image read-back's frame to the bit, in one frame reused across views as a tracker
/// reuses it: a small cube near and far, partly and wholly outside the image, with a corner
/// behind the near plane, and the large test scene; with the depth copied and resolved.
#[test]
fn focused_read_back_equals_the_whole_image() {
    let texture = std::sync::Arc::new(procedural::checker_texture(8, 8));
    let cube = procedural::cube([0.0, 0.0, 0.0], 0.05, texture);
    let views = [
        view([0.3, -0.25, 0.2], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        view([1.0, -0.8, 0.7], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        view([0.3, -0.25, 0.2], [0.25, 0.1, 0.0], [0.0, 0.0, 1.0]),
        view([0.3, -0.25, 0.2], [0.0, -0.6, 0.5], [0.0, 0.0, 1.0]),
        view([0.06, -0.06, 0.05], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        view([0.2, 0.15, -0.1], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
    ];
    for force_depth_resolve in [false, true] {
        let options = |whole_image| RendererOptions {
            width: W,
            height: H,
            force_depth_resolve,
            whole_image,
        };
        let (mut whole, mut focused) = (renderer(options(true)), renderer(options(false)));
        for (model, views) in [
            (&cube, &views[..]),
            (&procedural::test_scene(), &views[1..2]),
        ] {
            whole.set_model(model).unwrap();
            focused.set_model(model).unwrap();
            let mut full_frame = Frame::empty(views[0]);
            let mut tracker_frame = Frame::empty_for_tracker(views[0]);
            let mut model_pixels = 0;
            for v in views.iter().chain(views.iter().rev()) {
                let want = whole.render(v).unwrap();
                focused.render_into(v, &mut full_frame).unwrap();
                focused.render_into(v, &mut tracker_frame).unwrap();
                assert_eq!(full_frame.rgba, want.rgba, "{v:?}");
                assert_eq!(full_frame.mask, want.mask, "{v:?}");
                assert_eq!(tracker_frame.gray, want.gray, "{v:?}");
                assert_eq!(tracker_frame.mask, want.mask, "{v:?}");
                let bits = |f: &Frame| f.depth.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&full_frame), bits(&want), "{v:?}");
                for (u, row, _) in want.mask.enumerate_pixels() {
                    assert_eq!(tracker_frame.depth_at(u, row), want.depth_at(u, row));
                }
                model_pixels += want.mask.iter().filter(|&&m| m > 0).count();
                assert!(
                    full_frame.region().pixels() <= (W * H) as usize,
                    "{:?}",
                    full_frame.region()
                );
            }
            assert!(
                model_pixels > 1000,
                "the views show the model: {model_pixels} px"
            );
        }
    }
}
