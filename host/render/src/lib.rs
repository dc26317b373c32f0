#![deny(missing_docs)]
//! Offscreen rendering of the textured model from a camera pose (wgpu): colour, grayscale,
//! metric depth and a validity mask, read back to the CPU.
//!
//! The [`Renderer`] is created once (device, pipelines, targets, readback buffers) and reused
//! every frame. It runs on software drivers: Vulkan through Mesa lavapipe, GL through
//! llvmpipe, selected with `WGPU_BACKEND=vulkan|gl` (all backends when unset). The projection
//! is built from the intrinsics ([`projection`]) so a world point lands on the pixel
//! [`camera::Camera::project`] predicts for the undistorted camera, with integer pixel
//! coordinates at pixel centres.

pub mod backproject;
mod frame;
mod gpu;
mod mip;
pub mod projection;
pub mod region;
mod scene;
mod targets;
mod view;

pub use frame::Frame;
pub use region::Region;
pub use view::RenderView;

use gpu::Gpu;
use scene::{GpuScene, Vertex};
use targets::Targets;

use model::Model;

/// Why rendering failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No GPU adapter, not even a software one.
    #[error(
        "no GPU adapter for backends {backends} ({detail}). Install a software driver: \
         Vulkan: `apt-get install libvulkan1 mesa-vulkan-drivers`; GL: `apt-get install \
         libegl1 libgl1-mesa-dri`; choose with WGPU_BACKEND=vulkan or WGPU_BACKEND=gl"
    )]
    NoAdapter {
        /// Backends that were tried.
        backends: String,
        /// wgpu's reason.
        detail: String,
    },
    /// The adapter refused to open a device.
    #[error("cannot open the GPU device: {0}")]
    Device(String),
    /// A wgpu validation, out-of-memory or internal error, or a lost device.
    #[error("wgpu error while {during}: {message}")]
    Wgpu {
        /// What we were doing.
        during: &'static str,
        /// wgpu's message.
        message: String,
    },
    /// Reading the results back failed.
    #[error("reading back the rendering failed: {0}")]
    Readback(String),
    /// Image size zero or above the device limit.
    #[error("render size {width}x{height} not supported (1..={max} per side)")]
    BadSize {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
        /// Device limit.
        max: u32,
    },
    /// A texture larger than the device allows.
    #[error("material `{material}`: texture {width}x{height} not supported (1..={max} per side)")]
    TextureSize {
        /// Material name.
        material: String,
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
        /// Device limit.
        max: u32,
    },
    /// A frame's images disagree in size (`Frame::from_images`).
    #[error("frame images of different sizes: {0}")]
    FrameSizes(String),
    /// Too much geometry for one buffer.
    #[error("model too large: {0} exceeds the device limits")]
    TooLarge(&'static str),
    /// Invalid view parameters (intrinsics, near/far).
    #[error("invalid view: {0}")]
    BadView(String),
    /// The model is inconsistent (see [`Model::check`]).
    #[error("invalid model: {0}")]
    Model(#[from] model::ModelError),
    /// `render` before `set_model`, or a model without meshes.
    #[error("no model to render (call set_model with a non-empty model)")]
    EmptyModel,
    /// `finish_into` without a rendering submitted.
    #[error("no rendering submitted (call submit before finish_into)")]
    NothingSubmitted,
}

/// How depth reaches the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthReadback {
    /// Direct depth-texture-to-buffer copy (Vulkan).
    Copy,
    /// A full-screen pass writes the depth bits into an `R32Uint` target, which is copied
    /// (GL, where depth copies are not allowed).
    ShaderResolve,
}

/// Renderer options.
#[derive(Debug, Clone, Copy)]
pub struct RendererOptions {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Use the shader resolve even where a depth copy works (to test that path).
    pub force_depth_resolve: bool,
    /// Rasterise and read back the whole image, not only the rectangle the model can cover
    /// ([`region`]): the same frame, slower (to compare the two).
    pub whole_image: bool,
}

/// The offscreen renderer. Create once, [`Renderer::set_model`], then
/// [`Renderer::render`] every frame.
pub struct Renderer {
    gpu: std::sync::Arc<Gpu>,
    targets: Targets,
    scene: Option<GpuScene>,
    /// The view of the rendering submitted and not yet read back, and the rectangle rendered.
    pending: Option<(RenderView, Region)>,
    whole_image: bool,
}

impl Renderer {
    /// A renderer for `width × height` images on the adapter `WGPU_BACKEND` selects.
    pub fn new(width: u32, height: u32) -> Result<Self, RenderError> {
        Self::with_options(RendererOptions {
            width,
            height,
            force_depth_resolve: false,
            whole_image: false,
        })
    }

    /// A renderer with explicit options.
    pub fn with_options(options: RendererOptions) -> Result<Self, RenderError> {
        let gpu = Gpu::shared()?;
        let max = gpu.device.limits().max_texture_dimension_2d;
        let (width, height) = (options.width, options.height);
        if width == 0 || height == 0 || width > max || height > max {
            return Err(RenderError::BadSize { width, height, max });
        }
        let copy_ok = gpu
            .downlevel
            .flags
            .contains(wgpu::DownlevelFlags::DEPTH_TEXTURE_AND_BUFFER_COPIES);
        let depth = if copy_ok && !options.force_depth_resolve {
            DepthReadback::Copy
        } else {
            DepthReadback::ShaderResolve
        };
        let targets = gpu.scoped("creating render targets and pipelines", || {
            Ok(Targets::new(&gpu.device, width, height, depth))
        })?;
        Ok(Self {
            gpu,
            targets,
            scene: None,
            pending: None,
            whole_image: options.whole_image,
        })
    }

    /// The adapter in use (name, backend, driver).
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.gpu.info
    }

    /// One line naming the adapter and backend, for logs and reports.
    pub fn adapter_summary(&self) -> String {
        let i = &self.gpu.info;
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            i.name, i.backend, i.device_type, i.driver, i.driver_info
        )
    }

    /// How depth is read back on this adapter.
    pub fn depth_readback(&self) -> DepthReadback {
        self.targets.depth_readback
    }

    /// Image size `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        (self.targets.width, self.targets.height)
    }

    /// Uploads the model to render (replacing any previous one).
    pub fn set_model(&mut self, model: &Model) -> Result<(), RenderError> {
        model.check("model to render")?;
        let scene = self.gpu.scoped("uploading the model", || {
            GpuScene::upload(
                &self.gpu,
                &self.targets.material_layout,
                &self.targets.sampler,
                model,
            )
        })?;
        self.scene = Some(scene);
        Ok(())
    }

    /// Number of triangles of the current model.
    pub fn triangle_count(&self) -> usize {
        self.scene.as_ref().map_or(0, |s| s.triangles)
    }

    /// Renders the model as seen from `view` and reads everything back.
    pub fn render(&mut self, view: &RenderView) -> Result<Frame, RenderError> {
        let mut frame = Frame::empty(*view);
        self.render_into(view, &mut frame)?;
        Ok(frame)
    }

    /// [`Renderer::render`] into `frame`, reusing its buffers (a tracker renders every frame).
    pub fn render_into(&mut self, view: &RenderView, frame: &mut Frame) -> Result<(), RenderError> {
        self.submit(view)?;
        self.finish_into(frame)
    }

    /// Starts rendering `view` and returns without waiting: the driver rasterises on its own
    /// threads while the caller does other work, then [`Renderer::finish_into`] collects it.
    /// A rendering submitted and never collected is replaced by the next.
    pub fn submit(&mut self, view: &RenderView) -> Result<(), RenderError> {
        self.pending = None;
        view.validate()?;
        let scene = self.scene.as_ref().ok_or(RenderError::EmptyModel)?;
        let (gpu, targets) = (&self.gpu, &self.targets);
        let (width, height) = (targets.width, targets.height);
        let region = if self.whole_image {
            Region::full(width, height)
        } else {
            region::covered_region(&scene.bounds, view, width, height)
        };
        gpu.scoped("rendering", || {
            targets.encode_and_submit(&gpu.device, &gpu.queue, scene, view, region);
            Ok(())
        })?;
        self.pending = Some((*view, region));
        Ok(())
    }

    /// Waits for the rendering [`Renderer::submit`] started and reads it back into `frame`,
    /// reusing its buffers.
    pub fn finish_into(&mut self, frame: &mut Frame) -> Result<(), RenderError> {
        let (view, region) = self.pending.take().ok_or(RenderError::NothingSubmitted)?;
        let (gpu, targets) = (&self.gpu, &self.targets);
        targets.read_into(&gpu.device, view, region, frame)?;
        gpu.take_uncaptured("reading back")
    }
}

// Vertex is used by the pipeline layout in `targets`.
const _: () = assert!(std::mem::size_of::<Vertex>() == 20);
