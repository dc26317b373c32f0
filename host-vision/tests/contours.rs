//! The contour modality on synthetic frames of an object without texture (issue 37): the
//! model rendered at the true pose, its contour searched in the live frame, is found where it
//! is: no bias along the normals, an error within the variance each line states.

use std::path::PathBuf;

use firmware_sim::sim::scenario::ScenarioName;
use frames::euroc::Dataset;
use host_vision::synth::{SynthOptions, TextureOptions, UNTEXTURED_COLOUR};
use nalgebra::Vector2;
use protocol::PosePrediction;
use vision::{FrameImage, FrameJob, Vision, VisionOptions};

fn untextured_desktop() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("contours-desktop-fast");
    let options = SynthOptions {
        duration: Some(3.0),
        overwrite: true,
        textures: TextureOptions {
            untextured: Some(UNTEXTURED_COLOUR),
            ..TextureOptions::generated()
        },
        ..SynthOptions::new(ScenarioName::DesktopFast, dir.clone())
    };
    host_vision::synth::run(&options, &mut |_, _| {}).expect("synth");
    dir
}

/// Every third frame of 3 s of desktop-fast, predicted at its true pose (with no uncertainty,
/// so the lines are the shortest): the contours found lie where the model projects, without
/// bias along the normals and within the σ the lines state.
#[test]
fn contours_at_the_true_pose_are_found_without_bias() {
    let dir = untextured_desktop();
    let d = Dataset::open(&dir).unwrap();
    let model = host_vision::model::load(&dir.join("model/scene.obj")).unwrap();
    assert!(!vision::is_textured(&model));
    let camera = d.camera.camera;
    let options = VisionOptions {
        modality: vision::Modality::Contour,
        ..VisionOptions::default()
    };
    let mut v = Vision::new(camera, &model, options).unwrap();
    let fx = v.ideal_camera().pinhole.fx;
    let (mut all_sq, mut all_sum, mut all_n, mut sigma_sum) = (0.0, 0.0, 0usize, 0.0);
    for (index, f) in d.frames.iter().enumerate().step_by(3) {
        let (s_w, q_ws) = d.groundtruth_at(f.stamp).unwrap();
        let (c_w, q_cw) = d.hand_eye.camera_pose(&s_w, &q_ws);
        let q = q_cw.into_inner();
        let job = FrameJob {
            index,
            stamp: f.stamp,
            image: FrameImage::File(f.path.clone()),
            prediction: PosePrediction {
                frame_id: index as u32,
                t_us: 0,
                c_w: [c_w.x as f32, c_w.y as f32, c_w.z as f32],
                q_cw: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
                cov: [0.0; 21],
            },
            keep_image: false,
            omega_c: None,
        };
        let r = v.process(job).unwrap();
        let (mut sum, mut sq) = (0.0, 0.0);
        let mut abs: Vec<f64> = Vec::new();
        for c in &r.contours {
            // The filter's residual at the true pose (eq. 10c), in px: minus the offset.
            let m_w = nalgebra::Vector3::new(c.m_w[0], c.m_w[1], c.m_w[2]).cast::<f64>();
            let p_c: nalgebra::Vector3<f64> = q_cw * (m_w - c_w);
            let u = Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z);
            let h = (Vector2::new(c.n[0] as f64, c.n[1] as f64).dot(&u) - c.d as f64) * fx;
            sum += h;
            sq += h * h;
            abs.push(h.abs());

            sigma_sum += f64::from(c.var_d).sqrt() * fx;
        }
        let n = r.contours.len();
        abs.sort_by(f64::total_cmp);
        let pct = |p: f64| {
            abs.get(((abs.len() as f64 - 1.0) * p) as usize)
                .copied()
                .unwrap_or(0.0)
        };
        println!(
            "frame {index}: |h| p50 {:.2} p80 {:.2} p95 {:.2} max {:.2}",
            pct(0.5),
            pct(0.8),
            pct(0.95),
            pct(1.0)
        );
        println!(
            "frame {index}: {n} of {} lines, mean {:+.2} px, rms {:.2} px, {:?}",
            r.contour_tally.sampled,
            sum / n.max(1) as f64,
            (sq / n.max(1) as f64).sqrt(),
            r.contour_tally
        );
        all_sum += sum;
        all_sq += sq;
        all_n += n;
    }
    let mean = all_sum / all_n as f64;
    let rms = (all_sq / all_n as f64).sqrt();
    let sigma = sigma_sum / all_n as f64;
    println!("all: {all_n} contours, mean {mean:+.3} px, rms {rms:.3} px, stated σ {sigma:.2} px");
    // Measured: 1058 contours, mean +0.27 px, rms 0.84 px, stated σ 1.59 px (of 60 lines per
    // frame; the rest refused by name, mostly where the contour lies beyond the short lines a
    // confident prediction asks for).
    assert!(all_n > 600, "{all_n} contours");
    assert!(mean.abs() < 0.4, "biased: {mean} px");
    assert!(rms < sigma, "rms {rms} px against the stated σ {sigma} px");
}
