//! The robustness corpus in full (issue 56), as a bench: every scene synthesised (cached in
//! `target/corpus-bench/datasets`), tracked with the acc model and vision-only, and each
//! frame's verdict scored against the truth; the table printed (the README's, docs/VISION.md
//! §10), with each run's wall time, and written with the runs' outputs to
//! `target/corpus-bench/out`. `cargo bench -p host-vision --bench corpus` (the README gives
//! its time on 2 cores, the datasets' synthesis included and not); `-- --quick` runs the
//! suite's form (`host-vision/tests/corpus.rs`). The bunny's scenes are skipped, saying so,
//! without `../shared/data/meshes/bunny`.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use host_vision::corpus::{self, CorpusEvent, CorpusOptions};

fn main() {
    // `cargo bench` passes `--bench`; the only argument of this bench's own is `--quick`.
    let quick = std::env::args().any(|a| a == "--quick");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let bench = root.join("../target/corpus-bench");
    let options = CorpusOptions {
        quick,
        only: Vec::new(),
        cache: bench.join("datasets"),
        out: bench.join(if quick { "out-quick" } else { "out" }),
        seed: 0,
        data: root.join("../../shared/data"),
        overwrite: true,
        interrupt: Arc::new(AtomicBool::new(false)),
    };
    let started = Instant::now();
    let mut last = Instant::now();
    let report = corpus::run(&options, &mut |event| match event {
        CorpusEvent::Step { .. } => {}
        CorpusEvent::RunDone(row) => {
            println!(
                "{} {}: {} frames, {} tracked, {:.1} s (synthesis included where not cached)",
                row.scene.name,
                row.filter,
                row.score.frames,
                row.score.tracked,
                last.elapsed().as_secs_f64()
            );
            last = Instant::now();
        }
        CorpusEvent::Skipped(scene, why) => println!("skipped: {}: {why}", scene.name),
    })
    .expect("the corpus runs");
    println!("{}", report.markdown());
    println!(
        "{} runs in {:.0} s; outputs in {}",
        report.rows.len(),
        started.elapsed().as_secs_f64(),
        options.out.display()
    );
}
