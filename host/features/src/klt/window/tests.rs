//! The window's fast path against per-sample definitions.

use super::*;
use crate::pyramid::Pyramid;

/// A window inside the image that the mask covers in part takes its weights from whole
/// mask rows: the same verdicts as `Mask::valid_bilinear` per sample, at integer and
/// fractional origins, and the samples of the valid pixels kept.
#[test]
fn partly_masked_template_weights_match_per_sample_validity() {
    let (w, h) = (40, 30);
    let img = GrayF32::new(w, h, (0..w * h).map(|k| (k % 17) as f32).collect()).unwrap();
    // Valid below a diagonal, so that every window here is cut by it.
    let mask = Mask::new(w, h, (0..w * h).map(|k| k % w + k / w < 35).collect()).unwrap();
    let mut win = Window::new(7);
    for (gx, gy) in [(15.0, 12.0), (15.25, 12.0), (15.0, 12.5), (16.3, 11.7)] {
        win.sample_template(&img, Some(&mask), gx, gy);
        let (ox, oy) = (gx - 7.0, gy - 7.0);
        let mut count = 0;
        for j in 0..win.side {
            for i in 0..win.pw {
                let k = j * win.pw + i;
                let (x, y) = (ox + i as f64, oy + j as f64);
                let valid = i < win.side && mask.valid_bilinear(x, y);
                assert_eq!(
                    win.tw[k],
                    f32::from(u8::from(valid)),
                    "({gx}, {gy}) at {i}, {j}"
                );
                if valid {
                    count += 1;
                    let v = img.sample(x, y).unwrap();
                    assert!((win.t[k] - v).abs() < 1e-4, "({gx}, {gy}) at {i}, {j}");
                } else {
                    assert_eq!(win.t[k], 0.0);
                }
            }
        }
        assert_eq!(win.tcount, count);
        assert!(count > 0 && count < win.side * win.side);
    }
}

/// The clipped prediction's fields on an integer grid against the pyramids of the
/// pointwise fields of `I₀` (the one-kernel reduction against the cascade), inside the
/// image at every level and across the border (reflect-101) at level 0.
#[test]
fn clipped_fields_reduce_as_the_pyramid() {
    let (w, h) = (160, 150);
    let mut seed = 7u64;
    let data: Vec<f32> = (0..w * h)
        .map(|_| {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 56) as f32
        })
        .collect();
    let (ab, range) = ([2.5f32, -60.0], [0.0f32, 255.0]);
    let field = |f: &dyn Fn(f32) -> f32| {
        let img = GrayF32::new(w, h, data.iter().map(|&x| f(x)).collect()).unwrap();
        Pyramid::build_smoothed(img, 4, 1.0)
    };
    let inside = |x: f32| {
        let q = ab[0] * x + ab[1];
        q > range[0] && q < range[1]
    };
    let want = [
        field(&|x| (ab[0] * x + ab[1]).clamp(range[0], range[1])),
        field(&|x| if inside(x) { x } else { 0.0 }),
        field(&|x| if inside(x) { 1.0 } else { 0.0 }),
    ];
    let pyr = Pyramid::build_keeping_unsmoothed(GrayF32::new(w, h, data.clone()).unwrap(), 4, 1.0);
    let (img, kernel) = pyr.unsmoothed().unwrap();
    let (n, r, stride) = (7, 3, 8);
    for (level, corner) in [
        (0, [3, 4]),
        (1, [3, 4]),
        (2, [3, 4]),
        (3, [3, 4]),
        (0, [0, 1]),
    ] {
        let (gx, gy) = ((corner[0] + r) as f64, (corner[1] + r) as f64);
        let pre = Pre {
            img,
            kernel,
            level,
            gx,
            gy,
        };
        let mut scratch = ClipScratch::default();
        scratch.prepare(&pre, r);
        let mut f = [(); 3].map(|_| vec![0f32; n * stride]);
        let [f0, f1, f2] = &mut f;
        let out = [&mut f0[..], &mut f1[..], &mut f2[..]];
        let origin = [gx - r as f64, gy - r as f64];
        assert!(scratch.fields(&pre, origin, n, ab, range, out, stride));
        for (k, (got, want)) in f.iter().zip(&want).enumerate() {
            let lv = want.level(level).unwrap();
            for j in 0..n {
                for i in 0..n {
                    let e = lv.get(corner[0] + i, corner[1] + j).unwrap();
                    let g = got[j * stride + i];
                    assert!(
                        (g - e).abs() < 2e-3,
                        "level {level}, field {k}, ({i}, {j}): {g} vs {e}"
                    );
                }
            }
        }
    }
}
