//! The README's example of the tracker is the crate's own doc example (src/lib.rs), which the
//! doc-tests compile: the two must not drift apart.

use std::path::Path;

/// The visible lines of the first `no_run` example in the crate's documentation.
fn doc_example() -> Vec<String> {
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs"))
        .expect("src/lib.rs");
    lib.lines()
        .filter_map(|l| l.strip_prefix("//!"))
        .skip_while(|l| l.trim() != "```no_run")
        .skip(1)
        .take_while(|l| l.trim() != "```")
        .map(|l| l.strip_prefix(' ').unwrap_or(l))
        .filter(|l| !l.starts_with("# ") && *l != "#")
        .map(str::to_owned)
        .collect()
}

#[test]
fn the_readme_shows_the_crate_example_that_compiles() {
    let example = doc_example();
    assert!(
        example.len() >= 10,
        "the crate's example is missing: {example:?}"
    );
    let code_lines = example
        .iter()
        .filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with("//"))
        .count();
    assert!(
        code_lines <= 15,
        "the example has {code_lines} lines of code: the README promises at most 15"
    );
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md"))
            .expect("README.md");
    let lines: Vec<&str> = readme.lines().collect();
    let found = lines
        .windows(example.len())
        .any(|w| w.iter().zip(&example).all(|(a, b)| *a == b));
    assert!(
        found,
        "README.md does not show the tracker crate's example (src/lib.rs) line for line:\n{}",
        example.join("\n")
    );
}
