//! Pipelines, render targets and readback buffers, created once per renderer.

use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use super::projection::projection_matrix;
use super::region::Region;
use super::scene::{GpuScene, Vertex};
use super::{DepthReadback, Frame, RenderError, RenderView};

/// The longest a read-back waits for its mappings after the device went idle.
const MAPPING_WAIT: Duration = Duration::from_secs(10);

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const RESOLVE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;

/// Bytes per row of a readback buffer (rows padded to wgpu's copy alignment).
fn padded_row(width: u32) -> u32 {
    let unpadded = width * 4;
    unpadded.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

pub(crate) struct Targets {
    pub width: u32,
    pub height: u32,
    pub depth_readback: DepthReadback,
    pub material_layout: wgpu::BindGroupLayout,
    pub sampler: wgpu::Sampler,
    model_pipeline: wgpu::RenderPipeline,
    camera_buffer: wgpu::Buffer,
    camera_group: wgpu::BindGroup,
    colour: wgpu::Texture,
    colour_view: wgpu::TextureView,
    depth: wgpu::Texture,
    depth_view: wgpu::TextureView,
    /// The depth resolve: its pipeline, its bind group and the `R32Uint` target. GL reads all
    /// depth through it; elsewhere it serves the focused read-back, as WebGPU copies only
    /// whole depth textures.
    resolve: (wgpu::RenderPipeline, wgpu::BindGroup, wgpu::Texture),
    colour_readback: wgpu::Buffer,
    depth_readback_buffer: wgpu::Buffer,
}

fn texture(
    device: &wgpu::Device,
    label: &str,
    width: u32,
    height: u32,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// A uniform buffer's entry in a bind group layout.
fn uniform_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn readback_buffer(device: &wgpu::Device, label: &str, width: u32, height: u32) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: padded_row(width) as u64 * height as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

impl Targets {
    /// The material's bind group layout: its uniform, its texture and the sampler.
    fn material_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("material"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        })
    }

    /// The pipeline that draws the textured model (`model.wgsl`): no culling, reversed depth.
    fn model_pipeline(
        device: &wgpu::Device,
        camera_layout: &wgpu::BindGroupLayout,
        material_layout: &wgpu::BindGroupLayout,
    ) -> wgpu::RenderPipeline {
        let model_shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("model"),
            source: wgpu::ShaderSource::Wgsl(include_str!("model.wgsl").into()),
        });
        let model_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("model"),
            bind_group_layouts: &[Some(camera_layout), Some(material_layout)],
            immediate_size: 0,
        });
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("model"),
            layout: Some(&model_layout),
            vertex: wgpu::VertexState {
                module: &model_shader,
                entry_point: Some("vs_model"),
                compilation_options: Default::default(),
                buffers: &[Some(Vertex::LAYOUT)],
            },
            // No culling: CAD/OBJ winding is not reliable, the depth test decides.
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                cull_mode: None,
                ..Default::default()
            },
            // Reversed depth (near = 1, far = 0, cleared to 0): see `projection`.
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &model_shader,
                entry_point: Some("fs_model"),
                compilation_options: Default::default(),
                targets: &[Some(COLOUR_FORMAT.into())],
            }),
            multiview_mask: None,
            cache: None,
        })
    }

    pub fn new(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        depth_readback: DepthReadback,
    ) -> Self {
        let camera_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("camera"),
            entries: &[uniform_entry(0, wgpu::ShaderStages::VERTEX)],
        });
        let material_layout = Self::material_layout(device);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("material"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let camera_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("camera"),
            size: 64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let camera_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("camera"),
            layout: &camera_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: camera_buffer.as_entire_binding(),
            }],
        });

        let model_pipeline = Self::model_pipeline(device, &camera_layout, &material_layout);

        let colour = texture(
            device,
            "colour",
            width,
            height,
            COLOUR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let depth_usage = match depth_readback {
            DepthReadback::Copy => wgpu::TextureUsages::COPY_SRC,
            DepthReadback::ShaderResolve => wgpu::TextureUsages::empty(),
        } | wgpu::TextureUsages::TEXTURE_BINDING;
        let depth = texture(
            device,
            "depth",
            width,
            height,
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | depth_usage,
        );
        let colour_view = colour.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        let resolve = Self::resolve_pass(device, width, height, &depth_view);

        Self {
            width,
            height,
            depth_readback,
            material_layout,
            sampler,
            model_pipeline,
            camera_buffer,
            camera_group,
            colour,
            colour_view,
            depth,
            depth_view,
            resolve,
            colour_readback: readback_buffer(device, "colour readback", width, height),
            depth_readback_buffer: readback_buffer(device, "depth readback", width, height),
        }
    }

    fn resolve_pass(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        depth_view: &wgpu::TextureView,
    ) -> (wgpu::RenderPipeline, wgpu::BindGroup, wgpu::Texture) {
        // Explicit layout: a depth texture bound as unfilterable float (see TOOLCHAIN.md).
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("depth resolve"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("depth resolve"),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(depth_view),
            }],
        });
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("depth resolve"),
            source: wgpu::ShaderSource::Wgsl(include_str!("resolve.wgsl").into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("depth resolve"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("depth resolve"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_fullscreen"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_resolve"),
                compilation_options: Default::default(),
                targets: &[Some(RESOLVE_FORMAT.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let target = texture(
            device,
            "depth bits",
            width,
            height,
            RESOLVE_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        (pipeline, group, target)
    }

    /// Records the frame (model pass, optional depth resolve, copies of `region`) and submits
    /// it. Only `region` is rasterised (a scissor) and copied: outside it the model has no
    /// pixel ([`crate::region`]).
    pub fn encode_and_submit(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &GpuScene,
        view: &RenderView,
        region: Region,
    ) {
        let mvp = projection_matrix(&view.pinhole, self.width, self.height, view.near, view.far)
            * view.pose.view_matrix();
        let mvp: nalgebra::Matrix4<f32> = mvp.cast();
        // nalgebra is column-major, as WGSL's mat4x4.
        queue.write_buffer(&self.camera_buffer, 0, bytemuck::cast_slice(mvp.as_slice()));

        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("model"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.colour_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_scissor_rect(region.x, region.y, region.width, region.height);
            pass.set_pipeline(&self.model_pipeline);
            pass.set_bind_group(0, &self.camera_group, &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            for d in &scene.draws {
                pass.set_bind_group(1, &scene.materials[d.material], &[]);
                pass.draw_indexed(d.indices.clone(), d.base_vertex, 0..1);
            }
        }
        // A part of the image, or GL: the depth through the resolve pass.
        let resolve = (self.depth_readback == DepthReadback::ShaderResolve
            || region != Region::full(self.width, self.height))
        .then_some(&self.resolve);
        if let Some(resolve) = resolve {
            encode_resolve(&mut encoder, resolve, region);
        }
        let layout = wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(padded_row(region.width)),
            rows_per_image: Some(region.height),
        };
        let extent = wgpu::Extent3d {
            width: region.width,
            height: region.height,
            depth_or_array_layers: 1,
        };
        let origin = wgpu::Origin3d {
            x: region.x,
            y: region.y,
            z: 0,
        };
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                origin,
                ..self.colour.as_image_copy()
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.colour_readback,
                layout,
            },
            extent,
        );
        let depth_source = match resolve {
            Some((_, _, target)) => wgpu::TexelCopyTextureInfo {
                origin,
                ..target.as_image_copy()
            },
            None => wgpu::TexelCopyTextureInfo {
                texture: &self.depth,
                mip_level: 0,
                origin,
                aspect: wgpu::TextureAspect::DepthOnly,
            },
        };
        encoder.copy_texture_to_buffer(
            depth_source,
            wgpu::TexelCopyBufferInfo {
                buffer: &self.depth_readback_buffer,
                layout,
            },
            extent,
        );
        queue.submit(Some(encoder.finish()));
    }

    /// Waits for the frame and converts it into `frame` (see [`Frame::fill_from_mapped`]),
    /// straight from the mapped buffers, which hold `region`.
    pub fn read_into(
        &self,
        device: &wgpu::Device,
        view: RenderView,
        region: Region,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        let used = u64::from(padded_row(region.width)) * u64::from(region.height);
        let (tx, rx) = mpsc::channel();
        for (i, buffer) in [&self.colour_readback, &self.depth_readback_buffer]
            .into_iter()
            .enumerate()
        {
            let tx = tx.clone();
            buffer.map_async(wgpu::MapMode::Read, ..used, move |r| {
                // The receiver lives until both answers arrived or we failed.
                let _ = tx.send((i, r));
            });
        }
        drop(tx);
        let polled = device.poll(wgpu::PollType::wait_indefinitely());
        let mut mapped = [false; 2];
        let mut failure = polled.err().map(|e| e.to_string());
        // The device is shared (`Gpu::shared`): another thread's poll may have taken our
        // mappings' completion and call the callbacks a moment after ours returned.
        let deadline = Instant::now() + MAPPING_WAIT;
        while failure.is_none() && mapped != [true; 2] {
            match rx.recv_timeout(Duration::from_millis(2)) {
                Ok((i, Ok(()))) => mapped[i] = true,
                Ok((_, Err(e))) => failure = Some(e.to_string()),
                Err(RecvTimeoutError::Timeout) if Instant::now() < deadline => {
                    let _ = device.poll(wgpu::PollType::Poll);
                }
                Err(_) => failure = Some("buffer mapping did not complete".into()),
            }
        }
        let result = match failure {
            Some(f) => Err(RenderError::Readback(f)),
            None => self.convert(view, region, used, frame),
        };
        for (i, buffer) in [&self.colour_readback, &self.depth_readback_buffer]
            .into_iter()
            .enumerate()
        {
            if mapped[i] {
                buffer.unmap();
            }
        }
        result
    }

    fn convert(
        &self,
        view: RenderView,
        region: Region,
        used: u64,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        let map_err = |e: wgpu::MapRangeError| RenderError::Readback(e.to_string());
        let colour = self
            .colour_readback
            .get_mapped_range(..used)
            .map_err(map_err)?;
        let depth = self
            .depth_readback_buffer
            .get_mapped_range(..used)
            .map_err(map_err)?;
        frame.fill_from_mapped(
            view,
            (self.width, self.height),
            region,
            &colour,
            &depth,
            padded_row(region.width) as usize,
        )
    }
}

/// The depth resolve pass over `region`: the depth buffer's bits into the `R32Uint` target.
fn encode_resolve(
    encoder: &mut wgpu::CommandEncoder,
    (pipeline, group, target): &(wgpu::RenderPipeline, wgpu::BindGroup, wgpu::Texture),
    region: Region,
) {
    let target_view = target.create_view(&Default::default());
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("depth resolve"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: &target_view,
            depth_slice: None,
            resolve_target: None,
            // Every pixel of the rectangle is written and no other is read: no clear.
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Load,
                store: wgpu::StoreOp::Store,
            },
        })],
        ..Default::default()
    });
    pass.set_scissor_rect(region.x, region.y, region.width, region.height);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.draw(0..3, 0..1);
}
