//! One camera frame through the host's image analysis (docs/ARCHITECTURE.md §3): undistort the live
//! image, render the model at the predicted pose, extract features on demand, select a spread
//! subset, register each with the photometric KLT, and turn the registered ones into
//! correspondences. The renderer and its GPU resources are created once.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use image::GrayImage;
use nalgebra::{Matrix2, UnitQuaternion, Vector2, Vector3};
use protocol::{ContourPoint, Correspondence, PosePrediction};
use rayon::prelude::*;

use camera::{Camera, CameraPose, UndistortMap};
use features::correspondence::correspondence;
use features::map::MapFeature;
use features::outliers::{Registration, outliers, robust_fit, within_noise};
use features::{
    FeatureMap, GrayF32, KltConfig, KltFailure, KltResult, MapConfig, Mask, Outcome, OutlierRule,
    Predicted, Pyramid, TemplatePyramid, register,
};
use model::Model;
use render::{RenderView, Renderer};

use crate::VisionError;
use crate::assess::{
    Assessment, Contrast, RegistrationCov, contrast, registration_chi2, reprojection_rms,
    textured_ncc,
};
use crate::contours::{ContourFrame, ContourState, Modality};

/// Image-analysis parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionOptions {
    /// Feature map management.
    pub map: MapConfig,
    /// Registration.
    pub klt: KltConfig,
    /// Anti-aliasing blur of the rendering, px (σ).
    pub blur_sigma: f32,
    /// Near and far clip distances, m.
    pub clip: (f64, f64),
    /// Exposure time of the live camera [s]: with the angular velocity it predicts each
    /// feature's motion blur, whose extent is added to the registered position's covariance.
    pub exposure: f64,
    /// Standard deviation of the registration error per pixel of blur extent.
    pub blur_sigma_per_px: f64,
    /// Registrations that no rigid pose explains with the frame's others are not sent
    /// (`None`: all are sent, the core's gate alone judges them).
    pub outliers: Option<OutlierRule>,
    /// Which measurements a frame makes: the texture's, the contour's, or both.
    pub modality: Modality,
    /// The contour modality's parameters.
    pub contour: contour::ContourConfig,
}

impl Default for VisionOptions {
    fn default() -> Self {
        Self {
            map: MapConfig::default(),
            klt: KltConfig::default(),
            blur_sigma: 1.0,
            clip: (0.05, 50.0),
            exposure: 0.008,
            blur_sigma_per_px: 0.5,
            outliers: Some(OutlierRule::default()),
            modality: Modality::Texture,
            contour: contour::ContourConfig::default(),
        }
    }
}

/// The live image of a frame to analyse.
#[derive(Debug, Clone)]
pub enum FrameImage {
    /// An image file (a EuRoC dataset's frame), read by the analysis.
    File(PathBuf),
    /// A frame already decoded (a video, a camera, an image folder), grey. The analysis takes
    /// the pixels, leaving an empty image in the result's job.
    Decoded(GrayImage),
}

impl FrameImage {
    /// What to name in an error about this image.
    fn describe(&self, index: usize) -> PathBuf {
        match self {
            FrameImage::File(p) => p.clone(),
            FrameImage::Decoded(_) => PathBuf::from(format!("frame {index}")),
        }
    }
}

/// A frame to analyse.
#[derive(Debug, Clone)]
pub struct FrameJob {
    /// Index of the frame in the dataset.
    pub index: usize,
    /// Time stamp of the image [ns].
    pub stamp: u64,
    /// The image.
    pub image: FrameImage,
    /// The core's prediction for the frame's trigger.
    pub prediction: PosePrediction,
    /// Keep the undistorted live image in the result (for an overlay).
    pub keep_image: bool,
    /// Angular velocity of the camera at the trigger, in the camera frame [rad/s] (from the
    /// core's state report), for the motion-blur term of the covariance.
    pub omega_c: Option<Vector3<f64>>,
}

/// What happened to one selected feature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureOutcome {
    /// Map id.
    pub id: u64,
    /// Predicted pixel (undistorted image).
    pub predicted: [f64; 2],
    /// Registered pixel, or why registration failed.
    pub registered: Result<[f64; 2], KltFailure>,
    /// Whether a correspondence was sent for it.
    pub sent: bool,
}

/// Time spent per stage [s].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Reading and undistorting the live image.
    pub load: f64,
    /// Rendering and read-back.
    pub render: f64,
    /// Visibility prediction, and feature extraction (FAST) when the map needed more.
    pub extract: f64,
    /// Template and live pyramids. The live one is built while the rendering is in flight
    /// and the template beside the extraction, so these times overlap `render` and `extract`.
    pub pyramids: f64,
    /// Registration of all selected features.
    pub klt: f64,
    /// The contour's lines.
    pub contour: f64,
    /// The whole frame.
    pub total: f64,
}

/// The analysis of one frame.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// The job.
    pub job: FrameJob,
    /// Map features predicted visible.
    pub visible: usize,
    /// Features added from this rendering.
    pub added: usize,
    /// Features retired after this frame.
    pub retired: usize,
    /// Per selected feature.
    pub features: Vec<FeatureOutcome>,
    /// The correspondences to send.
    pub correspondences: Vec<Correspondence>,
    /// The contour correspondences to send (after the correspondences).
    pub contours: Vec<ContourPoint>,
    /// What the contour's lines gave (all zero without the contour modality).
    pub contour_tally: contour::Tally,
    /// Mean distance predicted → registered, px (the paper's prediction error).
    pub prediction_error_px: Option<f64>,
    /// Mean distance along the normals between the predicted contour and the one found, px.
    pub contour_error_px: Option<f64>,
    /// Fraction of the image covered by the rendered model.
    pub model_coverage: f64,
    /// Stage timings.
    pub times: StageTimes,
    /// The undistorted live image, if the job asked for it.
    pub image: Option<GrayImage>,
    /// Pixels on the border of the model rendered at the prediction, if the job asked for the
    /// image (the overlay draws the model's outline from them).
    pub outline: Vec<[u32; 2]>,
    /// The frame judged at its prediction over every correspondence sent
    /// ([`Vision::process_judged`]; `None` from [`Vision::process`]): with an IMU, the
    /// prediction is the pose the core put out at the frame's time.
    pub at_prediction: Option<Assessment>,
}

/// Fewest registrations whose fit judges the contour's lines in a frame measuring both (the
/// registrations' own outlier rule judges from 8).
const TEXTURE_FIT_MIN: usize = 8;

/// Rounds of registration and re-fitting in [`Vision::verify`], at most: the first starts from a
/// pose a few pixels off, the second from one the registrations fit (unless the first re-fit
/// moved it no more than their noise, eq. V1).
const VERIFY_ROUNDS: usize = 2;

/// A pose verified by [`Vision::verify`].
#[derive(Debug, Clone)]
pub struct Verified {
    /// The pose re-fitted to the registrations.
    pub pose: CameraPose,
    /// The judgement there.
    pub assessment: Assessment,
    /// The last round's analysis (its prediction is the pose of the round before).
    pub result: Option<FrameResult>,
    /// The last round's registrations (registered pixel, model point): the evidence the pose
    /// was fitted to.
    pub registered: Vec<Registration>,
}

/// The last analysed frame, kept for [`Vision::assess`].
#[derive(Debug, Clone)]
struct LastFrame {
    live: GrayImage,
    /// Registered pixel and model point of each correspondence sent, in the order sent.
    registered: Vec<Registration>,
    /// Their covariances: the registration's [px²] and the model point's [m²].
    registered_cov: Vec<RegistrationCov>,
    /// The contour measurements sent, in the order sent (after the correspondences).
    contours: Vec<contour::ContourMeasurement>,
}

/// The host's image analysis, with its renderer and feature map.
pub struct Vision {
    camera: Camera,
    ideal: Camera,
    undistort: UndistortMap,
    renderer: Renderer,
    map: FeatureMap,
    options: VisionOptions,
    contour: ContourState,
    last: Option<LastFrame>,
    /// The last rendering (of a frame, an assessment or a contrast), whose buffers the next
    /// one fills.
    rendering: Option<render::Frame>,
    /// The live image a verification or a comparison last prepared: they look at one image
    /// again and again (each round of each verification of each candidate pose), and its
    /// undistortion and pyramid are the same every time.
    prepared: Option<PreparedLive>,
}

/// A raw live image, undistorted, and its pyramid for the KLT.
struct PreparedLive {
    raw: GrayImage,
    live: GrayImage,
    target: Arc<Pyramid>,
}

impl std::fmt::Debug for Vision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Vision")
            .field("camera", &self.camera)
            .field("map_features", &self.map.len())
            .finish()
    }
}

/// The view of the ideal camera `ideal` at `pose` between the clip planes `clip`.
fn render_view(ideal: &Camera, clip: (f64, f64), pose: &CameraPose) -> RenderView {
    RenderView {
        pinhole: ideal.pinhole,
        pose: *pose,
        near: clip.0,
        far: clip.1,
    }
}

/// The model rendered in the ideal camera `ideal` at `pose`, between the clip planes `clip`,
/// into `reuse`'s buffers when given (the tracker keeps its last rendering's).
fn render_at(
    renderer: &mut Renderer,
    ideal: &Camera,
    clip: (f64, f64),
    pose: &CameraPose,
    reuse: Option<render::Frame>,
) -> Result<render::Frame, VisionError> {
    let view = render_view(ideal, clip, pose);
    let mut frame = reuse.unwrap_or_else(|| render::Frame::empty_for_tracker(view));
    renderer.render_into(&view, &mut frame)?;
    Ok(frame)
}

/// The camera pose of a prediction.
pub fn prediction_pose(p: &PosePrediction) -> Result<CameraPose, VisionError> {
    let q = p.q_cw.map(f64::from);
    CameraPose::from_wxyz(
        q,
        Vector3::new(p.c_w[0] as f64, p.c_w[1] as f64, p.c_w[2] as f64),
    )
    .map_err(|source| VisionError::BadPrediction {
        frame_id: p.frame_id,
        source,
    })
}

impl Vision {
    /// Creates the renderer for `camera` and uploads `model`.
    pub fn new(camera: Camera, model: &Model, options: VisionOptions) -> Result<Self, VisionError> {
        let ideal = camera.ideal();
        let undistort = UndistortMap::new(&camera)?;
        let mut renderer = Renderer::new(camera.width, camera.height)?;
        renderer.set_model(model)?;
        Ok(Self {
            camera,
            ideal,
            undistort,
            renderer,
            map: FeatureMap::new(options.map),
            contour: ContourState::new(options.contour),
            options,
            last: None,
            rendering: None,
            prepared: None,
        })
    }

    /// Judges the last analysed frame at `pose`, the core's estimate after that frame's
    /// update: the reprojection rms there of the correspondences the core applied (`applied`,
    /// one flag per correspondence sent, in order, then one per contour correspondence; the
    /// gated ones are outliers it did not use), and the model rendered there against the live
    /// image ([`crate::assess`]): its correlation where the model has texture, its silhouette's
    /// agreement with the object's statistics where the frame measured the contour.
    pub fn assess(
        &mut self,
        pose: &CameraPose,
        applied: &[bool],
    ) -> Result<Assessment, VisionError> {
        if self.last.is_none() {
            return Ok(Assessment::default());
        }
        let rendering = self.rendering_at(pose)?;
        let Some(last) = &self.last else {
            return Ok(Assessment::default());
        };
        let points = last.registered.len();
        let (applied_points, applied_contours) = applied.split_at(points.min(applied.len()));
        let (used, used_cov): (Vec<Registration>, Vec<RegistrationCov>) = last
            .registered
            .iter()
            .zip(&last.registered_cov)
            .zip(applied_points)
            .filter(|(_, a)| **a)
            .map(|((r, c), _)| (*r, *c))
            .unzip();
        let (features, rms_px) = reprojection_rms(&self.ideal, pose, &used);
        let consistency = registration_chi2(&self.ideal, pose, &used, &used_cov);
        let (ncc_pixels, ncc) = textured_ncc(&rendering.gray, &last.live, &rendering.mask);
        let contour = if self.options.modality.contour() {
            let live = GrayF32::from_gray8(&last.live)?;
            self.contour.judge(
                &last.contours,
                applied_contours,
                pose,
                &self.ideal.pinhole,
                &rendering,
                &live,
            )
        } else {
            crate::contours::ContourJudgement::default()
        };
        self.rendering = Some(rendering);
        Ok(Assessment {
            features,
            rms_px,
            ncc,
            ncc_pixels,
            contours: contour.contours,
            contour_rms_px: contour.rms_px,
            contour_spread: contour.spread,
            contour_excess: contour.excess,
            silhouette: contour.silhouette,
            prediction_offset: None,
            weakest_sigma: None,
            consistency,
        })
    }

    /// How the live image `raw` tells the poses `a` and `b` apart: each rendering correlated
    /// with it where the two renderings disagree (eq. P2, [`crate::assess::contrast`]).
    pub fn contrast(
        &mut self,
        raw: &GrayImage,
        a: &CameraPose,
        b: &CameraPose,
    ) -> Result<Contrast, VisionError> {
        let live = self.prepared_live(raw)?.live.clone();
        let ra = self.rendering_at(a)?;
        let rb = render_at(&mut self.renderer, &self.ideal, self.options.clip, b, None)?;
        let c = contrast((&ra.gray, &ra.mask), (&rb.gray, &rb.mask), &live);
        self.rendering = Some(ra);
        Ok(c)
    }

    /// The live image of `raw` undistorted into the ideal camera the analysis works in.
    pub fn undistort(&self, raw: &GrayImage) -> Result<GrayImage, VisionError> {
        Ok(self.undistort.remap_gray(raw)?)
    }

    /// Verifies a pose found without a prediction (docs/notes/issue15-cold-start.md §5): with
    /// a fresh feature map, the model rendered at `pose` is registered in `raw` and the pose
    /// re-fitted to the registrations (eq. R1); once more from there; then the frame is judged
    /// at the re-fitted pose ([`Vision::assess`]). The map keeps the features of the last
    /// round, ready for tracking to go on from the verified pose.
    /// With `keep_image`, the last round's analysis keeps its image (for an overlay).
    pub fn verify(
        &mut self,
        raw: &GrayImage,
        pose: &CameraPose,
        keep_image: bool,
    ) -> Result<Verified, VisionError> {
        let mut pose = *pose;
        let mut registered = 0;
        let mut result = None;
        // The verification asks for more features than tracking does: a small object wholly
        // in view gets the cells to hold them in every run (inertial runs track on with their
        // own grid afterwards).
        let tracking = *self.map.config();
        let verifying = MapConfig {
            small_object_cells: true,
            ..tracking
        };
        for _ in 0..VERIFY_ROUNDS {
            self.map = FeatureMap::new(verifying);
            let q = pose.q_cw;
            let job = FrameJob {
                index: 0,
                stamp: 0,
                image: FrameImage::Decoded(raw.clone()),
                prediction: PosePrediction {
                    frame_id: 0,
                    t_us: 0,
                    c_w: [pose.c_w.x as f32, pose.c_w.y as f32, pose.c_w.z as f32],
                    q_cw: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
                    cov: [0.0; 21],
                },
                // Whichever round is the last keeps it (see the early stop below).
                keep_image,
                omega_c: None,
            };
            match self.process_with(job, true) {
                Ok(r) => result = Some(r),
                Err(e) => {
                    self.map.set_config(tracking);
                    return Err(e);
                }
            }
            let Some(last) = &self.last else { break };
            registered = last.registered.len();
            // Too few registrations to re-fit a pose (and none at all would leave the robust
            // fit's median without values): judged where it is.
            if registered < 6 {
                break;
            }
            match robust_fit(&self.ideal, &pose, &last.registered) {
                Some((fitted, _)) => {
                    // A re-fit the registrations cannot tell from where it started (eq. V1):
                    // another round would move it by their noise only.
                    let settled = within_noise(&self.ideal, &pose, &fitted, &last.registered);
                    pose = fitted;
                    if settled {
                        break;
                    }
                }
                None => break,
            }
        }
        self.map.set_config(tracking);
        let applied = vec![true; registered];
        let assessment = self.assess(&pose, &applied)?;
        Ok(Verified {
            pose,
            assessment,
            result,
            registered: self
                .last
                .as_ref()
                .map_or_else(Vec::new, |l| l.registered.clone()),
        })
    }

    /// The renderer's adapter, for reports.
    pub fn adapter_summary(&self) -> String {
        self.renderer.adapter_summary()
    }

    /// The feature map.
    pub fn map(&self) -> &FeatureMap {
        &self.map
    }

    /// The ideal (undistorted) camera the analysis works in.
    pub fn ideal_camera(&self) -> &Camera {
        &self.ideal
    }

    /// Covariance [px²] of the registration error caused by motion blur at `pixel`: the image
    /// motion of a rotating camera (the rotational part of the image Jacobian) over the
    /// exposure, `b`, gives `σ² b bᵀ / |b|²·(k|b|)²`, i.e. a spread of `k|b|` along the blur.
    fn blur_covariance(
        &self,
        omega_c: Option<&Vector3<f64>>,
        pixel: &Vector2<f64>,
    ) -> Matrix2<f64> {
        let Some(w) = omega_c else {
            return Matrix2::zeros();
        };
        let pin = &self.ideal.pinhole;
        let n = pin.to_normalised(*pixel);
        let (x, y) = (n.x, n.y);
        // ṅ = ω × n for a point fixed in the world seen from a rotating camera (sign is
        // irrelevant here: only b bᵀ is used).
        let nx = x * y * w.x - (1.0 + x * x) * w.y + y * w.z;
        let ny = (1.0 + y * y) * w.x - x * y * w.y - x * w.z;
        let b = Vector2::new(pin.fx * nx, pin.fy * ny) * self.options.exposure;
        let k = self.options.blur_sigma_per_px;
        b * b.transpose() * (k * k)
    }

    /// Step 1 of [`Self::process`]: the job's live image, read or taken, at the camera's size.
    fn read_live(&self, job: &mut FrameJob) -> Result<GrayImage, VisionError> {
        let raw = match &mut job.image {
            FrameImage::File(path) => camera::read_frame(&*path)
                .map_err(|source| VisionError::Image {
                    path: path.clone(),
                    source,
                })?
                .into_luma8(),
            FrameImage::Decoded(image) => std::mem::take(image),
        };
        if raw.dimensions() != (self.camera.width, self.camera.height) {
            return Err(VisionError::ImageSize {
                path: job.image.describe(job.index),
                got: raw.dimensions(),
                expected: (self.camera.width, self.camera.height),
            });
        }
        Ok(raw)
    }

    /// The last step of [`Self::process`]'s registration: the registrations judged together
    /// (the outlier rule), each outcome recorded in the feature map, and the accepted ones
    /// turned into correspondences (with the motion blur's covariance at `omega_c`). Fills
    /// the frame's feature outcomes, correspondences and registrations; returns the sum and
    /// count of the registrations' distances from their predictions [px].
    fn record_attempts(
        &mut self,
        attempts: Vec<Attempt<'_>>,
        pose: &CameraPose,
        omega_c: Option<&Vector3<f64>>,
        frame_index: u64,
        (features, correspondences, registered, registered_cov): (
            &mut Vec<FeatureOutcome>,
            &mut Vec<Correspondence>,
            &mut Vec<Registration>,
            &mut Vec<RegistrationCov>,
        ),
    ) -> (f64, usize) {
        let mut error_sum = 0.0;
        let mut error_count = 0usize;
        let pairs: Vec<Registration> = attempts
            .iter()
            .filter_map(|(_, f, r)| {
                let r = r.as_ref().ok()?;
                Some((Vector2::new(r.position[0], r.position[1]), f.p_w))
            })
            .collect();
        let mut outlier = match &self.options.outliers {
            Some(rule) => outliers(&self.ideal, pose, &pairs, rule),
            None => vec![false; pairs.len()],
        }
        .into_iter();
        for (p, feature, result) in attempts {
            let position = [p.pixel.x, p.pixel.y];
            let outcome = match result {
                Ok(r) => {
                    let px = Vector2::new(r.position[0], r.position[1]);
                    error_sum += (px - p.pixel).norm();
                    error_count += 1;
                    let sent = if outlier.next().unwrap_or(false) {
                        self.map.record(p.id, Outcome::Outlier, frame_index);
                        false
                    } else {
                        self.map.record(p.id, Outcome::Success, frame_index);
                        let cov: Matrix2<f64> =
                            r.covariance + self.blur_covariance(omega_c, &p.pixel);
                        match correspondence(&self.ideal, px, &cov, &feature.p_w, &feature.cov_w) {
                            Ok(c) => {
                                correspondences.push(c);
                                registered.push((px, feature.p_w));
                                registered_cov.push((cov, feature.cov_w));
                                true
                            }
                            Err(_) => false,
                        }
                    };
                    FeatureOutcome {
                        id: p.id,
                        predicted: position,
                        registered: Ok(r.position),
                        sent,
                    }
                }
                Err(why) => {
                    self.map.record(p.id, Outcome::Failure(why), frame_index);
                    FeatureOutcome {
                        id: p.id,
                        predicted: position,
                        registered: Err(why),
                        sent: false,
                    }
                }
            };
            features.push(outcome);
        }
        (error_sum, error_count)
    }

    /// Step of [`Self::process`]: new features extracted from the rendering where the map
    /// needs them (FAST on demand) beside the template pyramid, which is built whenever the
    /// model is in view; both read only the rendering, so they run side by side (rayon).
    /// Returns the features added, the extraction's time [s], and the template with its time.
    #[allow(clippy::type_complexity)]
    fn extract_beside_template(
        &mut self,
        visible: &[Predicted],
        rendering: &render::Frame,
        model_coverage: f64,
        frame_index: u64,
        blur: TemplateBlur,
    ) -> Result<(usize, f64, Option<(TemplatePyramid, f64)>), VisionError> {
        let extract = self.map.needs_features(visible) && model_coverage > 0.0;
        let levels = self.options.klt.levels;
        let map = &mut self.map;
        let (extraction, template) = rayon::join(
            || -> Result<(usize, f64), VisionError> {
                let t = Instant::now();
                if !extract {
                    return Ok((0, 0.0));
                }
                let occupied: Vec<[f64; 2]> =
                    visible.iter().map(|p| [p.pixel.x, p.pixel.y]).collect();
                let added = map
                    .add_from_rendering(rendering, &occupied, frame_index)?
                    .len();
                Ok((added, t.elapsed().as_secs_f64()))
            },
            || -> Result<Option<(TemplatePyramid, f64)>, VisionError> {
                if model_coverage == 0.0 {
                    return Ok(None);
                }
                let t = Instant::now();
                let template = build_template(rendering, levels, blur)?;
                Ok(Some((template, t.elapsed().as_secs_f64())))
            },
        );
        let (added, extracting) = extraction?;
        Ok((added, extracting, template?))
    }

    /// The model rendered at `pose`: the last rendering itself where it shows that view,
    /// rendered into its buffers otherwise.
    fn rendering_at(&mut self, pose: &CameraPose) -> Result<render::Frame, VisionError> {
        let (ideal, clip) = (&self.ideal, self.options.clip);
        match self.rendering.take() {
            Some(f) if f.shows(&render_view(ideal, clip, pose)) => Ok(f),
            reuse => render_at(&mut self.renderer, ideal, clip, pose, reuse),
        }
    }

    /// Step of [`Self::process`]: the rendering at `view` submitted first, so that the driver
    /// rasterises on its threads while this one undistorts the live image `raw` and builds its
    /// pyramid (which needs no rendering); then the rendering read back into the previous
    /// frame's buffers (no fresh pages to fault in). Fills the load, pyramid and render times.
    /// With `reuse_live`, the live image and its pyramid are [`Self::prepared_live`]'s.
    fn render_beside_live(
        &mut self,
        raw: &GrayImage,
        view: RenderView,
        reuse_live: bool,
        t0: Instant,
        times: &mut StageTimes,
    ) -> Result<(GrayImage, Arc<Pyramid>, render::Frame), VisionError> {
        // The last rendering is this view's when a verification repeats from the pose it
        // judged, or a judgement renders where the analysis did: kept, not rendered again.
        let (kept, current) = match self.rendering.take() {
            Some(f) if f.shows(&view) => (Some(f), true),
            other => (other, false),
        };
        let t = Instant::now();
        if !current {
            self.renderer.submit(&view)?;
        }
        let submitted = t.elapsed();
        let (live, target) = if reuse_live {
            let prepared = self.prepared_live(raw)?;
            (prepared.live.clone(), prepared.target.clone())
        } else {
            let live = self.undistort.remap_gray(raw)?;
            times.load = (t0.elapsed() - submitted).as_secs_f64();
            let t = Instant::now();
            let target = self.options.klt.target_pyramid(GrayF32::from_gray8(&live)?);
            times.pyramids = t.elapsed().as_secs_f64();
            (live, Arc::new(target))
        };
        let t = Instant::now();
        let rendering = match kept {
            Some(f) if current => f,
            other => {
                let mut r = other.unwrap_or_else(|| render::Frame::empty_for_tracker(view));
                self.renderer.finish_into(&mut r)?;
                r
            }
        };
        times.render = (submitted + t.elapsed()).as_secs_f64();
        Ok((live, target, rendering))
    }

    /// The live image `raw` undistorted, with its pyramid: the ones kept from the last call
    /// where `raw` is the same image (a verification's rounds, the poses of one attempt),
    /// made and kept otherwise.
    fn prepared_live(&mut self, raw: &GrayImage) -> Result<&PreparedLive, VisionError> {
        let prepared = match self.prepared.take() {
            Some(p) if p.raw == *raw => p,
            _ => {
                let live = self.undistort.remap_gray(raw)?;
                let target = self.options.klt.target_pyramid(GrayF32::from_gray8(&live)?);
                PreparedLive {
                    raw: raw.clone(),
                    live,
                    target: Arc::new(target),
                }
            }
        };
        Ok(self.prepared.insert(prepared))
    }

    /// Analyses one frame: the texture's registrations and the contour's lines, as the
    /// options' modality says.
    pub fn process(&mut self, job: FrameJob) -> Result<FrameResult, VisionError> {
        self.process_with(job, false)
    }

    /// [`Self::process`], and the frame's prediction judged over every correspondence sent:
    /// the judgement of the pose put out at the frame's time where an IMU carries the pose
    /// between frames (docs/VISION.md §10). With enough registrations the frame is judged at
    /// the pose they fit from the prediction, and the prediction's offset from it is kept
    /// (eq. T4); with too few, at the prediction (its contour form, with the analysis's
    /// rendering).
    pub fn process_judged(&mut self, job: FrameJob) -> Result<FrameResult, VisionError> {
        let mut result = self.process_with(job, false)?;
        let prediction = prediction_pose(&result.job.prediction)?;
        let sent = vec![true; result.correspondences.len() + result.contours.len()];
        // The frame judged at the pose its registrations fit (as vision-only at the pose
        // estimated with them), and the prediction held to that pose (eq. T4). Rendered at
        // the prediction instead, a right prediction 5-6 px off (the gyro model's, 1 cm from
        // the truth) correlated at 0.22-0.29 and failed.
        let fit = self
            .last
            .as_ref()
            .filter(|l| l.registered.len() >= TEXTURE_FIT_MIN)
            .and_then(|l| robust_fit(&self.ideal, &prediction, &l.registered))
            .map(|(p, _)| p);
        let mut a = self.assess(fit.as_ref().unwrap_or(&prediction), &sent)?;
        a.prediction_offset = fit.map(|f| {
            [
                (f.c_w - prediction.c_w).norm(),
                f.q_cw.angle_to(&prediction.q_cw),
            ]
        });
        result.at_prediction = Some(a);
        Ok(result)
    }

    /// [`Self::process`], the live image and its pyramid [`Self::prepared_live`]'s with
    /// `reuse_live`.
    fn process_with(
        &mut self,
        mut job: FrameJob,
        reuse_live: bool,
    ) -> Result<FrameResult, VisionError> {
        let t0 = Instant::now();
        let mut times = StageTimes::default();
        self.last = None;
        let raw = self.read_live(&mut job)?;
        let pose = prediction_pose(&job.prediction)?;
        let view = render_view(&self.ideal, self.options.clip, &pose);
        let (live, target, rendering) =
            self.render_beside_live(&raw, view, reuse_live, t0, &mut times)?;
        let (w, h) = (self.camera.width, self.camera.height);
        let model_coverage = rendering.mask.as_raw().iter().filter(|&&v| v > 0).count() as f64
            / (w as f64 * h as f64);
        let texture = if self.options.modality.texture() {
            self.texture_step(&job, view, &rendering, &target, model_coverage, &mut times)?
        } else {
            TextureStep::default()
        };
        let contours = if self.options.modality.contour() && model_coverage > 0.0 {
            let t = Instant::now();
            let live_f = target.level(0).ok_or(features::ImageError::BadSize {
                width: 0,
                height: 0,
            })?;
            // With the texture measured too, the pose its registrations fit judges the lines.
            let texture_pose = (texture.registered.len() >= TEXTURE_FIT_MIN)
                .then(|| robust_fit(&self.ideal, &pose, &texture.registered))
                .flatten()
                .map(|(p, _)| p);
            let c = self.contour.measure(
                &rendering,
                live_f,
                &self.ideal.pinhole,
                &job.prediction,
                self.options.outliers.as_ref(),
                texture_pose.as_ref(),
            );
            times.contour = t.elapsed().as_secs_f64();
            c
        } else {
            ContourFrame::default()
        };
        let outline = if job.keep_image {
            mask_outline(&rendering.mask)
        } else {
            Vec::new()
        };
        // The live image stays for the judgement; only an overlay's frame needs a copy.
        let image = job.keep_image.then(|| live.clone());
        self.last = Some(LastFrame {
            live,
            registered: texture.registered,
            registered_cov: texture.registered_cov,
            contours: contours.measurements,
        });
        self.rendering = Some(rendering);
        times.total = t0.elapsed().as_secs_f64();
        Ok(FrameResult {
            visible: texture.visible,
            added: texture.added,
            retired: texture.retired,
            features: texture.features,
            correspondences: texture.correspondences,
            contours: contours.wire,
            contour_tally: contours.tally,
            prediction_error_px: (texture.error_count > 0)
                .then(|| texture.error_sum / texture.error_count as f64),
            contour_error_px: contours.error_px,
            model_coverage,
            times,
            image,
            outline,
            at_prediction: None,
            job,
        })
    }

    /// The texture's part of [`Self::process`]: the map's visible features, new ones where it
    /// needs them, a spread subset registered with the KLT until enough succeeded, the
    /// outliers dropped, the rest made correspondences. Fills the extract, pyramid and KLT
    /// times.
    fn texture_step(
        &mut self,
        job: &FrameJob,
        view: RenderView,
        rendering: &render::Frame,
        target: &Pyramid,
        model_coverage: f64,
        times: &mut StageTimes,
    ) -> Result<TextureStep, VisionError> {
        let klt = &self.options.klt;
        let (w, h) = (self.camera.width, self.camera.height);
        let frame_index = job.index as u64;
        let t = Instant::now();
        let mut visible = self.map.predict_visible(&view, w, h, Some(rendering));
        let predicted = t.elapsed().as_secs_f64();
        let blur = TemplateBlur {
            antialias: self.options.blur_sigma,
            klt: *klt,
        };
        let levels = klt.levels;
        let (added, extracting, template) =
            self.extract_beside_template(&visible, rendering, model_coverage, frame_index, blur)?;
        let template = template.map(|(template, took)| {
            times.pyramids += took;
            template
        });
        let t = Instant::now();
        if added > 0 {
            visible = self.map.predict_visible(&view, w, h, Some(rendering));
        }
        times.extract = predicted + extracting + t.elapsed().as_secs_f64();
        // Candidates in registration order; registration stops once `subset_size` succeeded
        // (a failing feature does not cost the frame a correspondence).
        let cfg = self.map.config();
        let wanted = cfg.subset_size;
        let selected = self.map.select_n(
            &visible,
            w,
            h,
            cfg.max_candidates.min(2 * wanted + 4).max(wanted),
        );
        let mut out = TextureStep {
            visible: visible.len(),
            added,
            ..TextureStep::default()
        };
        if !selected.is_empty() {
            let t = Instant::now();
            let template = match template {
                Some(template) => template,
                None => build_template(rendering, levels, blur)?,
            };
            times.pyramids += t.elapsed().as_secs_f64();

            let t = Instant::now();
            let candidates: Vec<(&Predicted, MapFeature)> = selected
                .iter()
                .filter_map(|p| Some((p, self.map.get(p.id).copied()?)))
                .collect();
            let attempts =
                register_until(&candidates, wanted, &template, target, &self.options.klt);
            (out.error_sum, out.error_count) = self.record_attempts(
                attempts,
                &view.pose,
                job.omega_c.as_ref(),
                frame_index,
                (
                    &mut out.features,
                    &mut out.correspondences,
                    &mut out.registered,
                    &mut out.registered_cov,
                ),
            );
            times.klt = t.elapsed().as_secs_f64();
        }
        out.retired = self.map.retire().len();
        Ok(out)
    }
}

/// What [`Vision::texture_step`] gave a frame.
#[derive(Debug, Default)]
struct TextureStep {
    visible: usize,
    added: usize,
    retired: usize,
    features: Vec<FeatureOutcome>,
    correspondences: Vec<Correspondence>,
    registered: Vec<Registration>,
    /// Their covariances, as [`LastFrame::registered_cov`].
    registered_cov: Vec<RegistrationCov>,
    /// Sum and count of the registrations' distances from their predictions [px].
    error_sum: f64,
    error_count: usize,
}

/// One registration attempt: the predicted feature, its map entry and the KLT's answer.
type Attempt<'a> = (&'a Predicted, MapFeature, Result<KltResult, KltFailure>);

/// Registers `candidates` in order until `wanted` succeeded. The registrations are
/// independent: they run in parallel (rayon) in batches of the successes still missing, and
/// the attempts are kept in order up to the one that completes `wanted`, so the result is the
/// sequential one whatever the threads.
fn register_until<'a>(
    candidates: &[(&'a Predicted, MapFeature)],
    wanted: usize,
    template: &TemplatePyramid,
    target: &Pyramid,
    klt: &KltConfig,
) -> Vec<Attempt<'a>> {
    let mut attempts: Vec<Attempt<'a>> = Vec::with_capacity(candidates.len());
    let mut succeeded = 0usize;
    let mut next = 0usize;
    while succeeded < wanted && next < candidates.len() {
        let batch = &candidates[next..(next + wanted - succeeded).min(candidates.len())];
        next += batch.len();
        let results: Vec<Result<KltResult, KltFailure>> = batch
            .par_iter()
            .map(|(p, _)| {
                register(
                    &template.image,
                    Some(&template.mask),
                    target,
                    [p.pixel.x, p.pixel.y],
                    [0.0, 0.0],
                    klt,
                )
            })
            .collect();
        for ((p, feature), result) in batch.iter().zip(results) {
            if succeeded >= wanted {
                break;
            }
            succeeded += usize::from(result.is_ok());
            attempts.push((p, *feature, result));
        }
    }
    attempts
}

/// How a template is blurred: the rendering's anti-aliasing σ [px], and the registration's
/// settings (its smoothing σ; with its clip levels, the image between the two is kept for
/// the clipped prediction, docs/VISION.md eq. 5.6).
#[derive(Debug, Clone, Copy)]
struct TemplateBlur {
    antialias: f32,
    klt: KltConfig,
}

/// The rendering `frame` prepared for registration: blurred by `blur`, `levels` levels of
/// image and mask.
fn build_template(
    frame: &render::Frame,
    levels: usize,
    blur: TemplateBlur,
) -> Result<TemplatePyramid, VisionError> {
    let (image, mask) = (
        GrayF32::from_gray8(&frame.gray)?,
        Mask::from_gray8(&frame.mask)?,
    );
    let klt = &blur.klt;
    Ok(match klt.saturation {
        Some(_) => TemplatePyramid::build_keeping_unsmoothed(
            image,
            mask,
            levels,
            blur.antialias,
            klt.smoothing,
        ),
        None => TemplatePyramid::build(image, mask, levels, klt.template_sigma(blur.antialias)),
    }?)
}

/// Mask pixels with a 4-neighbour outside the mask (or on the image border).
fn mask_outline(mask: &GrayImage) -> Vec<[u32; 2]> {
    let (w, h) = mask.dimensions();
    let on = |x: i64, y: i64| {
        x >= 0
            && y >= 0
            && x < w as i64
            && y < h as i64
            && mask.get_pixel(x as u32, y as u32).0[0] > 0
    };
    let mut out = Vec::new();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            if on(x, y) && !(on(x - 1, y) && on(x + 1, y) && on(x, y - 1) && on(x, y + 1)) {
                out.push([x as u32, y as u32]);
            }
        }
    }
    out
}

/// Camera pose of a prediction as position and `q_wc` (camera → world), for trajectories.
pub fn camera_in_world(p: &PosePrediction) -> Option<(Vector3<f64>, UnitQuaternion<f64>)> {
    let pose = prediction_pose(p).ok()?;
    Some((pose.c_w, pose.q_cw.inverse()))
}
