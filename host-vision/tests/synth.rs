//! Synthetic datasets (issue 6): geometry of the written calibration against rendered pixels,
//! the dataset layout, determinism, the realism effects and bad arguments. Needs a wgpu
//! adapter (software Vulkan or GL); without one the tests fail naming the packages.

use std::sync::Arc;

use firmware_sim::sim::imu::ImuNoise;
use firmware_sim::sim::scenario::{Scenario, ScenarioName, Surface, vertical_quad};
use firmware_sim::sim::trajectory::Trajectory;
use host_vision::camera::read_euroc_sensor_yaml;
use host_vision::model::load_obj;
use host_vision::synth::{
    FrameOptions, FrameSynth, SceneModels, SynthError, SynthOptions, TextureOptions,
    cam_sensor_yaml, run,
};
use image::{Rgba, RgbaImage};
use nalgebra::{Matrix4, Vector2, Vector3, Vector4};
use rand::SeedableRng;
use rand::rngs::StdRng;

/// A scenario whose camera rests at `eye` looking at `target`.
fn still(mut sc: Scenario, eye: Vector3<f64>, target: Vector3<f64>) -> Scenario {
    sc.path.centre = eye;
    sc.path.position = Default::default();
    sc.path.attitude = Default::default();
    sc.path.attitude0 = [0.0, 0.0, 0.3];
    sc.path.look_at = Some(target);
    sc.path.lever_arm = Vector3::zeros();
    sc
}

fn quick_textures() -> TextureOptions {
    TextureOptions {
        scale: 0.15,
        max_side: 1024,
        ..TextureOptions::generated()
    }
}

/// Model points (centres of Gaussian blobs on a plane) projected through the calibration
/// written to `cam0/sensor.yaml` and read back (intrinsics, radial-tangential distortion,
/// `T_BS`) land on the blobs' centroids in the rendered, distorted live frame within 0.1 px,
/// over the whole image including its strongly distorted corners.
#[test]
fn written_calibration_projects_model_points_onto_the_rendered_pixels() {
    // Plane x = 1.2 facing −x, 2.8 × 2.1 m, blobs every 0.1 m with σ = 7 mm (≈ 1.6 px).
    let (pw, ph, tpm) = (2.8, 2.1, 1000.0);
    let (tw, th) = ((pw * tpm) as u32, (ph * tpm) as u32);
    let sigma = 0.007 * tpm;
    let spacing = 0.1;
    let mut blobs_uv = Vec::new();
    let (nx, ny) = ((pw / spacing) as i32, (ph / spacing) as i32);
    for i in 1..nx {
        for j in 1..ny {
            blobs_uv.push((i as f64 * spacing, j as f64 * spacing));
        }
    }
    let mut tex = RgbaImage::from_pixel(tw, th, Rgba([0, 0, 0, 255]));
    for &(bu, bv) in &blobs_uv {
        let (cx, cy) = (bu * tpm - 0.5, bv * tpm - 0.5);
        let r = (4.0 * sigma) as i64;
        for y in (cy as i64 - r).max(0)..(cy as i64 + r).min(th as i64) {
            for x in (cx as i64 - r).max(0)..(cx as i64 + r).min(tw as i64) {
                let d2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
                let v = (255.0 * (-d2 / (2.0 * sigma * sigma)).exp()).round() as u8;
                let p = tex.get_pixel_mut(x as u32, y as u32);
                let g = v.max(p.0[0]);
                *p = Rgba([g, g, g, 255]);
            }
        }
    }
    let quad = vertical_quad(
        "markers",
        Vector3::new(1.2, 0.0, 1.0),
        std::f64::consts::PI,
        (pw, ph),
        Surface::Target,
        1,
        tpm,
    );
    let mut sc = still(
        Scenario::new(ScenarioName::DesktopSlow),
        Vector3::new(0.0, 0.03, 1.02),
        Vector3::new(1.2, -0.02, 0.97),
    );
    sc.scene.modelled = vec![quad.clone()];
    sc.scene.unmodelled.clear();
    let mut textures = quick_textures();
    textures.overrides.insert("markers".into(), Arc::new(tex));
    let models = SceneModels::build(&sc.scene, &textures).unwrap();
    let mut synth = FrameSynth::new(&sc, &models, FrameOptions::clean(320, 240))
        .unwrap_or_else(|e| panic!("the synth tests need a wgpu adapter: {e}"));
    let t = 0.0;
    let frame = synth.frame(&sc, t, &mut StdRng::seed_from_u64(1)).unwrap();

    let dir = tempfile::tempdir().unwrap();
    let yaml = dir.path().join("sensor.yaml");
    std::fs::write(&yaml, cam_sensor_yaml(&sc, synth.camera())).unwrap();
    let calib = read_euroc_sensor_yaml(&yaml).unwrap();
    let t_bs: Matrix4<f64> = calib.extrinsics.unwrap();
    let truth = sc.path.eval(t).kinematics;
    let img = &frame.image;
    let (w, h) = img.dimensions();
    let (mut worst, mut count) = (0.0f64, 0);
    for &(bu, bv) in &blobs_uv {
        let m_w = quad.point(bu / pw, bv / ph);
        // World → body (ground truth) → camera (inverse of T_BS from the file).
        let m_s = truth.q_ws.inverse() * (m_w - truth.p_w);
        let m_c = t_bs.try_inverse().unwrap() * Vector4::new(m_s.x, m_s.y, m_s.z, 1.0);
        let Some(px) = calib.camera.project(m_c.xyz()) else {
            continue;
        };
        let r = 5i64;
        if px.x < (r + 2) as f64
            || px.y < (r + 2) as f64
            || px.x > (w as i64 - r - 3) as f64
            || px.y > (h as i64 - r - 3) as f64
        {
            continue;
        }
        let (u0, v0) = (px.x.round() as i64, px.y.round() as i64);
        let (mut s, mut su, mut sv) = (0.0, 0.0, 0.0);
        for v in v0 - r..=v0 + r {
            for u in u0 - r..=u0 + r {
                let g = img.get_pixel(u as u32, v as u32).0[0] as f64;
                s += g;
                su += g * u as f64;
                sv += g * v as f64;
            }
        }
        let centroid = Vector2::new(su / s, sv / s);
        let err = (centroid - px).norm();
        worst = worst.max(err);
        count += 1;
    }
    let undistorted_shift = {
        let corner = Vector2::new(5.0, 5.0);
        (calib.camera.undistort_pixel(corner).unwrap() - corner).norm()
    };
    println!(
        "{count} blobs: worst centroid vs projection {worst:.3} px (the distortion moves the \
         image corner by {undistorted_shift:.1} px)"
    );
    assert!(count > 100, "too few blobs checked: {count}");
    assert!(undistorted_shift > 5.0);
    assert!(worst < 0.1, "worst {worst} px");
}

#[test]
fn a_short_dataset_has_the_euroc_layout_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("desktop");
    let mut o = SynthOptions::new(ScenarioName::DesktopFast, out.clone());
    o.duration = Some(0.5);
    o.seed = 7;
    // An IMU noise override reaches the calibration the tracker reads.
    o.imu_noise = Some(ImuNoise {
        gyro_walk: 3e-5,
        ..ImuNoise::MT9
    });
    o.frames = FrameOptions {
        subframes: 2,
        max_subframes: 3,
        ..FrameOptions::new(200, 150)
    };
    o.textures = quick_textures();
    let mut calls = 0;
    let report = run(&o, &mut |_, _| calls += 1).unwrap();
    println!("{report}");
    assert_eq!(report.frames, 13);
    assert_eq!(calls, 13);
    let mav0 = out.join("mav0");
    let imu = std::fs::read_to_string(mav0.join("imu0/data.csv")).unwrap();
    assert_eq!(imu.lines().count(), 1 + 51);
    let gt = std::fs::read_to_string(mav0.join("state_groundtruth_estimate0/data.csv")).unwrap();
    assert_eq!(gt.lines().nth(1).unwrap().split(',').count(), 23);
    let cams = std::fs::read_to_string(mav0.join("cam0/data.csv")).unwrap();
    let rows: Vec<&str> = cams.lines().skip(1).collect();
    assert_eq!(rows.len(), 13);
    // Camera stamps are every 4th IMU stamp.
    let imu_stamps: Vec<&str> = imu
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    for (i, row) in rows.iter().enumerate() {
        let (stamp, file) = row.split_once(',').unwrap();
        assert_eq!(stamp, imu_stamps[4 * i]);
        let img = image::open(mav0.join("cam0/data").join(file)).unwrap();
        assert_eq!((img.width(), img.height()), (200, 150));
        assert_eq!(img.color(), image::ColorType::L8);
    }
    let calib = read_euroc_sensor_yaml(&mav0.join("cam0/sensor.yaml")).unwrap();
    assert_eq!((calib.camera.width, calib.camera.height), (200, 150));
    assert_eq!(calib.rate_hz, Some(25.0));
    let imu_yaml = std::fs::read_to_string(mav0.join("imu0/sensor.yaml")).unwrap();
    assert!(
        imu_yaml.contains("gyroscope_noise_density: 1e-3")
            && imu_yaml.contains("gyroscope_random_walk: 3e-5"),
        "{imu_yaml}"
    );
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["scenario"], "desktop-fast");
    assert_eq!(manifest["seed"], 7);
    assert_eq!(manifest["camera"]["frames"], 13);
    // The model folder holds the two target faces only, not the desk or the wall.
    let model = load_obj(&out.join("model/scene.obj")).unwrap();
    let names: Vec<&str> = model.meshes.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["target_left", "target_right"]);
    assert!(model.materials.iter().all(|m| m.texture.is_some()));
    // Desk and target visible: model coverage in every frame.
    assert!(report.model_any == 1.0, "{report}");

    // Same seed: same bytes; another seed: other noise.
    let first = rows[5].split_once(',').unwrap().1.to_string();
    let bytes =
        |root: &std::path::Path| std::fs::read(root.join("mav0/cam0/data").join(&first)).unwrap();
    let again = dir.path().join("again");
    run(
        &SynthOptions {
            out: again.clone(),
            ..o.clone()
        },
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(bytes(&out), bytes(&again));
    assert_eq!(
        std::fs::read(mav0.join("imu0/data.csv")).unwrap(),
        std::fs::read(again.join("mav0/imu0/data.csv")).unwrap()
    );
    let other = dir.path().join("other");
    run(
        &SynthOptions {
            out: other.clone(),
            seed: 8,
            ..o.clone()
        },
        &mut |_, _| {},
    )
    .unwrap();
    assert_ne!(bytes(&out), bytes(&other));

    // An existing dataset is not overwritten unless asked.
    let err = run(&o, &mut |_, _| {}).unwrap_err();
    assert!(matches!(err, SynthError::Exists(_)), "{err}");
    run(
        &SynthOptions {
            overwrite: true,
            ..o.clone()
        },
        &mut |_, _| {},
    )
    .unwrap();
}

#[test]
fn bad_arguments_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a_file");
    std::fs::write(&file, "x").unwrap();
    let mut o = SynthOptions::new(ScenarioName::Room, file.clone());
    o.duration = Some(0.2);
    o.textures = quick_textures();
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(
        err.contains("a_file") && err.contains("not a folder"),
        "{err}"
    );
    o.out = file.join("below");
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("a_file"), "{err}");
    o.out = dir.path().join("ok");
    o.duration = Some(-1.0);
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("duration"), "{err}");
    o.duration = Some(0.2);
    o.textures.user_images = vec![dir.path().join("missing.png")];
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("missing.png"), "{err}");
    o.textures.user_images.clear();
    o.frames.supersample = 9;
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("supersample"), "{err}");
    o.frames.supersample = 2;
    o.imu_noise = Some(ImuNoise {
        gyro_walk: f64::NAN,
        ..ImuNoise::MT9
    });
    let err = run(&o, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("IMU noise") && err.contains("NaN"), "{err}");
    // Nothing was written by the failed runs.
    assert!(!dir.path().join("ok").exists());
}

/// Mean absolute horizontal gradient: a measure of sharpness.
fn sharpness(img: &image::GrayImage) -> f64 {
    let (w, h) = img.dimensions();
    let mut s = 0.0;
    for y in 0..h {
        for x in 1..w {
            s += (img.get_pixel(x, y).0[0] as f64 - img.get_pixel(x - 1, y).0[0] as f64).abs();
        }
    }
    s / ((w - 1) * h) as f64
}

fn mean(img: &image::GrayImage) -> f64 {
    img.pixels().map(|p| p.0[0] as f64).sum::<f64>() / (img.width() * img.height()) as f64
}

/// The room: the occluder crosses the view and hides part of the model; the unmodelled wall
/// fills the view during a turn (no model, but texture); motion blur softens a fast frame;
/// dimmed lights darken the image; noise has the configured strength.
#[test]
fn live_frames_show_occluder_unmodelled_wall_blur_lighting_and_noise() {
    let sc = Scenario::new(ScenarioName::Room);
    let models = SceneModels::build(&sc.scene, &quick_textures()).unwrap();
    let clean = FrameOptions::clean(160, 120);
    let mut synth = FrameSynth::new(&sc, &models, clean)
        .unwrap_or_else(|e| panic!("the synth tests need a wgpu adapter: {e}"));
    let mut rng = StdRng::seed_from_u64(3);

    // Occluder mid-crossing (27–30.5 s) vs. the same view a little earlier.
    let occ = synth.frame(&sc, 28.75, &mut rng).unwrap();
    let before = synth.frame(&sc, 26.5, &mut rng).unwrap();
    println!(
        "occluder: coverage {:.2}, model {:.2} (before: model {:.2})",
        occ.occluder_coverage, occ.model_coverage, before.model_coverage
    );
    assert!(occ.occluder_coverage > 0.05 && before.occluder_coverage == 0.0);
    assert!(occ.model_coverage < before.model_coverage - 0.05);

    // During the first turn (8.5–14 s) the camera faces the unmodelled wall x = 5.
    let turn = (0..=55)
        .map(|i| 8.5 + 0.1 * i as f64)
        .map(|t| (t, synth.frame(&sc, t, &mut rng).unwrap()))
        .min_by(|a, b| a.1.model_coverage.total_cmp(&b.1.model_coverage))
        .unwrap();
    println!(
        "turn: least model coverage {:.3} at {:.1} s, image sharpness {:.1}",
        turn.1.model_coverage,
        turn.0,
        sharpness(&turn.1.image)
    );
    assert_eq!(turn.1.model_coverage, 0.0);
    assert!(
        sharpness(&turn.1.image) > 1.0,
        "the unmodelled wall is not rendered"
    );

    // Fast rotational shake (35–38 s): blur over the 8 ms exposure.
    let t_fast = (0..300)
        .map(|i| 35.5 + 0.01 * i as f64)
        .max_by(|a, b| {
            sc.path
                .at(*a)
                .omega_s
                .norm()
                .total_cmp(&sc.path.at(*b).omega_s.norm())
        })
        .unwrap();
    let sharp = synth.frame(&sc, t_fast, &mut rng).unwrap();
    let mut blurred_synth = FrameSynth::new(
        &sc,
        &models,
        FrameOptions {
            subframes: 7,
            ..clean
        },
    )
    .unwrap();
    let blurred = blurred_synth.frame(&sc, t_fast, &mut rng).unwrap();
    let (s0, s1) = (sharpness(&sharp.image), sharpness(&blurred.image));
    println!(
        "blur at {t_fast:.2} s ({:.1} rad/s): sharpness {s0:.2} → {s1:.2}",
        sc.path.at(t_fast).omega_s.norm()
    );
    assert!(s1 < 0.7 * s0);

    lighting_and_noise(&sc, &models, clean, &mut synth, &mut rng);
}

/// The room's lights dimmed at 11–12 s darken a lit frame as they should, and two noisy
/// renderings of one instant differ by the configured noise (the end of
/// `live_frames_show_occluder_unmodelled_wall_blur_lighting_and_noise`).
fn lighting_and_noise(
    sc: &Scenario,
    models: &SceneModels,
    clean: FrameOptions,
    synth: &mut FrameSynth,
    rng: &mut StdRng,
) {
    // Lights dimmed at 11–12 s by 45 %: with lighting on, the mean drops accordingly.
    let mut lit = FrameSynth::new(
        sc,
        models,
        FrameOptions {
            lighting: true,
            ..clean
        },
    )
    .unwrap();
    let (a, b) = (
        lit.frame(sc, 5.0, rng).unwrap(),
        synth.frame(sc, 5.0, rng).unwrap(),
    );
    let (c, d) = (
        lit.frame(sc, 18.0, rng).unwrap(),
        synth.frame(sc, 18.0, rng).unwrap(),
    );
    let (r_bright, r_dim) = (
        mean(&a.image) / mean(&b.image),
        mean(&c.image) / mean(&d.image),
    );
    println!(
        "lighting: live/model mean {r_bright:.2} at 5 s (gain {:.2}), {r_dim:.2} at 18 s (gain {:.2})",
        a.light.gain, c.light.gain
    );
    assert!(c.light.gain < 0.65 && r_dim < 0.75 * r_bright);

    // Noise: the difference of two noisy renderings of the same instant has std √2 σ.
    let mut noisy = FrameSynth::new(
        sc,
        models,
        FrameOptions {
            read_noise: 3.0,
            shot_noise: 0.0,
            ..clean
        },
    )
    .unwrap();
    let (n1, n2) = (
        noisy.frame(sc, 5.0, rng).unwrap(),
        noisy.frame(sc, 5.0, rng).unwrap(),
    );
    let diffs: Vec<f64> = n1
        .image
        .pixels()
        .zip(n2.image.pixels())
        .map(|(p, q)| p.0[0] as f64 - q.0[0] as f64)
        .collect();
    let sd = (diffs.iter().map(|d| d * d).sum::<f64>() / diffs.len() as f64).sqrt() / 2f64.sqrt();
    println!("noise: measured σ {sd:.2} grey levels (configured 3.0)");
    assert!((sd / 3.0 - 1.0).abs() < 0.1);
}
