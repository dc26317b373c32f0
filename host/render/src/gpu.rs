//! Opening the wgpu device, and turning wgpu errors into [`RenderError`]s instead of panics.
//!
//! The renderers of a process share one device ([`Gpu::shared`]) and its textures
//! ([`Gpu::texture`]): a tracker renders the same model on two threads (the frames', the
//! searches'), and a 5083×3409 texture with its mipmaps is 92 MB on a software driver, in the
//! process's memory, for each copy.

use std::sync::{Arc, Mutex, PoisonError, Weak};

use image::RgbaImage;

use super::RenderError;

/// The device and what we learnt about its adapter.
pub(crate) struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub downlevel: wgpu::DownlevelCapabilities,
    /// Errors that escaped every error scope (wgpu would panic on them by default).
    uncaptured: Arc<Mutex<Vec<String>>>,
    /// The textures uploaded, by the image they hold, while that image lives.
    textures: Mutex<Vec<(Weak<RgbaImage>, wgpu::TextureView)>>,
}

impl Gpu {
    /// The device every renderer of the process uses while one is alive: opened by the first,
    /// closed with the last.
    pub fn shared() -> Result<Arc<Self>, RenderError> {
        static SHARED: Mutex<Weak<Gpu>> = Mutex::new(Weak::new());
        let mut slot = SHARED.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(gpu) = slot.upgrade() {
            return Ok(gpu);
        }
        let gpu = Arc::new(Self::open()?);
        *slot = Arc::downgrade(&gpu);
        Ok(gpu)
    }

    /// The texture of `image` on this device: uploaded by the first renderer that asks, the
    /// same view for the others while the image lives.
    pub fn texture(
        &self,
        image: &Arc<RgbaImage>,
        upload: impl FnOnce() -> wgpu::TextureView,
    ) -> wgpu::TextureView {
        // Held during the upload: a second renderer asking for the same image waits for it.
        let mut textures = self.textures.lock().unwrap_or_else(PoisonError::into_inner);
        textures.retain(|(held, _)| held.strong_count() > 0);
        if let Some((_, view)) = textures
            .iter()
            .find(|(held, _)| std::ptr::eq(held.as_ptr(), Arc::as_ptr(image)))
        {
            return view.clone();
        }
        let view = upload();
        textures.push((Arc::downgrade(image), view.clone()));
        view
    }

    /// Opens the first adapter of the backends `WGPU_BACKEND` selects (all when unset).
    fn open() -> Result<Self, RenderError> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        let backends = desc.backends;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..Default::default()
        }))
        .map_err(|e| RenderError::NoAdapter {
            backends: format!("{backends:?}"),
            detail: e.to_string(),
        })?;
        let info = adapter.get_info();
        let downlevel = adapter.get_downlevel_capabilities();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("host-vision renderer"),
            required_features: wgpu::Features::empty(),
            // The adapter's own limits: always valid, and large textures stay possible.
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::Device(format!("{} ({:?}): {e}", info.name, info.backend)))?;

        let uncaptured = Arc::new(Mutex::new(Vec::new()));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        let lost = uncaptured.clone();
        device.set_device_lost_callback(move |reason, msg| {
            if let Ok(mut v) = lost.lock() {
                v.push(format!("device lost ({reason:?}): {msg}"));
            }
        });
        Ok(Self {
            device,
            queue,
            info,
            downlevel,
            uncaptured,
            textures: Mutex::default(),
        })
    }

    /// Fails with the first error no scope caught since the last call.
    pub fn take_uncaptured(&self, during: &'static str) -> Result<(), RenderError> {
        let mut v = self.uncaptured.lock().map_err(|_| RenderError::Wgpu {
            during,
            message: "error log poisoned".into(),
        })?;
        match v.drain(..).next() {
            Some(message) => Err(RenderError::Wgpu { during, message }),
            None => Ok(()),
        }
    }

    /// Runs `f` inside validation, out-of-memory and internal error scopes.
    pub fn scoped<T>(
        &self,
        during: &'static str,
        f: impl FnOnce() -> Result<T, RenderError>,
    ) -> Result<T, RenderError> {
        let mut guards = vec![
            self.device.push_error_scope(wgpu::ErrorFilter::Validation),
            self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory),
            self.device.push_error_scope(wgpu::ErrorFilter::Internal),
        ];
        let result = f();
        let mut first = None;
        // Scopes must be popped in reverse order.
        while let Some(g) = guards.pop() {
            if let Some(e) = pollster::block_on(g.pop()) {
                first.get_or_insert_with(|| e.to_string());
            }
        }
        if let Some(message) = first {
            return Err(RenderError::Wgpu { during, message });
        }
        self.take_uncaptured(during)?;
        result
    }
}
