//! The feature map (paper §2 and its reference [2]): natural features with their 3D model
//! points, managed by simple rules.
//!
//! - **Add on demand**: when fewer than `min_visible` features are predicted visible, FAST
//!   corners are extracted in the free cells of the rendering ([`super::grid`]) and
//!   back-projected through the depth buffer to model points with covariance.
//! - **Retire**: a feature that failed `max_consecutive_failures` registrations in a row, or
//!   whose success ratio stays below `min_success_ratio` after `min_attempts`, is removed.
//! - **Select**: each frame a fixed-size subset of the features predicted visible is
//!   registered, spread over the image: the image is cut into about as many cells as features
//!   wanted and cells are visited round-robin, each giving its best feature per round.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector2, Vector3};

use super::gray::{ImageError, Mask};
use super::grid::{self, GridConfig};
use super::klt::KltFailure;
use render::backproject::backproject;
use render::{Frame, RenderView};

/// Smallest extraction cell [px]: the registration window is 15 px wide, and features closer
/// than about a window share most of their pixels.
pub const MIN_CELL_SIZE: usize = 12;

/// Share of the image below which a rendered model counts as small ([`FeatureMap::grid_for`]).
pub const SMALL_MODEL_SHARE: f64 = 0.25;

/// Map management parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapConfig {
    /// Extract new features when fewer than this many are predicted visible.
    pub min_visible: usize,
    /// Features registered per frame (candidates are tried until this many succeed, or
    /// `max_candidates` were tried).
    pub subset_size: usize,
    /// Most registrations tried per frame.
    pub max_candidates: usize,
    /// Retire after this many failures in a row.
    pub max_consecutive_failures: u32,
    /// Retire when the success ratio is below this …
    pub min_success_ratio: f64,
    /// … after at least this many attempts.
    pub min_attempts: u32,
    /// A predicted point counts as visible only this far (px) inside the image.
    pub margin: f64,
    /// Occlusion test: the rendered depth at the predicted pixel must match the point's depth
    /// within this fraction of it.
    pub depth_tolerance: f64,
    /// Localisation uncertainty of a new corner, px (propagated into the model point).
    pub corner_sigma_px: f64,
    /// Extraction of new features.
    pub grid: GridConfig,
    /// Smaller extraction cells for a small object wholly in view ([`FeatureMap::grid_for`]).
    /// On in vision-only runs, where no IMU bridges frames with few features; the inertial
    /// runs keep the paper's fixed grid.
    pub small_object_cells: bool,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            min_visible: 40,
            subset_size: 40,
            max_candidates: 60,
            max_consecutive_failures: 3,
            min_success_ratio: 0.3,
            min_attempts: 10,
            margin: 8.0,
            depth_tolerance: 0.02,
            corner_sigma_px: 0.5,
            grid: GridConfig::default(),
            small_object_cells: false,
        }
    }
}

/// Registration history of one feature.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FeatureStats {
    /// Frame it was extracted in.
    pub created_frame: u64,
    /// Registrations tried.
    pub attempts: u32,
    /// Registrations accepted.
    pub successes: u32,
    /// Failures since the last success.
    pub consecutive_failures: u32,
    /// Last frame it was registered in, if ever.
    pub last_success_frame: Option<u64>,
}

impl FeatureStats {
    /// Success ratio with one prior success and one prior failure (new features rank
    /// between proven good and proven bad ones).
    pub fn quality(&self) -> f64 {
        (self.successes as f64 + 1.0) / (self.attempts as f64 + 2.0)
    }
}

/// One natural feature of the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapFeature {
    /// Unique id, never reused.
    pub id: u64,
    /// Model point in the world frame, m.
    pub p_w: Vector3<f64>,
    /// Its covariance, m².
    pub cov_w: Matrix3<f64>,
    /// History.
    pub stats: FeatureStats,
}

/// A feature predicted visible in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Predicted {
    /// Feature id.
    pub id: u64,
    /// Predicted pixel (ideal pinhole of the view).
    pub pixel: Vector2<f64>,
    /// Predicted depth along the optical axis, m.
    pub z: f64,
}

/// Outcome of one registration attempt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// Registered and accepted.
    Success,
    /// Failed, with the reason.
    Failure(KltFailure),
    /// Registered, but no rigid pose explains it with the frame's other registrations
    /// ([`crate::outliers`]): not sent, and counted as a failure.
    Outlier,
}

/// The feature map.
#[derive(Debug, Clone, Default)]
pub struct FeatureMap {
    features: Vec<MapFeature>,
    next_id: u64,
    config: MapConfig,
}

impl FeatureMap {
    /// An empty map.
    pub fn new(config: MapConfig) -> Self {
        Self {
            features: Vec::new(),
            next_id: 0,
            config,
        }
    }

    /// The parameters.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }

    /// Changes the settings; the features stay.
    pub fn set_config(&mut self, config: MapConfig) {
        self.config = config;
    }

    /// All features.
    pub fn features(&self) -> &[MapFeature] {
        &self.features
    }

    /// Number of features.
    pub fn len(&self) -> usize {
        self.features.len()
    }

    /// Whether the map is empty.
    pub fn is_empty(&self) -> bool {
        self.features.is_empty()
    }

    /// The feature with `id`.
    pub fn get(&self, id: u64) -> Option<&MapFeature> {
        self.features.iter().find(|f| f.id == id)
    }

    /// Adds a feature directly (model points known otherwise); returns its id.
    pub fn insert(&mut self, p_w: Vector3<f64>, cov_w: Matrix3<f64>, frame: u64) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        self.features.push(MapFeature {
            id,
            p_w,
            cov_w,
            stats: FeatureStats {
                created_frame: frame,
                ..FeatureStats::default()
            },
        });
        id
    }

    /// Features whose model point projects into a `width × height` image of `view`, at least
    /// `margin` inside, in front of the camera, and — with the model rendered from the same
    /// view — not occluded.
    pub fn predict_visible(
        &self,
        view: &RenderView,
        width: u32,
        height: u32,
        rendering: Option<&Frame>,
    ) -> Vec<Predicted> {
        let m = self.config.margin;
        let (wf, hf) = (width as f64, height as f64);
        self.features
            .iter()
            .filter_map(|f| {
                let p_c = view.pose.world_to_camera(&f.p_w);
                // Behind the camera, or NaN.
                if p_c.z.is_nan() || p_c.z <= 0.0 {
                    return None;
                }
                let pixel = view
                    .pinhole
                    .to_pixel(Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z));
                let inside = pixel.x >= m
                    && pixel.y >= m
                    && pixel.x <= wf - 1.0 - m
                    && pixel.y <= hf - 1.0 - m;
                if !inside {
                    return None;
                }
                if let Some(frame) = rendering {
                    let (u, v) = (pixel.x.round() as u32, pixel.y.round() as u32);
                    let z = frame.depth_at(u, v)?;
                    if !(z > 0.0 && (z - p_c.z).abs() <= self.config.depth_tolerance * p_c.z) {
                        return None;
                    }
                }
                Some(Predicted {
                    id: f.id,
                    pixel,
                    z: p_c.z,
                })
            })
            .collect()
    }

    /// Whether new features should be extracted, given those predicted visible.
    pub fn needs_features(&self, visible: &[Predicted]) -> bool {
        visible.len() < self.config.min_visible
    }

    /// The extraction grid for a rendering: the configured cells, or, with
    /// [`MapConfig::small_object_cells`], for a small object wholly in view (its rendering
    /// covers less than [`SMALL_MODEL_SHARE`] of the image and touches no image border),
    /// smaller ones, so that its mask still holds about twice `min_visible` cells (down to
    /// [`MIN_CELL_SIZE`]). A scene that fills the view, or a model cut by the border, keeps the
    /// configured cells.
    pub fn grid_for(&self, mask: &image::GrayImage) -> GridConfig {
        let mut grid = self.config.grid;
        if !self.config.small_object_cells {
            return grid;
        }
        let model_px = mask.pixels().filter(|p| p.0[0] > 0).count() as f64;
        let image_px = f64::from(mask.width()) * f64::from(mask.height());
        let (w, h) = mask.dimensions();
        let on = |x: u32, y: u32| mask.get_pixel(x, y).0[0] > 0;
        let touches_border = (0..w).any(|x| on(x, 0) || on(x, h.saturating_sub(1)))
            || (0..h).any(|y| on(0, y) || on(w.saturating_sub(1), y));
        if model_px >= SMALL_MODEL_SHARE * image_px || touches_border {
            return grid;
        }
        let wanted = 2.0 * self.config.min_visible.max(1) as f64;
        let side = (model_px / wanted).sqrt().floor() as usize;
        grid.cell_size = grid.cell_size.min(side.max(MIN_CELL_SIZE));
        grid
    }

    /// Extracts FAST corners in the free cells of a rendering (cells not holding one of
    /// `occupied`, on the model's mask; [`Self::grid_for`]), back-projects them through the
    /// depth buffer and adds them. Returns the new ids.
    pub fn add_from_rendering(
        &mut self,
        frame: &Frame,
        occupied: &[[f64; 2]],
        frame_index: u64,
    ) -> Result<Vec<u64>, ImageError> {
        let mask = Mask::from_gray8(&frame.mask)?;
        let grid = self.grid_for(&frame.mask);
        let corners = grid::extract(&frame.gray, Some(&mask), occupied, &grid)?;
        let mut ids = Vec::with_capacity(corners.len());
        for c in corners {
            let Some(z) = frame.depth_at(c.x, c.y) else {
                continue;
            };
            let b = backproject(
                &frame.view,
                c.x as f64,
                c.y as f64,
                z,
                self.config.corner_sigma_px,
            );
            if b.p_w.iter().all(|v| v.is_finite()) {
                ids.push(self.insert(b.p_w, b.cov_w, frame_index));
            }
        }
        Ok(ids)
    }

    /// Records a registration attempt in frame `frame_index`; unknown ids are ignored.
    pub fn record(&mut self, id: u64, outcome: Outcome, frame_index: u64) {
        if let Some(f) = self.features.iter_mut().find(|f| f.id == id) {
            let s = &mut f.stats;
            s.attempts = s.attempts.saturating_add(1);
            match outcome {
                Outcome::Success => {
                    s.successes = s.successes.saturating_add(1);
                    s.consecutive_failures = 0;
                    s.last_success_frame = Some(frame_index);
                }
                Outcome::Failure(_) | Outcome::Outlier => {
                    s.consecutive_failures = s.consecutive_failures.saturating_add(1);
                }
            }
        }
    }

    /// Removes the features that fail too often; returns their ids.
    pub fn retire(&mut self) -> Vec<u64> {
        let c = self.config;
        let bad = |s: &FeatureStats| {
            s.consecutive_failures >= c.max_consecutive_failures
                || (s.attempts >= c.min_attempts
                    && (s.successes as f64) < c.min_success_ratio * s.attempts as f64)
        };
        let retired: Vec<u64> = self
            .features
            .iter()
            .filter(|f| bad(&f.stats))
            .map(|f| f.id)
            .collect();
        self.features.retain(|f| !bad(&f.stats));
        retired
    }

    /// Chooses up to `subset_size` of `visible`, spread over a `width × height` image: about
    /// `subset_size` cells, visited round-robin, each giving its best remaining feature (by
    /// [`FeatureStats::quality`], then lower id) per round; within a round cells with better
    /// candidates go first.
    pub fn select(&self, visible: &[Predicted], width: u32, height: u32) -> Vec<Predicted> {
        self.select_n(visible, width, height, self.config.subset_size)
    }

    /// As [`FeatureMap::select`], for `n` features: the order is the registration order, so a
    /// caller that wants `subset_size` *registered* features can take candidates from a longer
    /// list until enough succeeded.
    pub fn select_n(
        &self,
        visible: &[Predicted],
        width: u32,
        height: u32,
        n: usize,
    ) -> Vec<Predicted> {
        if n == 0 || visible.is_empty() {
            return Vec::new();
        }
        let (wf, hf) = (width.max(1) as f64, height.max(1) as f64);
        let cols = ((n as f64 * wf / hf).sqrt().ceil() as usize).max(1);
        let rows = n.div_ceil(cols).max(1);
        let quality = |p: &Predicted| self.get(p.id).map_or(0.0, |f| f.stats.quality());
        // Only the occupied cells, in row-major order: `n` sizes the grid, and a huge `n` must
        // not allocate for it (`--features 100000000000` asked for 2.4 TB).
        let mut cells: BTreeMap<(usize, usize), Vec<Predicted>> = BTreeMap::new();
        for p in visible {
            let c = ((p.pixel.x / wf * cols as f64).floor().max(0.0) as usize).min(cols - 1);
            let r = ((p.pixel.y / hf * rows as f64).floor().max(0.0) as usize).min(rows - 1);
            cells.entry((r, c)).or_default().push(*p);
        }
        for cell in cells.values_mut() {
            // Best last, so that `pop` takes it.
            cell.sort_by(|a, b| {
                quality(a)
                    .total_cmp(&quality(b))
                    .then_with(|| b.id.cmp(&a.id))
            });
        }
        let mut out = Vec::with_capacity(n.min(visible.len()));
        while out.len() < n {
            let mut round: Vec<Predicted> = cells.values_mut().filter_map(|c| c.pop()).collect();
            if round.is_empty() {
                break;
            }
            round.sort_by(|a, b| {
                quality(b)
                    .total_cmp(&quality(a))
                    .then_with(|| a.id.cmp(&b.id))
            });
            let take = (n - out.len()).min(round.len());
            out.extend(round.into_iter().take(take));
        }
        out
    }
}
