//! FAST-9 against a brute-force segment test written here from the definition, and against
//! OpenCV's reference corners, on real images of `../shared/data` (skipped with a message
//! when that folder is absent).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use host_vision::features::fast::{self, CIRCLE, Corner};
use host_vision::features::gray::Mask;
use host_vision::features::grid::{self, GridConfig};
use image::GrayImage;
use proptest::prelude::*;

fn data_root() -> Option<PathBuf> {
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    if root.is_dir() {
        Some(root.to_path_buf())
    } else {
        println!(
            "SKIPPED: shared data folder {} absent; real-image FAST checks not run",
            root.display()
        );
        None
    }
}

fn load(path: &Path) -> GrayImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_luma8()
}

/// The strict segment test from its definition: 9 contiguous circle pixels (wrapping) all
/// brighter than `v + t` or all darker than `v − t`.
fn segment_test(img: &GrayImage, x: u32, y: u32, t: i32) -> bool {
    let v = img.get_pixel(x, y).0[0] as i32;
    let c: Vec<i32> = CIRCLE
        .iter()
        .map(|&(dx, dy)| {
            img.get_pixel((x as i32 + dx) as u32, (y as i32 + dy) as u32)
                .0[0] as i32
        })
        .collect();
    (0..16)
        .any(|s| (0..9).all(|k| c[(s + k) % 16] > v + t) || (0..9).all(|k| c[(s + k) % 16] < v - t))
}

/// Brute-force FAST: every pixel 3 from the border, score = the largest threshold that still
/// passes (found by raising it one by one), strict 3×3 non-maximum suppression.
fn brute_force(img: &GrayImage, t: u8, nms: bool) -> Vec<Corner> {
    let (w, h) = img.dimensions();
    let mut score = vec![None::<u16>; (w * h) as usize];
    for y in 3..h.saturating_sub(3) {
        for x in 3..w.saturating_sub(3) {
            if segment_test(img, x, y, t as i32) {
                let mut s = t as i32;
                while s < 255 && segment_test(img, x, y, s + 1) {
                    s += 1;
                }
                score[(y * w + x) as usize] = Some(s as u16);
            }
        }
    }
    let at = |x: u32, y: u32| score[(y * w + x) as usize];
    let mut out = Vec::new();
    for y in 3..h.saturating_sub(3) {
        for x in 3..w.saturating_sub(3) {
            let Some(s) = at(x, y) else { continue };
            let is_max = (y - 1..=y + 1).all(|yy| {
                (x - 1..=x + 1).all(|xx| (xx, yy) == (x, y) || at(xx, yy).unwrap_or(0) < s)
            });
            if !nms || is_max {
                out.push(Corner { x, y, score: s });
            }
        }
    }
    out
}

fn test_images(root: &Path) -> Vec<PathBuf> {
    let cam0 = root.join("euroc-v101-micro/mav0/cam0/data");
    vec![
        cam0.join("1403715273262142976.png"),
        cam0.join("1403715275762142976.png"),
        root.join("textures/skimage/camera.png"),
        root.join("textures/skimage/brick.png"),
        root.join("textures/opencv_samples/graf1.png"),
        root.join("textures/opencv_samples/box.png"),
    ]
}

#[test]
fn equals_brute_force_segment_test_on_real_images() {
    let Some(root) = data_root() else { return };
    for path in test_images(&root) {
        let img = load(&path);
        for (t, nms) in [(20, true), (20, false), (10, true), (40, true), (1, true)] {
            let got = fast::detect(&img, t, nms);
            let want = brute_force(&img, t, nms);
            println!(
                "{}: threshold {t}, nms {nms}: {} corners (brute force {})",
                path.file_name().unwrap().to_string_lossy(),
                got.len(),
                want.len()
            );
            assert!(!want.is_empty(), "a real image has corners");
            assert_eq!(got, want, "{} t={t} nms={nms}", path.display());
        }
    }
}

#[test]
fn matches_opencv_reference_corners_and_scores() {
    let Some(root) = data_root() else { return };
    let refs = root.join("reference/opencv-fast");
    for (csv, expected_count) in [("fast_frame00.csv", 891), ("fast_frame50.csv", 892)] {
        let text = std::fs::read_to_string(refs.join(csv)).unwrap();
        let mut lines = text.lines();
        let header = lines.next().unwrap();
        let source = header
            .split_whitespace()
            .find_map(|f| f.strip_prefix("source="))
            .expect("source= in the first line");
        assert_eq!(lines.next(), Some("x,y,response"));
        let reference: BTreeSet<(u32, u32, u16)> = lines
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (
                    f[0].parse::<f64>().unwrap() as u32,
                    f[1].parse::<f64>().unwrap() as u32,
                    f[2].parse::<u16>().unwrap(),
                )
            })
            .collect();
        assert_eq!(reference.len(), expected_count);
        let img = load(&root.join("euroc-v101-micro/mav0/cam0/data").join(source));
        let corners = fast::detect(&img, 20, true);
        let ours: BTreeSet<(u32, u32, u16)> = corners.iter().map(|c| (c.x, c.y, c.score)).collect();
        let missing: Vec<_> = reference.difference(&ours).take(10).collect();
        let extra: Vec<_> = ours.difference(&reference).take(10).collect();
        println!(
            "{source}: {} corners (OpenCV {}), first ten (x, y, score): {:?}",
            corners.len(),
            reference.len(),
            corners
                .iter()
                .take(10)
                .map(|c| (c.x, c.y, c.score))
                .collect::<Vec<_>>()
        );
        let mean_score = corners.iter().map(|c| c.score as f64).sum::<f64>() / corners.len() as f64;
        let (xs, ys): (Vec<u32>, Vec<u32>) = corners.iter().map(|c| (c.x, c.y)).unzip();
        println!(
            "  x {}..{}, y {}..{}, mean score {mean_score:.1}",
            xs.iter().min().unwrap(),
            xs.iter().max().unwrap(),
            ys.iter().min().unwrap(),
            ys.iter().max().unwrap()
        );
        assert!(
            missing.is_empty() && extra.is_empty(),
            "missing {missing:?}, extra {extra:?}"
        );
        assert_eq!(corners.len(), reference.len());
    }
}

#[test]
fn tiny_and_flat_images_have_no_corners() {
    for (w, h) in [(1, 1), (6, 6), (7, 7), (3, 50)] {
        let img = GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 37 + y * 91) % 256) as u8]));
        assert!(
            fast::detect(&img, 0, false).len()
                <= ((w.saturating_sub(6)) * (h.saturating_sub(6))) as usize
        );
        assert_eq!(fast::score_map(&img, 20).len(), (w * h) as usize);
    }
    let flat = GrayImage::from_pixel(40, 30, image::Luma([128]));
    assert!(fast::detect(&flat, 0, false).is_empty());
    // One bright dot on black: a corner at the dot (all 16 circle pixels darker), score 254.
    let mut dot = GrayImage::new(20, 20);
    dot.put_pixel(10, 10, image::Luma([255]));
    let c = fast::detect(&dot, 20, true);
    assert_eq!(
        c,
        vec![Corner {
            x: 10,
            y: 10,
            score: 254
        }]
    );
}

#[test]
fn grid_extraction_skips_occupied_and_masked_cells() {
    // Bright 5×5 squares every 16 px on a dark ground: FAST corners at their corners.
    let (w, h) = (128u32, 96u32);
    let img = GrayImage::from_fn(w, h, |x, y| {
        let on = (x % 16) >= 6 && (x % 16) < 11 && (y % 16) >= 6 && (y % 16) < 11;
        let noise = ((x * 7 + y * 13) % 11) as u8;
        image::Luma([if on { 200 + noise } else { 40 + noise }])
    });
    let cfg = GridConfig {
        cell_size: 32,
        ..GridConfig::default()
    };
    let all = grid::extract(&img, None, &[], &cfg).unwrap();
    // 4 × 3 cells, one corner each.
    assert_eq!(all.len(), 12);
    // Occupied: the cell holding (40, 40) is skipped.
    let some = grid::extract(&img, None, &[[40.0, 40.0]], &cfg).unwrap();
    assert_eq!(some.len(), 11);
    assert!(
        some.iter()
            .all(|c| !(32..64).contains(&c.x) || !(32..64).contains(&c.y))
    );
    // Mask only the left half: right-half cells are skipped, and corners whose circle
    // reaches the background are dropped.
    let mut mask = Mask::full(w as usize, h as usize).unwrap();
    for y in 0..h as usize {
        for x in 64..w as usize {
            mask.set(x, y, false);
        }
    }
    let left = grid::extract(&img, Some(&mask), &[], &cfg).unwrap();
    assert_eq!(left.len(), 6);
    assert!(left.iter().all(|c| c.x + 3 < 64));
    // Every extracted corner is a FAST corner, the best of its cell.
    let fast_all = fast::detect(&img, cfg.fast_threshold, true);
    for c in &all {
        assert!(fast_all.contains(c));
        let (cx, cy) = (c.x / 32, c.y / 32);
        let best = fast_all
            .iter()
            .filter(|o| {
                o.x / 32 == cx
                    && o.y / 32 == cy
                    && o.x >= 8
                    && o.y >= 8
                    && o.x + 8 < w
                    && o.y + 8 < h
            })
            .map(|o| o.score)
            .max()
            .unwrap();
        assert_eq!(c.score, best);
    }
    // Size mismatch is an error, not a panic.
    let small = Mask::full(10, 10).unwrap();
    assert!(grid::extract(&img, Some(&small), &[], &cfg).is_err());
}

/// The vectorised path against the scalar reference (`fast::reference`): the same corners,
/// scores and score map, for one image, threshold and suppression setting, with the baseline's
/// 16 lanes and (where the CPU has AVX2) 32. The choice is global, so tests running beside this
/// one may run either copy meanwhile; every copy must give the reference's answer anyway.
fn assert_same_as_reference(img: &GrayImage, t: u8, nms: bool) {
    let (w, h) = img.dimensions();
    isa::each_copy(|copy| {
        assert_eq!(
            fast::detect(img, t, nms),
            fast::reference::detect(img, t, nms),
            "{w}x{h}, threshold {t}, nms {nms}, {copy}"
        );
        assert_eq!(
            fast::score_map(img, t),
            fast::reference::score_map(img, t),
            "score map {w}x{h}, threshold {t}, {copy}"
        );
    });
}

/// A pseudo-random image with pixel values in `0..levels` spread over 0..=255 (few levels:
/// many equal scores, which is what strict suppression must get right).
fn lcg_image(w: u32, h: u32, seed: u64, levels: u32) -> GrayImage {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    GrayImage::from_fn(w, h, |_, _| {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let level = ((s >> 33) as u32) % levels;
        image::Luma([(level * 255 / (levels - 1).max(1)) as u8])
    })
}

#[test]
fn equals_reference_on_every_small_size() {
    // Every width up to 80 (below 7: no candidates; 7 to 21: fewer than 16 candidates a row,
    // the scalar row path; from 22: 16-lane chunks with an overlapping last chunk; from 38 the
    // same with 32 lanes) and heights around 7.
    let mut corners = 0;
    for w in 1..=80 {
        for h in [1, 2, 6, 7, 8, 9, 13] {
            for (seed, levels) in [(1, 256), (2, 3), (3, 2)] {
                let img = lcg_image(w, h, seed + u64::from(w * 100 + h), levels);
                for t in [0, 1, 20, 255] {
                    for nms in [false, true] {
                        assert_same_as_reference(&img, t, nms);
                    }
                }
                corners += fast::reference::detect(&img, 20, false).len();
            }
        }
    }
    // Not vacuous: the images do have corners.
    assert!(corners > 1000, "{corners} corners");
}

#[test]
fn equals_reference_on_real_images() {
    let Some(root) = data_root() else { return };
    for path in test_images(&root) {
        let img = load(&path);
        for t in [0, 1, 5, 20, 40, 100, 255] {
            for nms in [false, true] {
                assert_same_as_reference(&img, t, nms);
            }
        }
    }
}

fn image_strategy() -> impl Strategy<Value = GrayImage> {
    (
        1u32..=90,
        1u32..=24,
        prop_oneof![Just(2u32), Just(3), Just(8), Just(256)],
    )
        .prop_flat_map(|(w, h, levels)| {
            proptest::collection::vec(0..levels, (w * h) as usize).prop_map(move |v| {
                let px = v
                    .into_iter()
                    .map(|l| (l * 255 / (levels - 1)) as u8)
                    .collect();
                GrayImage::from_raw(w, h, px).expect("w × h pixels")
            })
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn equals_reference_on_random_images(
        img in image_strategy(),
        t in prop_oneof![Just(0u8), Just(1), Just(20), Just(255), any::<u8>()],
        nms in any::<bool>(),
    ) {
        assert_same_as_reference(&img, t, nms);
    }
}
