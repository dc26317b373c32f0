//! Render + readback time (colour, gray, depth, mask on the CPU) at 320×240 and 640×480, for
//! the test scene and a procedural 131k-triangle textured terrain: a fresh frame each time, and
//! as the tracker renders (`/tracker`: into kept buffers, without the RGBA copy); and with
//! nothing in view, the floor of submission, clears, copies and read-back. The adapter is printed
//! first; choose it with `WGPU_BACKEND=vulkan|gl`.

use std::sync::Arc;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use host_vision::camera::{CameraPose, Pinhole};
use host_vision::model::procedural;
use host_vision::render::{Frame, RenderView, Renderer};
use nalgebra::Vector3;

fn view(width: u32, height: u32, eye: [f64; 3], target: [f64; 3]) -> RenderView {
    let f = 0.9 * width as f64;
    RenderView {
        pinhole: Pinhole::new(
            f,
            f,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
        ),
        pose: CameraPose::look_at(eye.into(), target.into(), Vector3::z())
            .expect("fixed, valid pose"),
        near: 0.05,
        far: 20.0,
    }
}

fn render(c: &mut Criterion) {
    let scenes = [
        (
            "test_scene",
            procedural::test_scene(),
            [1.4, -1.2, 1.1],
            [0.0, 0.0, 0.2],
        ),
        (
            "terrain",
            procedural::terrain(256, 2.0, 0.1, Arc::new(procedural::checker_texture(16, 32))),
            [0.0, -1.6, 1.3],
            [0.0, 0.0, 0.0],
        ),
    ];
    let mut group = c.benchmark_group("render+readback");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    for (width, height) in [(320, 240), (640, 480)] {
        let mut renderer = Renderer::new(width, height)
            .unwrap_or_else(|e| panic!("the benchmark needs a wgpu adapter: {e}"));
        println!("adapter: {}", renderer.adapter_summary());
        for (name, model, eye, target) in &scenes {
            renderer
                .set_model(model)
                .unwrap_or_else(|e| panic!("uploading {name}: {e}"));
            let v = view(width, height, *eye, *target);
            let id = format!(
                "{name} ({} triangles)/{width}x{height}",
                renderer.triangle_count()
            );
            group.bench_function(id.clone(), |b| {
                b.iter(|| renderer.render(&v).unwrap_or_else(|e| panic!("{e}")))
            });
            // As the tracker renders: into the last frame's buffers, without the RGBA copy.
            let mut frame = Frame::empty_for_tracker(v);
            group.bench_function(format!("{id}/tracker"), |b| {
                b.iter(|| {
                    renderer
                        .render_into(&v, &mut frame)
                        .unwrap_or_else(|e| panic!("{e}"))
                })
            });
            if *name == "test_scene" {
                // The floor: nothing in view (looking away from the test scene), so the time
                // is the submission, the clears, the copies and the read-back alone.
                let away = view(width, height, [0.0, -5.0, 1.0], [0.0, -10.0, 1.0]);
                let mut frame = Frame::empty_for_tracker(away);
                group.bench_function(format!("nothing in view/{width}x{height}/tracker"), |b| {
                    b.iter(|| {
                        renderer
                            .render_into(&away, &mut frame)
                            .unwrap_or_else(|e| panic!("{e}"))
                    })
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, render);
criterion_main!(benches);
