//! Tests of [`super`] (`pyramid.rs`).

//! The fast passes against direct per-pixel definitions, including images smaller than
//! the kernels (every border case).
use super::*;

/// A small deterministic generator for the random images (also `support`'s tests).
pub(super) fn lcg(seed: &mut u64) -> u64 {
    *seed = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    *seed >> 33
}

fn sizes() -> Vec<(usize, usize)> {
    let mut v = vec![
        (1, 1),
        (1, 7),
        (7, 1),
        (2, 3),
        (3, 2),
        (5, 5),
        (6, 9),
        (17, 12),
    ];
    v.push((40, 31));
    v
}

fn conv_ref(img: &GrayF32, kernel: &[f32]) -> Vec<f32> {
    let (w, h) = (img.width(), img.height());
    let r = kernel.len() as isize - 1;
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for dy in -r..=r {
                for dx in -r..=r {
                    let v = img.data()
                        [reflect101(y as isize + dy, h) * w + reflect101(x as isize + dx, w)];
                    acc += kernel[dy.unsigned_abs()] * kernel[dx.unsigned_abs()] * v;
                }
            }
            out[y * w + x] = acc;
        }
    }
    out
}

#[test]
fn blur_and_pyr_down_match_direct_definitions() {
    let mut seed = 7;
    for (w, h) in sizes() {
        let data = (0..w * h).map(|_| (lcg(&mut seed) % 256) as f32).collect();
        let img = GrayF32::new(w, h, data).unwrap();
        let sigma = 1.0f32;
        let mut k: Vec<f32> = (0..=3)
            .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
            .collect();
        let sum = k[0] + 2.0 * k[1..].iter().sum::<f32>();
        k.iter_mut().for_each(|v| *v /= sum);
        let fast = gaussian_blur(&img, sigma);
        for (a, b) in fast.data().iter().zip(conv_ref(&img, &k)) {
            assert!((a - b).abs() < 1e-3, "{w}x{h}: {a} vs {b}");
        }
        let full = conv_ref(&img, &[6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0]);
        let down = pyr_down(&img);
        assert_eq!(
            (down.width(), down.height()),
            (w.div_ceil(2), h.div_ceil(2))
        );
        for y2 in 0..down.height() {
            for x2 in 0..down.width() {
                let (a, b) = (
                    down.data()[y2 * down.width() + x2],
                    full[2 * y2 * w + 2 * x2],
                );
                assert!((a - b).abs() < 1e-3, "{w}x{h}: {a} vs {b}");
            }
        }
    }
}

#[test]
fn erosion_and_mask_pyramid_match_direct_definitions() {
    let mut seed = 11;
    for (w, h) in sizes().into_iter().chain([(64, 48), (33, 70)]) {
        for density in [2, 10, 60] {
            let data = (0..w * h)
                .map(|_| !lcg(&mut seed).is_multiple_of(density))
                .collect();
            let m = Mask::new(w, h, data).unwrap();
            for r in [1, 2, 3, 8] {
                let e = erode(&m, r);
                for y in 0..h {
                    for x in 0..w {
                        let want = (y.saturating_sub(r)..=(y + r).min(h - 1)).all(|yy| {
                            (x.saturating_sub(r)..=(x + r).min(w - 1)).all(|xx| m.get(xx, yy))
                        });
                        assert_eq!(e.get(x, y), want, "{w}x{h} r={r} at ({x},{y})");
                    }
                }
            }
            // Big enough for two levels: each coarse pixel is the AND of its 5×5 support.
            if w >= 2 * MIN_LEVEL_SIDE && h >= 2 * MIN_LEVEL_SIDE {
                let p = MaskPyramid::build(m.clone(), 2);
                let c = p.level(1).unwrap();
                for y2 in 0..c.height() {
                    for x2 in 0..c.width() {
                        let (x, y) = (2 * x2 as isize, 2 * y2 as isize);
                        let want = (-2..=2).all(|dy| {
                            (-2..=2).all(|dx| m.get(reflect101(x + dx, w), reflect101(y + dy, h)))
                        });
                        assert_eq!(c.get(x2, y2), want);
                    }
                }
            }
        }
    }
}

fn random_image(w: usize, h: usize, seed: &mut u64) -> GrayF32 {
    let data = (0..w * h)
        .map(|_| (lcg(seed) % 25_600) as f32 / 100.0)
        .collect();
    GrayF32::new(w, h, data).unwrap()
}

fn assert_same(a: &GrayF32, b: &GrayF32, what: &str) {
    assert_eq!((a.width(), a.height()), (b.width(), b.height()), "{what}");
    for (i, (x, y)) in a.data().iter().zip(b.data()).enumerate() {
        assert_eq!(x.to_bits(), y.to_bits(), "{what} at {i}: {x} vs {y}");
    }
}

/// Every size up to 40 × 40 (all the border cases of every kernel here, both parities,
/// the vector chunks' overlapping tails): blur and pyramid step equal the reference to the
/// last bit, with each instruction set's copy of the kernels.
#[test]
fn vectorised_passes_equal_the_reference_bit_for_bit() {
    isa::each_copy(|copy| {
        let mut seed = 3;
        for w in 1..=40 {
            for h in 1..=40 {
                let img = random_image(w, h, &mut seed);
                for sigma in [0.5f32, 1.0, std::f32::consts::SQRT_2] {
                    assert_same(
                        &gaussian_blur(&img, sigma),
                        &reference::gaussian_blur(&img, sigma),
                        &format!("blur {w}x{h} σ={sigma}, {copy}"),
                    );
                }
                assert_same(
                    &pyr_down(&img),
                    &reference::pyr_down(&img),
                    &format!("pyr_down {w}x{h}, {copy}"),
                );
            }
        }
        // Wide kernels (radius above the vectorised passes' limit) and a wide image.
        let img = random_image(300, 21, &mut seed);
        for sigma in [2.5f32, 6.0] {
            assert_same(
                &gaussian_blur(&img, sigma),
                &reference::gaussian_blur(&img, sigma),
                &format!("blur 300x21 σ={sigma}, {copy}"),
            );
        }
        assert_same(
            &pyr_down(&img),
            &reference::pyr_down(&img),
            &format!("pyr_down 300x21, {copy}"),
        );
    });
}

/// The pyramids as the tracker builds them, on a 752 × 480 image: every level equal, with
/// each instruction set's copy of the kernels.
#[test]
fn pyramids_equal_the_reference_at_full_size() {
    isa::each_copy(|copy| {
        let mut seed = 17;
        let img = random_image(752, 480, &mut seed);
        let p = Pyramid::build_smoothed(img.clone(), 4, 1.0);
        let mut want = vec![reference::gaussian_blur(&img, 1.0)];
        for _ in 1..4 {
            want.push(reference::pyr_down(&want[want.len() - 1]));
        }
        assert_eq!(p.len(), 4);
        for (k, (a, b)) in p.levels().iter().zip(&want).enumerate() {
            assert_same(a, b, &format!("level {k}, {copy}"));
        }
        let mask = Mask::new(
            752,
            480,
            (0..752 * 480)
                .map(|_| !lcg(&mut seed).is_multiple_of(50))
                .collect(),
        )
        .unwrap();
        let t =
            TemplatePyramid::build(img.clone(), mask.clone(), 4, std::f32::consts::SQRT_2).unwrap();
        let mut m = reference::erode(&mask, 3);
        assert_eq!(t.mask.level(0).unwrap().data(), m.data());
        for k in 1..4 {
            m = reference::mask_pyr_down(&m).unwrap();
            assert_eq!(
                t.mask.level(k).unwrap().data(),
                m.data(),
                "mask level {k}, {copy}"
            );
        }
        let b = reference::gaussian_blur(&img, std::f32::consts::SQRT_2);
        assert_same(
            t.image.level(0).unwrap(),
            &b,
            &format!("template level 0, {copy}"),
        );
    });
}

/// Issue 54, point 27: a template kept for the clipped prediction is blurred by the
/// anti-aliasing, kept, then by the registration's smoothing, whose kernel it carries; its mask
/// is eroded by the two blurs' reach together, as the one-step template's.
#[test]
fn a_template_kept_for_clipping_holds_its_image_between_the_blurs() {
    let mut seed = 5;
    let img = random_image(160, 120, &mut seed);
    let mask = Mask::new(160, 120, vec![true; 160 * 120]).unwrap();
    let (antialias, smoothing) = (1.0f32, 1.0f32);
    let kept = TemplatePyramid::build_keeping_unsmoothed(
        img.clone(),
        mask.clone(),
        3,
        antialias,
        smoothing,
    )
    .unwrap();
    let (i0, kernel) = kept.image.unsmoothed().expect("kept");
    assert_same(
        i0,
        &reference::gaussian_blur(&img, antialias),
        "the kept image",
    );
    assert_eq!(kernel, gaussian_kernel(smoothing).unwrap().as_slice());
    assert_same(
        kept.image.level(0).unwrap(),
        &reference::gaussian_blur(&reference::gaussian_blur(&img, antialias), smoothing),
        "level 0",
    );
    let one = TemplatePyramid::build(img, mask, 3, (antialias.powi(2) + smoothing.powi(2)).sqrt())
        .unwrap();
    assert!(one.image.unsmoothed().is_none());
    assert_eq!(
        one.mask.level(0).unwrap().data(),
        kept.mask.level(0).unwrap().data()
    );
}

/// Erosion and the mask pyramid step against the reference for every size up to 24 × 24.
#[test]
fn masks_equal_the_reference() {
    let mut seed = 23;
    for w in 1..=24 {
        for h in 1..=24 {
            for density in [2, 7] {
                let data = (0..w * h)
                    .map(|_| !lcg(&mut seed).is_multiple_of(density))
                    .collect();
                let m = Mask::new(w, h, data).unwrap();
                for r in [1, 2, 3, 5] {
                    assert_eq!(
                        erode(&m, r).data(),
                        reference::erode(&m, r).data(),
                        "{w}x{h} r={r}"
                    );
                }
                let (a, b) = (
                    mask_pyr_down(&m).unwrap(),
                    reference::mask_pyr_down(&m).unwrap(),
                );
                assert_eq!((a.width(), a.height()), (b.width(), b.height()));
                assert_eq!(a.data(), b.data(), "{w}x{h}");
            }
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Random sizes, σ and values (including large and negative ones).
    #[test]
    fn blur_equals_the_reference_on_random_images(
        w in 1usize..120, h in 1usize..30, sigma in 0.1f32..4.0, seed in 0u64..1_000_000,
    ) {
        let mut seed = seed;
        let data = (0..w * h)
            .map(|_| (lcg(&mut seed) as f32 / 1000.0) - 1.0e6)
            .collect();
        let img = GrayF32::new(w, h, data).unwrap();
        let (a, b) = (gaussian_blur(&img, sigma), reference::gaussian_blur(&img, sigma));
        proptest::prop_assert!(a.data().iter().zip(b.data()).all(|(x, y)| x.to_bits() == y.to_bits()));
        let (a, b) = (pyr_down(&img), reference::pyr_down(&img));
        proptest::prop_assert!(a.data().iter().zip(b.data()).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
}
