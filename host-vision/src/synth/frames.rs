//! Live frames: the scene rendered from the ground-truth camera pose, then made real.
//!
//! Per frame: several sub-frames along the trajectory over the exposure are rendered (ideal
//! pinhole, supersampled, with a margin wide enough for the lens distortion) and averaged
//! (motion blur); occluders are composited by depth; the average is resampled through the
//! lens distortion with 2×2 samples per output pixel (pixel-area integration), so the host
//! must undistort; then lighting (gain, offset, spatial gradient) and sensor noise (read +
//! shot) are applied and the result is quantised to 8 bits.

use firmware_sim::sim::scenario::{LightState, Scenario};
use image::GrayImage;
use nalgebra::Vector2;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

use super::SynthError;
use super::scene::SceneModels;
use super::shading::Shading;
use crate::camera::{Camera, CameraPose, Distortion, Pinhole};
use crate::model::Model;
use crate::render::{Frame, RenderView, Renderer};

/// How live frames are made.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameOptions {
    /// Output width [px].
    pub width: u32,
    /// Output height [px].
    pub height: u32,
    /// Render supersampling factor per axis (1–4).
    pub supersample: u32,
    /// Fewest sub-frames averaged over the exposure (1 with `max_subframes` ≤ 1: no motion
    /// blur).
    pub subframes: u32,
    /// Most sub-frames: fast frames get more, so that the image moves by at most about one
    /// pixel between sub-frames and the blur is smooth rather than a set of ghosts.
    pub max_subframes: u32,
    /// Apply the scenario's lighting (off: the live image has the model's values).
    pub lighting: bool,
    /// Read noise [grey levels]; 0 with `shot_noise` 0 for noise-free frames.
    pub read_noise: f64,
    /// Shot noise: variance per grey level of signal.
    pub shot_noise: f64,
    /// Lit, shaded surfaces (a directional and an ambient light); `None`: the model's values
    /// unlit, as the renderer draws them.
    pub shading: Option<Shading>,
}

impl FrameOptions {
    /// Defaults: 320×240, 2× supersampling, 4 to 32 sub-frames, lighting and noise on.
    pub fn new(width: u32, height: u32) -> Self {
        FrameOptions {
            width,
            height,
            supersample: 2,
            subframes: 4,
            max_subframes: 32,
            lighting: true,
            read_noise: 1.5,
            shot_noise: 0.04,
            shading: None,
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |what: String| Err(SynthError::BadOption(what));
        if !(1..=4).contains(&self.supersample) {
            return bad(format!(
                "supersample must be 1..=4, got {}",
                self.supersample
            ));
        }
        if !(1..=64).contains(&self.subframes) || self.max_subframes > 64 {
            return bad(format!(
                "sub-frames must be 1..=64, got {} (most {})",
                self.subframes, self.max_subframes
            ));
        }
        if !(16..=4096).contains(&self.width) || !(16..=4096).contains(&self.height) {
            return bad(format!(
                "resolution must be 16..=4096 per side, got {}x{}",
                self.width, self.height
            ));
        }
        let noise_ok = |v: f64| v.is_finite() && (0.0..=100.0).contains(&v);
        if !noise_ok(self.read_noise) || !noise_ok(self.shot_noise) {
            return bad(format!(
                "noise must be in [0, 100], got read {} shot {}",
                self.read_noise, self.shot_noise
            ));
        }
        Ok(())
    }

    /// Without motion blur, lighting or noise (geometry checks).
    pub fn clean(width: u32, height: u32) -> Self {
        FrameOptions {
            subframes: 1,
            max_subframes: 1,
            lighting: false,
            read_noise: 0.0,
            shot_noise: 0.0,
            ..Self::new(width, height)
        }
    }
}

/// One synthetic live frame.
#[derive(Debug, Clone)]
pub struct SynthFrame {
    /// The 8-bit distorted image.
    pub image: GrayImage,
    /// Share of the image where the model is visible (not occluded), mid-exposure.
    pub model_coverage: f64,
    /// Share of the image covered by occluders, mid-exposure.
    pub occluder_coverage: f64,
    /// Share of the model's own pixels that no occluder hides, mid-exposure (`None` where the
    /// model is out of view): how much of it a tracker can see.
    pub model_unoccluded: Option<f64>,
    /// Lighting applied.
    pub light: LightState,
}

/// The live camera of a scenario for a given image size.
pub fn live_camera(scenario: &Scenario, width: u32, height: u32) -> Result<Camera, SynthError> {
    let p = scenario.camera.pinhole_for(width, height);
    let [k1, k2, p1, p2] = scenario.camera.distortion;
    Ok(Camera::new(
        width,
        height,
        Pinhole::new(p.fx, p.fy, p.cx, p.cy),
        Distortion::RadTan {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        },
    )?)
}

/// One rendering of the live world, occluders composited, at the render size.
struct LiveRender {
    /// Grey values.
    gray: Vec<f32>,
    /// Camera-frame depth [m], 0 on background.
    depth: Vec<f32>,
    /// Where an occluder is in front.
    occluded: Vec<bool>,
}

/// Makes live frames for one scenario.
pub struct FrameSynth {
    options: FrameOptions,
    camera: Camera,
    render_pinhole: Pinhole,
    render_size: (u32, u32),
    clip: (f64, f64),
    live: Renderer,
    model: Renderer,
    occluder: Option<(Renderer, Vec<Model>, usize)>,
    /// Render-image coordinates of the 2×2 samples of every output pixel (NaN: none).
    samples: Vec<[f32; 2]>,
    /// Nearest render pixel of every output pixel's centre (for coverage), if any.
    centres: Vec<Option<usize>>,
    accum: Vec<f32>,
}

impl FrameSynth {
    /// Sets up renderers and the distortion map.
    pub fn new(
        scenario: &Scenario,
        models: &SceneModels,
        options: FrameOptions,
    ) -> Result<Self, SynthError> {
        options.validate()?;
        let camera = live_camera(scenario, options.width, options.height)?;
        let (w, h) = (options.width as f64, options.height as f64);
        // Ideal pixels of the distorted image's border: how far the render must reach.
        let (mut lo, mut hi) = (Vector2::new(0.0, 0.0), Vector2::new(w - 1.0, h - 1.0));
        let border = (0..=options.width)
            .flat_map(|u| [(u as f64 - 0.5, -0.5), (u as f64 - 0.5, h - 0.5)])
            .chain(
                (0..=options.height)
                    .flat_map(|v| [(-0.5, v as f64 - 0.5), (w - 0.5, v as f64 - 0.5)]),
            );
        for (u, v) in border {
            let ideal = camera.undistort_pixel(Vector2::new(u, v)).ok_or_else(|| {
                SynthError::BadOption(format!(
                    "the lens distortion cannot be inverted at pixel ({u}, {v})"
                ))
            })?;
            lo = lo.inf(&ideal);
            hi = hi.sup(&ideal);
        }
        let s = options.supersample as f64;
        let ml = (-lo.x).max(0.0).ceil() + 2.0;
        let mt = (-lo.y).max(0.0).ceil() + 2.0;
        let mr = (hi.x - (w - 1.0)).max(0.0).ceil() + 2.0;
        let mb = (hi.y - (h - 1.0)).max(0.0).ceil() + 2.0;
        let render_size = ((s * (w + ml + mr)) as u32, (s * (h + mt + mb)) as u32);
        let k = camera.pinhole;
        // Output ideal pixel p sits at render pixel s (p + margin + ½) − ½ (pixel centres).
        let render_pinhole = Pinhole::new(
            s * k.fx,
            s * k.fy,
            s * (k.cx + ml + 0.5) - 0.5,
            s * (k.cy + mt + 0.5) - 0.5,
        );
        let to_render = |p: Vector2<f64>| -> Option<Vector2<f64>> {
            camera
                .pixel_to_normalised(p)
                .map(|n| render_pinhole.to_pixel(n))
        };
        let mut samples = Vec::with_capacity((options.width * options.height * 4) as usize);
        let mut centres = Vec::with_capacity((options.width * options.height) as usize);
        let (rw, rh) = (render_size.0 as f64, render_size.1 as f64);
        let inside =
            |r: &Vector2<f64>| r.x >= 0.0 && r.y >= 0.0 && r.x <= rw - 1.0 && r.y <= rh - 1.0;
        for v in 0..options.height {
            for u in 0..options.width {
                for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let r = to_render(Vector2::new(u as f64 + du, v as f64 + dv))
                        .filter(inside)
                        .map_or([f32::NAN; 2], |r| [r.x as f32, r.y as f32]);
                    samples.push(r);
                }
                centres.push(
                    to_render(Vector2::new(u as f64, v as f64))
                        .filter(inside)
                        .map(|r| {
                            r.y.round() as usize * render_size.0 as usize + r.x.round() as usize
                        }),
                );
            }
        }
        let mut live = Renderer::new(render_size.0, render_size.1)?;
        live.set_model(&models.live)?;
        let mut model = Renderer::new(render_size.0, render_size.1)?;
        model.set_model(&models.model)?;
        let occluder = if models.occluders.is_empty() {
            None
        } else {
            let mut r = Renderer::new(render_size.0, render_size.1)?;
            r.set_model(&models.occluders[0])?;
            Some((r, models.occluders.clone(), 0))
        };
        Ok(FrameSynth {
            options,
            camera,
            render_pinhole,
            render_size,
            clip: scenario.scene.clip,
            live,
            model,
            occluder,
            samples,
            centres,
            accum: vec![0.0; (render_size.0 * render_size.1) as usize],
        })
    }

    /// The live camera (intrinsics and distortion as written to `sensor.yaml`).
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Render size `(width, height)` including margins and supersampling.
    pub fn render_size(&self) -> (u32, u32) {
        self.render_size
    }

    /// The renderer's adapter.
    pub fn adapter_summary(&self) -> String {
        self.live.adapter_summary()
    }

    fn view(&self, pose: CameraPose) -> RenderView {
        RenderView {
            pinhole: self.render_pinhole,
            pose,
            near: self.clip.0,
            far: self.clip.1,
        }
    }

    /// Renders the live world at `t`: gray values and depth with occluders composited, and
    /// the occluder mask.
    fn render_live(&mut self, scenario: &Scenario, t: f64) -> Result<LiveRender, SynthError> {
        let (c_w, q_cw) = scenario.camera_pose(t);
        let view = self.view(CameraPose { q_cw, c_w });
        let live = self.live.render(&view)?;
        let mut gray: Vec<f32> = live.gray.as_raw().iter().map(|&g| g as f32).collect();
        let mut depth = live.depth.into_raw();
        let mut occluded = vec![false; gray.len()];
        if let Some((renderer, models, current)) = &mut self.occluder {
            for (j, occ) in scenario
                .scene
                .occluders
                .iter()
                .enumerate()
                .take(models.len())
            {
                let (r_wo, o_w) = occ.pose_at(t);
                // The camera seen from the occluder's frame: same image, occluder at rest.
                let pose = CameraPose {
                    q_cw: q_cw * r_wo,
                    c_w: r_wo.inverse() * (c_w - o_w),
                };
                if *current != j {
                    renderer.set_model(&models[j])?;
                    *current = j;
                }
                let view = RenderView {
                    pinhole: self.render_pinhole,
                    pose,
                    near: self.clip.0,
                    far: self.clip.1,
                };
                let f: Frame = renderer.render(&view)?;
                for (i, &z) in f.depth.as_raw().iter().enumerate() {
                    if z > 0.0 && (depth[i] <= 0.0 || z < depth[i]) {
                        depth[i] = z;
                        gray[i] = f.gray.as_raw()[i] as f32;
                        occluded[i] = true;
                    }
                }
            }
        }
        Ok(LiveRender {
            gray,
            depth,
            occluded,
        })
    }

    /// The live frame triggered at `t` (exposure centred on `t`).
    pub fn frame(
        &mut self,
        scenario: &Scenario,
        t: f64,
        rng: &mut StdRng,
    ) -> Result<SynthFrame, SynthError> {
        let exposure = scenario.camera.exposure;
        let n = self.subframe_count(scenario, t, exposure);
        self.accum.iter_mut().for_each(|a| *a = 0.0);
        let mid = n / 2;
        let (mut model_coverage, mut occluder_coverage, mut model_unoccluded) = (0.0, 0.0, None);
        for i in 0..n {
            // Mid-points of n equal slots of the exposure.
            let ts = t + exposure * ((i as f64 + 0.5) / n as f64 - 0.5);
            let mut r = self.render_live(scenario, ts)?;
            if let Some(shading) = &self.options.shading {
                let (_, q_cw) = scenario.camera_pose(ts);
                shading.apply(
                    &mut r.gray,
                    &r.depth,
                    self.render_size.0 as usize,
                    &self.render_pinhole,
                    &q_cw,
                    ts,
                );
            }
            for (a, g) in self.accum.iter_mut().zip(&r.gray) {
                *a += g;
            }
            if i == mid {
                (model_coverage, occluder_coverage, model_unoccluded) =
                    self.coverage(scenario, ts, &r.depth, &r.occluded)?;
            }
        }
        let scale = 1.0 / n as f32;
        let light = if self.options.lighting {
            scenario.scene.lighting.at(t)
        } else {
            LightState {
                gain: 1.0,
                offset: 0.0,
                gradient_u: 0.0,
                gradient_v: 0.0,
            }
        };
        let (w, h) = (self.options.width, self.options.height);
        let rw = self.render_size.0 as usize;
        let k = self.camera.pinhole;
        let mut out = GrayImage::new(w, h);
        for (idx, px) in out.pixels_mut().enumerate() {
            let mut sum = 0.0f32;
            for s in &self.samples[4 * idx..4 * idx + 4] {
                if !s[0].is_nan() {
                    sum += bilinear(&self.accum, rw, s[0], s[1]);
                }
            }
            let value = (sum * 0.25 * scale) as f64;
            let (u, v) = ((idx as u32 % w) as f64, (idx as u32 / w) as f64);
            let shade = 1.0
                + light.gradient_u * (u - k.cx) / (w as f64 / 2.0)
                + light.gradient_v * (v - k.cy) / (h as f64 / 2.0);
            let mut x = light.gain * value * shade.max(0.0) + light.offset;
            let var = self.options.read_noise.powi(2) + self.options.shot_noise * x.max(0.0);
            if var > 0.0 {
                let g: f64 = StandardNormal.sample(rng);
                x += g * var.sqrt();
            }
            px.0[0] = x.round().clamp(0.0, 255.0) as u8;
        }
        Ok(SynthFrame {
            image: out,
            model_coverage,
            occluder_coverage,
            model_unoccluded,
            light,
        })
    }

    /// Sub-frames for the exposure around `t`: about one per pixel of image motion, from
    /// the rotation and from the translation seen at 0.4 m (the nearest surfaces the
    /// scenarios show).
    fn subframe_count(&self, scenario: &Scenario, t: f64, exposure: f64) -> u32 {
        let (lo, hi) = (
            self.options.subframes,
            self.options.max_subframes.max(self.options.subframes),
        );
        if hi == lo {
            return lo;
        }
        let (c0, q0) = scenario.camera_pose(t - exposure / 2.0);
        let (c1, q1) = scenario.camera_pose(t + exposure / 2.0);
        let radians = (q1 * q0.inverse()).angle() + (c1 - c0).norm() / 0.4;
        let pixels = radians * self.camera.pinhole.fx;
        (pixels.ceil() as u32).clamp(lo, hi)
    }

    /// Shares of the output image where the model is visible and where occluders are, and
    /// the share of the model's own pixels that are visible (`None` where it has none).
    fn coverage(
        &mut self,
        scenario: &Scenario,
        t: f64,
        live_depth: &[f32],
        occluded: &[bool],
    ) -> Result<(f64, f64, Option<f64>), SynthError> {
        let (c_w, q_cw) = scenario.camera_pose(t);
        let view = self.view(CameraPose { q_cw, c_w });
        let m = self.model.render(&view)?;
        let zm = m.depth.as_raw();
        let (mut vis, mut occ, mut model) = (0usize, 0usize, 0usize);
        for &i in self.centres.iter().flatten() {
            model += usize::from(zm[i] > 0.0);
            // The same surfaces rendered twice give the same depth; anything nearer in the
            // live world hides the model.
            vis += usize::from(zm[i] > 0.0 && live_depth[i] >= zm[i] * (1.0 - 1e-4));
            occ += usize::from(occluded[i]);
        }
        let total = self.centres.len().max(1) as f64;
        let unoccluded = (model > 0).then(|| vis as f64 / model as f64);
        Ok((vis as f64 / total, occ as f64 / total, unoccluded))
    }
}

fn bilinear(img: &[f32], width: usize, x: f32, y: f32) -> f32 {
    let height = img.len() / width;
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    let (ax, ay) = (x - x0 as f32, y - y0 as f32);
    let at = |xx: usize, yy: usize| img[yy * width + xx];
    let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
    let bottom = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
    top * (1.0 - ay) + bottom * ay
}
