//! Descriptor matching, the cold start's second stage: 3000 live descriptors (the attempt's
//! budget, `LocateConfig`) against 45,000 database entries (as many as the cube's database,
//! 2.2 MB), a third of the queries near copies of entries, through the index with its 3000
//! checks per query.

use criterion::{Criterion, criterion_group, criterion_main};
use locate::index::Index;
use locate::matching::{MatchConfig, match_descriptors};
use locate::orb::Descriptor;

/// xorshift64: the same data every run.
fn descriptors(n: usize, seed: u64) -> Vec<Descriptor> {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    (0..n).map(|_| [next(), next(), next(), next()]).collect()
}

fn matching(c: &mut Criterion) {
    let train = descriptors(45_000, 7);
    let points: Vec<[f32; 3]> = (0..train.len())
        .map(|i| [i as f32 * 0.01, 0.0, 0.0])
        .collect();
    let mut query = descriptors(3000, 11);
    for (i, q) in query.iter_mut().enumerate().step_by(3) {
        // A near copy: 20 of 256 bits flipped.
        *q = train[i * 13];
        for b in 0..20 {
            q[b % 4] ^= 1 << ((b * 11 + i) % 64);
        }
    }
    let index = Index::new(&train);
    let config = MatchConfig::default();
    let found = match_descriptors(&query, &train, &points, Some(&index), &config);
    eprintln!("{} matches of {} queries", found.len(), query.len());
    let mut g = c.benchmark_group("matching");
    g.sample_size(20);
    g.bench_function("3000 x 45000 through the index", |b| {
        b.iter(|| match_descriptors(&query, &train, &points, Some(&index), &config))
    });
    g.finish();
}

criterion_group!(benches, matching);
criterion_main!(benches);
