//! Issue 37, bad input: an object of one grey on a background of the same grey gives the
//! contour modality few or no lines, and the frame is judged lost, never tracked at a pose
//! nothing supports. The same object against a contrasting background is measured and
//! judged tracked.

use std::sync::Arc;

use camera::{CameraPose, Pinhole, pinhole_camera};
use image::{GrayImage, Luma};
use nalgebra::Vector3;
use protocol::PosePrediction;
use render::{RenderView, Renderer};
use vision::{FrameImage, FrameJob, Modality, TrackedRule, Vision, VisionOptions};

fn job(index: usize, image: GrayImage, pose: &CameraPose) -> FrameJob {
    let q = pose.q_cw.into_inner();
    FrameJob {
        index,
        stamp: index as u64,
        image: FrameImage::Decoded(image),
        prediction: PosePrediction {
            frame_id: index as u32,
            t_us: 0,
            c_w: [pose.c_w.x as f32, pose.c_w.y as f32, pose.c_w.z as f32],
            q_cw: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
            // 3 mm and 3 mrad: lines of a few pixels.
            cov: {
                let mut c = [0.0f32; 21];
                for i in 0..6 {
                    c[protocol::sym_index(6, i, i)] = 1e-5;
                }
                c
            },
        },
        keep_image: false,
        omega_c: None,
    }
}

#[test]
fn a_grey_object_on_its_own_grey_is_lost_and_on_black_is_tracked() {
    let mut model =
        model::procedural::cube([0.0, 0.0, 0.0], 0.05, Arc::new(image::RgbaImage::new(1, 1)));
    model.materials[0].texture = None;
    model.materials[0].base_colour = [0.5, 0.5, 0.5, 1.0];
    assert!(!vision::is_textured(&model));
    let camera = pinhole_camera(320, 240, Pinhole::new(300.0, 300.0, 160.0, 120.0)).unwrap();
    let pose = CameraPose::look_at(
        Vector3::new(0.25, -0.3, 0.2),
        Vector3::zeros(),
        Vector3::z(),
    )
    .unwrap();
    // The live image: the cube rendered on black.
    let mut renderer = Renderer::new(320, 240).unwrap();
    renderer.set_model(&model).unwrap();
    let view = RenderView {
        pinhole: camera.pinhole,
        pose,
        near: 0.05,
        far: 10.0,
    };
    let mut frame = render::Frame::empty(view);
    renderer.render_into(&view, &mut frame).unwrap();
    let on_black = frame.gray.clone();
    let grey = on_black.get_pixel(160, 120).0[0];
    assert!(grey > 60, "the cube is in the middle of the image: {grey}");

    let options = VisionOptions {
        modality: Modality::Contour,
        ..VisionOptions::default()
    };
    let mut v = Vision::new(camera, &model, options).unwrap();
    let rule = TrackedRule::default();
    let applied = |n: usize| vec![true; n];

    let r = v.process(job(0, on_black, &pose)).unwrap();
    println!("on black: {:?}", r.contour_tally);
    assert!(
        r.contours.len() >= rule.min_contours,
        "{:?}",
        r.contour_tally
    );
    let a = v.assess(&pose, &applied(r.contours.len())).unwrap();
    println!("on black: {a:?}");
    assert!(rule.holds(&a), "{a:?}");

    // The same object on a background of its own grey: nothing to find.
    let same = GrayImage::from_pixel(320, 240, Luma([grey]));
    let r = v.process(job(1, same, &pose)).unwrap();
    println!("on its own grey: {:?}", r.contour_tally);
    assert!(
        r.contours.len() < rule.min_contours,
        "{:?}",
        r.contour_tally
    );
    let a = v.assess(&pose, &applied(r.contours.len())).unwrap();
    println!("on its own grey: {a:?}");
    assert!(!rule.holds(&a), "judged tracked with nothing to see: {a:?}");
}
