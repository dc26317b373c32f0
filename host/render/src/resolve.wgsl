// Depth resolve: copies the depth buffer's bits into an R32Uint colour target, because GL
// cannot copy depth textures to buffers (and R32Float is not renderable there).
@group(0) @binding(0) var depth_texture: texture_2d<f32>;

@vertex
fn vs_fullscreen(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the viewport: (-1,-1), (3,-1), (-1,3).
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_resolve(@builtin(position) p: vec4<f32>) -> @location(0) u32 {
    let d = textureLoad(depth_texture, vec2<i32>(p.xy), 0).r;
    return bitcast<u32>(d);
}
