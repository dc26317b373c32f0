//! Feature map behaviour (add on demand, retire, spread selection, occlusion) and
//! correspondence building, on synthetic renderings.

use host_vision::camera::{Camera, CameraPose, Distortion, Gray32FImage, Pinhole};
use host_vision::features::correspondence::{self, CorrespondenceError};
use host_vision::features::klt::KltFailure;
use host_vision::features::map::{FeatureMap, MapConfig, Outcome, Predicted};
use host_vision::render::{Frame, RenderView};
use image::{GrayImage, Luma, RgbaImage};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

const W: u32 = 320;
const H: u32 = 240;

/// A camera 2 m above the plane z = 0, looking straight down.
fn view() -> RenderView {
    RenderView {
        pinhole: Pinhole::new(300.0, 300.0, 159.5, 119.5),
        pose: CameraPose::look_at(Vector3::new(0.0, 0.0, 2.0), Vector3::zeros(), Vector3::y())
            .unwrap(),
        near: 0.1,
        far: 10.0,
    }
}

/// A rendering of a textured plane (bright squares on dark, many FAST corners) that covers
/// the image left of `model_right` (background to its right).
fn frame(model_right: u32) -> Frame {
    let gray = GrayImage::from_fn(W, H, |x, y| {
        if x >= model_right {
            return Luma([0]);
        }
        let on = (x % 12) >= 4 && (x % 12) < 8 && (y % 12) >= 4 && (y % 12) < 8;
        // A little deterministic texture breaks the score ties strict suppression would drop.
        let t = ((x * 7 + y * 13) % 11) as u8;
        Luma([if on { 200 + t } else { 60 + t }])
    });
    let mask = GrayImage::from_fn(W, H, |x, _| Luma([if x < model_right { 255 } else { 0 }]));
    let depth = Gray32FImage::from_fn(W, H, |x, _| Luma([if x < model_right { 2.0 } else { 0.0 }]));
    let rgba = RgbaImage::from_fn(W, H, |x, y| {
        let g = gray.get_pixel(x, y).0[0];
        image::Rgba([g, g, g, if x < model_right { 255 } else { 0 }])
    });
    Frame::from_images(view(), rgba, gray, depth, mask).expect("images of one size")
}

fn config() -> MapConfig {
    MapConfig {
        min_visible: 20,
        subset_size: 16,
        ..MapConfig::default()
    }
}

#[test]
fn adds_features_on_demand_in_free_model_cells() {
    let f = frame(240);
    let mut map = FeatureMap::new(config());
    let visible = map.predict_visible(&f.view, W, H, Some(&f));
    assert!(visible.is_empty() && map.needs_features(&visible));
    let ids = map.add_from_rendering(&f, &[], 0).unwrap();
    println!("added {} features", ids.len());
    // 32-px cells: 7 full columns of cells on the model (x < 224) … partial 8th; 8 rows.
    assert!(ids.len() >= 7 * 7, "{}", ids.len());
    for id in &ids {
        let feat = map.get(*id).unwrap();
        // On the plane, and back-projected where it was extracted.
        assert!(feat.p_w.z.abs() < 1e-9);
        let p_c = f.view.pose.world_to_camera(&feat.p_w);
        let px = f
            .view
            .pinhole
            .to_pixel(Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z));
        assert!(px.x < 240.0 - 3.0, "extracted on background: {px}");
        assert!((px.x - px.x.round()).abs() < 1e-6 && (px.y - px.y.round()).abs() < 1e-6);
        assert!(feat.cov_w.symmetric_eigenvalues().iter().all(|&e| e > 0.0));
    }
    let visible = map.predict_visible(&f.view, W, H, Some(&f));
    assert_eq!(visible.len(), ids.len());
    assert!(!map.needs_features(&visible));
    // Every model cell holds a tracked feature now: nothing more to add there.
    let occupied: Vec<[f64; 2]> = visible.iter().map(|p| [p.pixel.x, p.pixel.y]).collect();
    assert!(map.add_from_rendering(&f, &occupied, 1).unwrap().is_empty());
    // A wider model frees new cells on the right only.
    let wider = frame(W);
    let more = map.add_from_rendering(&wider, &occupied, 2).unwrap();
    assert!(!more.is_empty());
    for id in more {
        let p = map.get(id).unwrap().p_w;
        let p_c = wider.view.pose.world_to_camera(&p);
        let x = wider
            .view
            .pinhole
            .to_pixel(Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z))
            .x;
        assert!(
            x >= 224.0 - 0.5,
            "new feature at x = {x} in an occupied cell"
        );
    }
    // Ids are unique.
    let mut all: Vec<u64> = map.features().iter().map(|f| f.id).collect();
    all.dedup();
    assert_eq!(all.len(), map.len());
}

#[test]
fn occluded_and_out_of_view_points_are_not_visible() {
    let f = frame(W);
    let mut map = FeatureMap::new(config());
    let on_plane = map.insert(Vector3::new(0.1, 0.05, 0.0), Matrix3::identity() * 1e-6, 0);
    // 0.5 m below the rendered surface: hidden by it.
    let hidden = map.insert(Vector3::new(0.1, 0.05, -0.5), Matrix3::identity() * 1e-6, 0);
    let outside = map.insert(Vector3::new(5.0, 0.0, 0.0), Matrix3::identity() * 1e-6, 0);
    let behind = map.insert(Vector3::new(0.0, 0.0, 3.0), Matrix3::identity() * 1e-6, 0);
    let with_depth: Vec<u64> = map
        .predict_visible(&f.view, W, H, Some(&f))
        .iter()
        .map(|p| p.id)
        .collect();
    assert_eq!(with_depth, vec![on_plane]);
    let without: Vec<u64> = map
        .predict_visible(&f.view, W, H, None)
        .iter()
        .map(|p| p.id)
        .collect();
    assert_eq!(without, vec![on_plane, hidden]);
    assert!(!without.contains(&outside) && !without.contains(&behind));
}

#[test]
fn retires_features_that_fail_repeatedly() {
    let mut map = FeatureMap::new(MapConfig {
        max_consecutive_failures: 5,
        ..config()
    });
    let p = Vector3::zeros();
    let c = Matrix3::identity();
    let good = map.insert(p, c, 0);
    let flaky = map.insert(p, c, 0);
    let bad = map.insert(p, c, 0);
    let poor = map.insert(p, c, 0);
    let fail = Outcome::Failure(KltFailure::SsdTooHigh {
        ssd: 0.9,
        threshold: 0.25,
    });
    for frame in 0..12u64 {
        map.record(good, Outcome::Success, frame);
        // Every second attempt fails: never 5 in a row, success ratio 1/2.
        map.record(
            flaky,
            if frame % 2 == 1 {
                Outcome::Success
            } else {
                fail
            },
            frame,
        );
        if frame < 5 {
            map.record(bad, fail, frame);
        }
        // One success in four: ratio 3/11 < 0.3 at the 11th attempt, never 5 failures in a row.
        map.record(
            poor,
            if frame % 4 == 0 {
                Outcome::Success
            } else {
                fail
            },
            frame,
        );
        let retired = map.retire();
        match frame {
            4 => assert_eq!(retired, vec![bad]),
            10 => assert_eq!(retired, vec![poor]),
            _ => assert!(retired.is_empty(), "frame {frame}: {retired:?}"),
        }
    }
    let left: Vec<u64> = map.features().iter().map(|f| f.id).collect();
    assert_eq!(left, vec![good, flaky]);
    let s = map.get(good).unwrap().stats;
    assert_eq!(
        (s.attempts, s.successes, s.consecutive_failures),
        (12, 12, 0)
    );
    assert_eq!(s.last_success_frame, Some(11));
    // Unknown ids are ignored.
    map.record(999, fail, 12);
}

#[test]
fn selection_is_spread_over_the_image() {
    let mut map = FeatureMap::new(config());
    let mut visible = Vec::new();
    // 400 proven features crowded into the top-left 60×40 px …
    for i in 0..400u32 {
        let id = map.insert(Vector3::zeros(), Matrix3::identity(), 0);
        for k in 0..10 {
            map.record(id, Outcome::Success, k);
        }
        visible.push(Predicted {
            id,
            pixel: Vector2::new((i % 20) as f64 * 3.0, (i / 20) as f64 * 2.0),
            z: 2.0,
        });
    }
    // … and 48 new ones on a regular grid over the whole image.
    for i in 0..48u32 {
        let id = map.insert(Vector3::zeros(), Matrix3::identity(), 0);
        visible.push(Predicted {
            id,
            pixel: Vector2::new(20.0 + (i % 8) as f64 * 40.0, 15.0 + (i / 8) as f64 * 40.0),
            z: 2.0,
        });
    }
    let chosen = map.select(&visible, W, H);
    assert_eq!(chosen.len(), 16);
    let cells = |ps: &[Predicted]| {
        let mut c: Vec<(u32, u32)> = ps
            .iter()
            .map(|p| ((p.pixel.x / 80.0) as u32, (p.pixel.y / 60.0) as u32))
            .collect();
        c.sort();
        c.dedup();
        c.len()
    };
    // The best 16 by quality alone would all sit in one corner cell.
    let mut by_quality = visible.clone();
    by_quality.sort_by(|a, b| {
        let q = |p: &Predicted| map.get(p.id).unwrap().stats.quality();
        q(b).total_cmp(&q(a))
    });
    println!(
        "4×4 image cells covered: spread selection {}, best-quality-first {}",
        cells(&chosen),
        cells(&by_quality[..16])
    );
    assert_eq!(cells(&by_quality[..16]), 1);
    assert!(cells(&chosen) >= 12);
    // The crowded corner still contributes its best, and no feature is chosen twice.
    let mut ids: Vec<u64> = chosen.iter().map(|p| p.id).collect();
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 16);
    assert!(chosen.iter().any(|p| p.id < 400));
    // Fewer visible than wanted: all of them.
    assert_eq!(map.select(&visible[..5], W, H).len(), 5);
    assert!(map.select(&[], W, H).is_empty());
}

#[test]
fn correspondences_carry_normalised_points_and_propagated_covariances() {
    let pinhole = Pinhole::new(458.0, 457.0, 367.0, 248.0).with_skew(0.3);
    let ideal = Camera::new(752, 480, pinhole, Distortion::None).unwrap();
    let cov_px = Matrix2::new(0.04, 0.01, 0.01, 0.09);
    let p_w = Vector3::new(1.0, 2.0, 3.0);
    let cov_w = Matrix3::new(1e-4, 1e-5, 0.0, 1e-5, 2e-4, 3e-6, 0.0, 3e-6, 4e-4);
    let px = Vector2::new(500.25, 100.75);
    let c = correspondence::correspondence(&ideal, px, &cov_px, &p_w, &cov_w).unwrap();
    // Ideal camera: m_n = K⁻¹ p and Σ_n = A Σ_p Aᵀ with A the 2×2 block of K⁻¹.
    let k_inv = pinhole.k().try_inverse().unwrap();
    let a = k_inv.fixed_view::<2, 2>(0, 0).into_owned();
    let want = a * cov_px * a.transpose();
    let n = pinhole.to_normalised(px);
    assert!((c.m_n[0] as f64 - n.x).abs() < 1e-6 && (c.m_n[1] as f64 - n.y).abs() < 1e-6);
    for (got, w) in c
        .cov_n
        .iter()
        .zip([want[(0, 0)], want[(0, 1)], want[(1, 1)]])
    {
        assert!(
            (*got as f64 - w).abs() < 1e-6 * w.abs().max(1e-9),
            "{got} vs {w}"
        );
    }
    assert_eq!(c.m_w, [1.0, 2.0, 3.0]);
    assert_eq!(c.cov_w, [1e-4, 1e-5, 0.0, 2e-4, 3e-6, 4e-4]);

    // Distorted camera (EuRoC cam0): the covariance maps back to the pixel covariance through
    // the forward model's Jacobian.
    let radtan = Distortion::RadTan {
        k1: -0.2834,
        k2: 0.0739,
        p1: 0.0002,
        p2: 1.76e-05,
        k3: 0.0,
    };
    let cam = Camera::new(752, 480, pinhole, radtan).unwrap();
    let (n, cov_n) = correspondence::pixel_to_normalised(&cam, px, &cov_px).unwrap();
    assert!((cam.normalised_to_pixel(n) - px).norm() < 1e-9);
    let h = 1e-7;
    let jx = (cam.normalised_to_pixel(n + Vector2::new(h, 0.0)) - cam.normalised_to_pixel(n)) / h;
    let jy = (cam.normalised_to_pixel(n + Vector2::new(0.0, h)) - cam.normalised_to_pixel(n)) / h;
    let j = Matrix2::from_columns(&[jx, jy]);
    let back = j * cov_n * j.transpose();
    assert!(
        (back - cov_px).norm() < 1e-5 * cov_px.norm(),
        "{back} vs {cov_px}"
    );

    // Bad input: typed errors.
    let nan = Vector2::new(f64::NAN, 1.0);
    assert_eq!(
        correspondence::correspondence(&cam, nan, &cov_px, &p_w, &cov_w),
        Err(CorrespondenceError::NotFinite)
    );
    let neg = Matrix2::new(-1.0, 0.0, 0.0, 1.0);
    assert_eq!(
        correspondence::correspondence(&cam, px, &neg, &p_w, &cov_w),
        Err(CorrespondenceError::BadCovariance)
    );

    // A frame's correspondences as protocol messages, split without truncation.
    let all: Vec<_> = (0..40).map(|_| c).collect();
    let msgs = correspondence::frame_messages(7, 123_456, &all).unwrap();
    assert_eq!(msgs.len(), 3);
    assert_eq!(msgs.iter().map(|m| m.items.len()).sum::<usize>(), 40);
    assert!(msgs.iter().all(|m| m.frame_id == 7 && m.parts == 3));
    let too_many: Vec<_> = (0..1000).map(|_| c).collect();
    assert!(correspondence::frame_messages(7, 0, &too_many).is_err());
}

/// A small object wholly in view gets cells small enough for about `2 × min_visible` of them
/// on it (down to 12 px), when asked for (vision-only runs); a model cut by the image border,
/// one that covers a quarter of the image, or the default configuration keep the 32-px cells.
#[test]
fn small_objects_get_smaller_cells_when_asked() {
    let square = |x0: u32, side: u32| {
        image::GrayImage::from_fn(640, 480, |x, y| {
            image::Luma([
                if (x0..x0 + side).contains(&x) && (200..200 + side).contains(&y) {
                    255
                } else {
                    0
                },
            ])
        })
    };
    let small = square(300, 160);
    let adaptive = FeatureMap::new(MapConfig {
        small_object_cells: true,
        ..MapConfig::default()
    });
    // 160² px / (2 × 40) = 320 px² per cell: 17 px.
    assert_eq!(adaptive.grid_for(&small).cell_size, 17);
    assert_eq!(
        FeatureMap::new(MapConfig::default())
            .grid_for(&small)
            .cell_size,
        32
    );
    assert_eq!(
        adaptive.grid_for(&square(0, 160)).cell_size,
        32,
        "cut by the border"
    );
    assert_eq!(
        adaptive.grid_for(&square(100, 279)).cell_size,
        32,
        "a quarter of the image"
    );
    assert_eq!(
        adaptive.grid_for(&square(300, 40)).cell_size,
        12,
        "the smallest cell"
    );
}
