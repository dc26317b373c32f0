// Textured, unlit rendering of the model.

struct CameraUniform {
    // Clip-space transform of world points (projection · view), column-major.
    mvp: mat4x4<f32>,
};

struct MaterialUniform {
    base_colour: vec4<f32>,
};

@group(0) @binding(0) var<uniform> camera: CameraUniform;
@group(1) @binding(0) var<uniform> material: MaterialUniform;
@group(1) @binding(1) var material_texture: texture_2d<f32>;
@group(1) @binding(2) var material_sampler: sampler;

struct VertexOut {
    @builtin(position) position: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

@vertex
fn vs_model(@location(0) position: vec3<f32>, @location(1) uv: vec2<f32>) -> VertexOut {
    var out: VertexOut;
    out.position = camera.mvp * vec4<f32>(position, 1.0);
    out.uv = uv;
    return out;
}

@fragment
fn fs_model(in: VertexOut) -> @location(0) vec4<f32> {
    let c = textureSample(material_texture, material_sampler, in.uv) * material.base_colour;
    return vec4<f32>(c.rgb, 1.0);
}
