//! The model uploaded to the GPU: one vertex and one index buffer, one texture per image
//! (with mipmaps), one bind group per material.

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::sync::Arc;

use image::RgbaImage;
use wgpu::util::DeviceExt;

use super::RenderError;
use super::gpu::Gpu;
use model::Model;

/// Interleaved vertex: position (m) then texture coordinates.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct Vertex {
    pub position: [f32; 3],
    pub uv: [f32; 2],
}

impl Vertex {
    pub const LAYOUT: wgpu::VertexBufferLayout<'static> = wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2],
    };
}

/// One indexed draw.
pub(crate) struct Draw {
    pub material: usize,
    pub indices: std::ops::Range<u32>,
    pub base_vertex: i32,
}

pub(crate) struct GpuScene {
    pub vertices: wgpu::Buffer,
    pub indices: wgpu::Buffer,
    pub materials: Vec<wgpu::BindGroup>,
    pub draws: Vec<Draw>,
    pub triangles: usize,
    /// The least and greatest corner of the box around every vertex (model frame, m).
    pub bounds: ([f32; 3], [f32; 3]),
}

impl GpuScene {
    pub fn upload(
        gpu: &Gpu,
        layout: &wgpu::BindGroupLayout,
        sampler: &wgpu::Sampler,
        model: &Model,
    ) -> Result<Self, RenderError> {
        let (device, queue) = (&gpu.device, &gpu.queue);
        let limits = device.limits();
        let mut vertices = Vec::new();
        let mut indices = Vec::new();
        let mut draws = Vec::new();
        for mesh in &model.meshes {
            let base_vertex =
                i32::try_from(vertices.len()).map_err(|_| RenderError::TooLarge("vertex count"))?;
            let start =
                u32::try_from(indices.len()).map_err(|_| RenderError::TooLarge("index count"))?;
            vertices.extend(
                mesh.positions
                    .iter()
                    .zip(&mesh.uvs)
                    .map(|(&position, &uv)| Vertex { position, uv }),
            );
            indices.extend_from_slice(&mesh.indices);
            let end =
                u32::try_from(indices.len()).map_err(|_| RenderError::TooLarge("index count"))?;
            draws.push(Draw {
                material: mesh.material,
                indices: start..end,
                base_vertex,
            });
        }
        if draws.is_empty() {
            return Err(RenderError::EmptyModel);
        }
        let vertex_bytes: &[u8] = bytemuck::cast_slice(&vertices);
        let index_bytes: &[u8] = bytemuck::cast_slice(&indices);
        if vertex_bytes.len().max(index_bytes.len()) as u64 > limits.max_buffer_size {
            return Err(RenderError::TooLarge("vertex or index buffer"));
        }
        // Draw in material order: fewer bind-group switches.
        draws.sort_by_key(|d| d.material);
        let bounds = bounds(&vertices);

        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("model vertices"),
            contents: vertex_bytes,
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("model indices"),
            contents: index_bytes,
            usage: wgpu::BufferUsages::INDEX,
        });

        let white = Arc::new(RgbaImage::from_pixel(1, 1, image::Rgba([255; 4])));
        let mut views: HashMap<*const RgbaImage, wgpu::TextureView> = HashMap::new();
        let mut materials = Vec::with_capacity(model.materials.len());
        for m in &model.materials {
            let image = m.texture.clone().unwrap_or_else(|| white.clone());
            let key = Arc::as_ptr(&image);
            let view = match views.entry(key) {
                Entry::Occupied(e) => e.into_mut(),
                Entry::Vacant(e) => {
                    let max = limits.max_texture_dimension_2d;
                    let (w, h) = image.dimensions();
                    if w == 0 || h == 0 || w > max || h > max {
                        return Err(RenderError::TextureSize {
                            material: m.name.clone(),
                            width: w,
                            height: h,
                            max,
                        });
                    }
                    e.insert(gpu.texture(&image, || upload_texture(device, queue, &image)))
                }
            };
            let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("material"),
                contents: bytemuck::cast_slice(&m.base_colour),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            materials.push(device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("material"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(sampler),
                    },
                ],
            }));
        }
        Ok(Self {
            vertices,
            indices,
            materials,
            draws,
            triangles: model.triangle_count(),
            bounds,
        })
    }
}

/// The least and greatest corner of the box around `vertices`.
fn bounds(vertices: &[Vertex]) -> ([f32; 3], [f32; 3]) {
    let mut bounds = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for v in vertices {
        for axis in 0..3 {
            bounds.0[axis] = bounds.0[axis].min(v.position[axis]);
            bounds.1[axis] = bounds.1[axis].max(v.position[axis]);
        }
    }
    bounds
}

/// Uploads an RGBA8 texture with a full mip chain (triangle-filtered on the CPU, [`super::mip`]), so minified
/// textures do not alias.
fn upload_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    image: &RgbaImage,
) -> wgpu::TextureView {
    let levels = 32 - image.width().max(image.height()).leading_zeros();
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("material texture"),
        size: wgpu::Extent3d {
            width: image.width(),
            height: image.height(),
            depth_or_array_layers: 1,
        },
        mip_level_count: levels,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        // Unorm, not sRGB: the rendered values are the texture's values.
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    write_level(device, queue, &texture, 0, image);
    let mut smaller: Option<RgbaImage> = None;
    for level in 1..levels {
        let above = smaller.as_ref().unwrap_or(image);
        let level_image = super::mip::half(above);
        write_level(device, queue, &texture, level, &level_image);
        smaller = Some(level_image);
    }
    texture.create_view(&wgpu::TextureViewDescriptor::default())
}

/// Most bytes staged at once: a texture goes up in bands of rows, each staging buffer freed
/// before the next (a whole level would stage its full size, 69 MB for 5083×3409).
const STAGING_BYTES: usize = 8 << 20;

/// Writes `image` as mip `level` of `texture`, band by band, waiting for each.
fn write_level(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    level: u32,
    image: &RgbaImage,
) {
    let row_bytes = 4 * image.width() as usize;
    let band = (STAGING_BYTES / row_bytes).max(1);
    for y0 in (0..image.height()).step_by(band) {
        let height = (image.height() - y0).min(band as u32);
        let start = y0 as usize * row_bytes;
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: level,
                origin: wgpu::Origin3d { x: 0, y: y0, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            &image.as_raw()[start..start + height as usize * row_bytes],
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row_bytes as u32),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d {
                width: image.width(),
                height,
                depth_or_array_layers: 1,
            },
        );
        // The staging buffer goes with the submission that copies it.
        queue.submit([]);
        let _ = device.poll(wgpu::PollType::wait_indefinitely());
    }
}
