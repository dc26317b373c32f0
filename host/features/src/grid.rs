//! FAST extraction restricted to free areas of the rendering (paper §2): the image is cut into
//! square cells; a cell that already holds a tracked feature, or that the model's mask does
//! not cover well enough, gets no new feature. Each free cell contributes its best corners.

use image::GrayImage;

use super::fast::{self, CIRCLE, Corner};
use super::gray::{ImageError, Mask};

/// Extraction parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridConfig {
    /// Cell side, px.
    pub cell_size: usize,
    /// FAST threshold, gray levels.
    pub fast_threshold: u8,
    /// Corners taken per free cell (the best scores).
    pub per_cell: usize,
    /// A cell counts as on the model if at least this fraction of its pixels is in the mask.
    pub min_mask_fraction: f64,
    /// Corners closer than this to the image border are dropped (registration windows need
    /// room), px.
    pub border: usize,
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            cell_size: 32,
            fast_threshold: 20,
            per_cell: 1,
            min_mask_fraction: 0.5,
            border: 8,
        }
    }
}

/// The cell layout of an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    /// Cell side, px.
    pub cell: usize,
    /// Cells per row.
    pub cols: usize,
    /// Cell rows.
    pub rows: usize,
}

impl Grid {
    /// Cells of side `cell` (≥ 1) covering a `width × height` image (the last row and column
    /// may be partial).
    pub fn new(width: usize, height: usize, cell: usize) -> Self {
        let cell = cell.max(1);
        Self {
            cell,
            cols: width.div_ceil(cell),
            rows: height.div_ceil(cell),
        }
    }

    /// Index of the cell holding pixel position `(x, y)`; `None` outside or non-finite.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<usize> {
        // Pixel (0, 0) covers [−0.5, 0.5]²: shift so that cells start at pixel edges.
        let (fx, fy) = (x + 0.5, y + 0.5);
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (c, r) = (
            (fx / self.cell as f64) as usize,
            (fy / self.cell as f64) as usize,
        );
        (c < self.cols && r < self.rows).then_some(r * self.cols + c)
    }
}

/// Which cells may receive new features: not holding one of `occupied` (tracked feature
/// positions, px) and, with a mask, covered by it for at least `min_mask_fraction`.
pub fn free_cells(
    width: usize,
    height: usize,
    mask: Option<&Mask>,
    occupied: &[[f64; 2]],
    cfg: &GridConfig,
) -> (Grid, Vec<bool>) {
    let grid = Grid::new(width, height, cfg.cell_size);
    let mut free = vec![true; grid.cols * grid.rows];
    for p in occupied {
        if let Some(c) = grid.cell_of(p[0], p[1]) {
            free[c] = false;
        }
    }
    if let Some(m) = mask {
        let mw = m.width();
        for r in 0..grid.rows {
            for c in 0..grid.cols {
                // A cell already taken needs no count.
                if !free[r * grid.cols + c] {
                    continue;
                }
                let (x0, y0) = (c * grid.cell, r * grid.cell);
                let (x1, y1) = ((x0 + grid.cell).min(width), (y0 + grid.cell).min(height));
                // Whole rows of the mask, a form the compiler vectorises (`m.get` per pixel
                // did not); outside the mask counts as off, as `m.get` has it.
                let on = (y0..y1.min(m.height()))
                    .map(|y| {
                        let row = &m.data()[y * mw..(y + 1) * mw];
                        row[x0.min(mw)..x1.min(mw)].iter().filter(|&&v| v).count()
                    })
                    .sum::<usize>();
                let total = (x1 - x0) * (y1 - y0);
                if (on as f64) < cfg.min_mask_fraction * total as f64 {
                    free[r * grid.cols + c] = false;
                }
            }
        }
    }
    (grid, free)
}

/// New FAST corners (non-maximum suppressed) in the free cells: per cell the `per_cell`
/// highest scores among corners whose centre and whole circle lie on the mask (a corner on
/// the silhouette would be a corner against the background, which the live image does not
/// share). Ordered by cell, then by decreasing score.
pub fn extract(
    img: &GrayImage,
    mask: Option<&Mask>,
    occupied: &[[f64; 2]],
    cfg: &GridConfig,
) -> Result<Vec<Corner>, ImageError> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if let Some(m) = mask
        && (m.width(), m.height()) != (w, h)
    {
        return Err(ImageError::SizeMismatch {
            a: (w, h),
            b: (m.width(), m.height()),
        });
    }
    let (grid, free) = free_cells(w, h, mask, occupied, cfg);
    let mut per_cell: Vec<Vec<Corner>> = vec![Vec::new(); free.len()];
    for c in fast::detect(img, cfg.fast_threshold, true) {
        let (x, y) = (c.x as usize, c.y as usize);
        if x < cfg.border || y < cfg.border || x + cfg.border >= w || y + cfg.border >= h {
            continue;
        }
        let Some(cell) = grid.cell_of(x as f64, y as f64) else {
            continue;
        };
        if !free[cell] {
            continue;
        }
        if let Some(m) = mask {
            let on_model = m.get(x, y)
                && CIRCLE.iter().all(|&(dx, dy)| {
                    m.get(
                        (x as i64 + dx as i64) as usize,
                        (y as i64 + dy as i64) as usize,
                    )
                });
            if !on_model {
                continue;
            }
        }
        per_cell[cell].push(c);
    }
    let mut out = Vec::new();
    for mut cs in per_cell {
        // Stable: equal scores keep row-major order, so the result is deterministic.
        cs.sort_by_key(|c| std::cmp::Reverse(c.score));
        out.extend(cs.into_iter().take(cfg.per_cell));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The free cells from whole mask rows agree with counting `Mask::get` pixel by pixel, on
    /// a mask of uneven coverage whose cells do not divide the image, with cells occupied.
    #[test]
    fn free_cells_agree_with_the_per_pixel_count() {
        let (w, h) = (101, 77);
        let mut seed = 3u64;
        let mask = Mask::new(
            w,
            h,
            (0..w * h)
                .map(|k| {
                    seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                    // Denser towards the right, so cells fall on both sides of the fraction.
                    ((seed >> 40) % 100) as usize <= (k % w)
                })
                .collect(),
        )
        .unwrap();
        let cfg = GridConfig {
            cell_size: 16,
            min_mask_fraction: 0.5,
            ..GridConfig::default()
        };
        let occupied = [[3.0, 3.0], [70.5, 40.2], [100.0, 76.0]];
        let (grid, free) = free_cells(w, h, Some(&mask), &occupied, &cfg);
        let mut expected = vec![true; grid.cols * grid.rows];
        for p in &occupied {
            if let Some(c) = grid.cell_of(p[0], p[1]) {
                expected[c] = false;
            }
        }
        for r in 0..grid.rows {
            for c in 0..grid.cols {
                let (x0, y0) = (c * grid.cell, r * grid.cell);
                let (x1, y1) = ((x0 + grid.cell).min(w), (y0 + grid.cell).min(h));
                let on = (y0..y1)
                    .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                    .filter(|&(x, y)| mask.get(x, y))
                    .count();
                if (on as f64) < cfg.min_mask_fraction * ((x1 - x0) * (y1 - y0)) as f64 {
                    expected[r * grid.cols + c] = false;
                }
            }
        }
        assert_eq!(free, expected);
        assert!(free.iter().any(|&f| f) && free.iter().any(|&f| !f));
    }
}
