//! Filter benchmarks (filled in with the filter).
fn main() {}
