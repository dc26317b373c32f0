//! The reference check of `cargo xtask test`: every section or equation that a comment in the
//! Rust sources cites must exist in the document it cites, so that a reader with only the
//! repository can follow it (issue 19: the old design file outside the repository left
//! dozens of dangling citations).
//!
//! What counts as a citation, in the text of `//`, `///` and `//!` comments (consecutive full-line
//! comments are read as one text, so a citation broken over two lines is still seen):
//!
//! - a section sign followed by a number (`4`, `4.6`), or an equation label after "eq." /
//!   "eqs." (case-insensitive): a number or a capital and a number (`17`, `R1`), a range of
//!   either (`5-6`, `C4-C6`), and further labels joined by `/`, `,` or `and`;
//! - the document it points into is the last `*.md` name before it, looking back no further
//!   than the nearest parenthesis and at most 100 characters, or one right after it
//!   introduced by "of" or "in". A named document must be one of the repository's: the
//!   Markdown files under `docs/` and `protocol/PROTOCOL.md`;
//! - a citation whose nearest anchor is a work outside the repository ([`EXTERNAL`], e.g. the
//!   paper the filter follows) is not checked: the documents name those works;
//! - an equation with no document must be defined in one of the documents; a section with no
//!   document is broken (a bare section number names nothing).
//!
//! A label list stops at the first word between labels: in "eq. 7 (gyro), 12" only 7 is
//! checked.
//!
//! A document defines a section by a heading that starts with the section sign and its number,
//! or with the number and a dot (PROTOCOL.md's style), and an equation by bold text or a heading
//! that starts with "Eq." and its label.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::Path;

/// Works outside the repository that comments cite by their own sections and equations.
pub const EXTERNAL: &[&str] = &[
    "paper",
    "Lambda Twist",
    "Bar-Shalom",
    "data sheet",
    "DS-000347",
];

/// How far back a citation looks for its document when no parenthesis bounds it [chars].
const WINDOW: usize = 100;

/// The documents a citation may point into, with what each defines.
#[derive(Debug, Default)]
pub struct Docs {
    /// Path from the repository root (`docs/FILTER.md`) → its section and equation labels.
    docs: BTreeMap<String, Labels>,
}

/// Section and equation labels one document defines.
#[derive(Debug, Default)]
struct Labels {
    sections: BTreeSet<String>,
    equations: BTreeSet<String>,
}

/// A citation that names nothing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Broken {
    /// Source file, from the repository root.
    pub file: String,
    /// Line (from 1).
    pub line: usize,
    /// The citation as written, and why it is broken.
    pub what: String,
}

impl std::fmt::Display for Broken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}: {}", self.file, self.line, self.what)
    }
}

impl Docs {
    /// Adds a document's text under its path from the repository root.
    pub fn add(&mut self, path: &str, text: &str) {
        let mut labels = Labels::default();
        for line in text.lines() {
            let heading = line.trim_start().starts_with('#');
            let body = line.trim_start().trim_start_matches('#').trim_start();
            if heading {
                if let Some(rest) = body.strip_prefix('§') {
                    if let Some(l) = section_label(rest.trim_start()) {
                        labels.sections.insert(l);
                    }
                } else if let Some(l) = section_label(body)
                    && body[l.len()..].starts_with('.')
                {
                    labels.sections.insert(l);
                }
                if let Some(l) = after_prefix(body, "Eq.").and_then(equation_label) {
                    labels.equations.insert(l);
                }
            }
            let mut rest = line;
            while let Some(at) = rest.find("**Eq.") {
                rest = &rest[at + "**Eq.".len()..];
                if let Some(l) = equation_label(rest.trim_start()) {
                    labels.equations.insert(l);
                }
            }
        }
        self.docs.insert(path.to_string(), labels);
    }

    /// The document a citation's name means: the one whose path is the name or ends with it.
    fn resolve(&self, name: &str) -> Option<(&str, &Labels)> {
        self.docs
            .iter()
            .find(|(path, _)| {
                path.as_str() == name
                    || path.ends_with(&format!("/{}", name.trim_start_matches("./")))
            })
            .map(|(p, l)| (p.as_str(), l))
    }

    fn equation_anywhere(&self, label: &str) -> bool {
        self.docs.values().any(|l| l.equations.contains(label))
    }
}

/// `text` after `prefix`, compared case-insensitively.
fn after_prefix<'a>(text: &'a str, prefix: &str) -> Option<&'a str> {
    let head = text.get(..prefix.len())?;
    head.eq_ignore_ascii_case(prefix)
        .then(|| text[prefix.len()..].trim_start())
}

/// A section number at the start of `text`: digits, and dot-separated digits after them.
fn section_label(text: &str) -> Option<String> {
    let mut end = 0;
    let bytes = text.as_bytes();
    // A dot counts only between digits: `4.6` is one label, `6.` ends at the 6.
    while bytes.get(end).is_some_and(|&b| {
        b.is_ascii_digit()
            || (b == b'.' && end > 0 && bytes.get(end + 1).is_some_and(u8::is_ascii_digit))
    }) {
        end += 1;
    }
    (end > 0).then(|| text[..end].to_string())
}

/// One equation label at the start of `text`: `[A-Z]?digits`, or a range of two.
fn equation_label(text: &str) -> Option<String> {
    let one = |t: &str| -> Option<usize> {
        let b = t.as_bytes();
        let start = usize::from(b.first().is_some_and(u8::is_ascii_uppercase));
        let digits = b[start..].iter().take_while(|c| c.is_ascii_digit()).count();
        (digits > 0).then_some(start + digits)
    };
    let first = one(text)?;
    let mut end = first;
    if let Some(rest) = text[first..].strip_prefix('-')
        && let Some(second) = one(rest)
    {
        end = first + 1 + second;
    }
    Some(text[..end].to_string())
}

/// The last `*.md` name in `text`, with where it ends.
fn last_doc_name(text: &str) -> Option<(String, usize)> {
    let mut found = None;
    let mut from = 0;
    while let Some(at) = text[from..].find(".md") {
        let end = from + at + 3;
        let start = text[..from + at]
            .rfind(|c: char| !(c.is_alphanumeric() || "_-./".contains(c)))
            .map_or(0, |i| {
                i + text[i..].chars().next().map_or(1, char::len_utf8)
            });
        let after_ok = text[end..]
            .chars()
            .next()
            .is_none_or(|c| !c.is_alphanumeric());
        if start < from + at && after_ok {
            found = Some((text[start..end].to_string(), end));
        }
        from = end;
    }
    found
}

/// The last external work named in `text`, with where its name ends.
fn last_external(text: &str) -> Option<usize> {
    EXTERNAL
        .iter()
        .filter_map(|w| text.rfind(w).map(|at| at + w.len()))
        .max()
}

/// The comment texts of a Rust source: (text, line of each of its characters' byte offsets).
/// Consecutive full-line comments form one text; a trailing comment is a text of its own.
fn comments(source: &str) -> Vec<(String, Vec<(usize, usize)>)> {
    let mut out: Vec<(String, Vec<(usize, usize)>)> = Vec::new();
    let mut open = false;
    for (i, line) in source.lines().enumerate() {
        let trimmed = line.trim_start();
        let (text, full) = if trimmed.starts_with("//") {
            (
                trimmed.trim_start_matches('/').trim_start_matches('!'),
                true,
            )
        } else if let Some(at) = trailing_comment(line) {
            (&line[at + 2..], false)
        } else {
            open = false;
            continue;
        };
        if !(open && full) {
            out.push((String::new(), Vec::new()));
        }
        if let Some((buf, lines)) = out.last_mut() {
            if !buf.is_empty() {
                buf.push(' ');
            }
            lines.push((buf.len(), i + 1));
            buf.push_str(text.trim());
        }
        open = full;
    }
    out
}

/// Where a trailing `//` comment starts in a line of code: outside string literals (an even
/// number of quotes before it) and not part of a URL.
fn trailing_comment(line: &str) -> Option<usize> {
    let mut from = 0;
    while let Some(at) = line[from..].find("//") {
        let at = from + at;
        let quotes = line[..at].matches('"').count() - line[..at].matches("\\\"").count();
        if quotes & 1 == 0 && !line[..at].ends_with(':') {
            return Some(at);
        }
        from = at + 2;
    }
    None
}

/// The line of byte offset `at` in a comment text.
fn line_of(lines: &[(usize, usize)], at: usize) -> usize {
    lines
        .iter()
        .take_while(|(start, _)| *start <= at)
        .last()
        .map_or(0, |(_, l)| *l)
}

/// The citations of one source file that name nothing, and how many citations it has.
pub fn check_source(file: &str, source: &str, docs: &Docs) -> (usize, Vec<Broken>) {
    let mut broken = Vec::new();
    let mut count = 0;
    for (text, lines) in comments(source) {
        for (at, kind, labels, end) in citations(&text) {
            count += 1;
            let mut start = at.saturating_sub(WINDOW);
            while !text.is_char_boundary(start) {
                start += 1;
            }
            let before = &text[start..at];
            let before = match before.rfind(['(', ')']) {
                Some(p) => &before[p + 1..],
                None => before,
            };
            let written = &text[at..end];
            let after_name = ["of ", "in "]
                .iter()
                .find_map(|w| text[end..].trim_start().strip_prefix(w))
                .and_then(|t| {
                    let name: String = t
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || "_-./".contains(*c))
                        .collect();
                    let name = name.trim_end_matches(['.', ',']).to_string();
                    name.ends_with(".md").then_some(name)
                });
            let doc = last_doc_name(before);
            let external = last_external(before);
            let name = match (after_name, doc, external) {
                (Some(n), _, _) => Some(n),
                (None, Some((n, d)), e) if e.is_none_or(|e| d > e) => Some(n),
                (None, _, Some(_)) => continue,
                (None, _, None) => None,
            };
            let mut fail = |why: String| {
                broken.push(Broken {
                    file: file.to_string(),
                    line: line_of(&lines, at),
                    what: format!("`{written}`: {why}"),
                })
            };
            match name {
                Some(n) => match docs.resolve(&n) {
                    None => fail(format!("{n} is not a document of the repository")),
                    Some((path, l)) => {
                        for label in &labels {
                            let defined = match kind {
                                Kind::Section => l.sections.contains(label),
                                Kind::Equation => {
                                    equation_defined(label, |x| l.equations.contains(x))
                                }
                            };
                            if !defined {
                                fail(format!("{path} has no {} {label}", kind.noun()));
                            }
                        }
                    }
                },
                None => match kind {
                    Kind::Section => fail("a section with no document".to_string()),
                    Kind::Equation => {
                        for label in &labels {
                            if !equation_defined(label, |x| docs.equation_anywhere(x)) {
                                fail(format!("no document defines equation {label}"));
                            }
                        }
                    }
                },
            }
        }
    }
    (count, broken)
}

/// Whether `label` is defined, or, for a range that is not, both its ends (`C4-C6`).
fn equation_defined(label: &str, defined: impl Fn(&str) -> bool) -> bool {
    if defined(label) {
        return true;
    }
    match label.split_once('-') {
        Some((a, b)) => {
            // `R1-2` means `R1-R2`.
            let prefix: String = a.chars().take_while(char::is_ascii_uppercase).collect();
            let b = if b.starts_with(|c: char| c.is_ascii_digit()) {
                format!("{prefix}{b}")
            } else {
                b.to_string()
            };
            defined(a) && defined(&b)
        }
        None => false,
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Section,
    Equation,
}

impl Kind {
    fn noun(self) -> &'static str {
        match self {
            Kind::Section => "section",
            Kind::Equation => "equation",
        }
    }
}

/// The citations in a comment text: (start, kind, labels, end).
fn citations(text: &str) -> Vec<(usize, Kind, Vec<String>, usize)> {
    let mut out = Vec::new();
    for (at, c) in text.char_indices() {
        if c == '§' {
            let rest = &text[at + c.len_utf8()..];
            let lead = rest.len() - rest.trim_start_matches(' ').len();
            if let Some(l) = section_label(&rest[lead..]) {
                let end = at + c.len_utf8() + lead + l.len();
                out.push((at, Kind::Section, vec![l], end));
            }
            continue;
        }
        if !(c == 'e' || c == 'E') {
            continue;
        }
        if text[..at]
            .chars()
            .next_back()
            .is_some_and(char::is_alphanumeric)
        {
            continue;
        }
        let rest = &text[at..];
        let Some(after) = after_prefix(rest, "eqs.").or_else(|| after_prefix(rest, "eq.")) else {
            continue;
        };
        let mut pos = text.len() - after.len();
        let mut labels = Vec::new();
        let mut end = pos;
        while let Some(l) = equation_label(&text[pos..]) {
            pos += l.len();
            end = pos;
            labels.push(l);
            let tail = &text[pos..];
            let joined = ["/", ",", "and"].iter().find_map(|j| {
                let t = tail.trim_start();
                t.strip_prefix(j).map(|t| t.trim_start())
            });
            match joined {
                Some(t) if equation_label(t).is_some() => pos = text.len() - t.len(),
                _ => break,
            }
        }
        if !labels.is_empty() {
            out.push((at, Kind::Equation, labels, end));
        }
    }
    out
}

/// Loads the repository's documents: Markdown under `docs/`, and `protocol/PROTOCOL.md`.
pub fn load_docs(root: &Path) -> Result<Docs, String> {
    let mut docs = Docs::default();
    let mut files = Vec::new();
    walk(&root.join("docs"), "md", &mut files)?;
    files.push(root.join("protocol/PROTOCOL.md"));
    for f in files {
        let text = fs::read_to_string(&f).map_err(|e| format!("{}: {e}", f.display()))?;
        docs.add(&relative(root, &f), &text);
    }
    Ok(docs)
}

/// Checks every Rust source of the repository; returns how many citations resolved, or the
/// list of broken ones.
pub fn check(root: &Path) -> Result<usize, String> {
    let docs = load_docs(root)?;
    let mut sources = Vec::new();
    walk(root, "rs", &mut sources)?;
    sources.sort();
    let mut count = 0;
    let mut broken = Vec::new();
    for f in sources {
        let text = fs::read_to_string(&f).map_err(|e| format!("{}: {e}", f.display()))?;
        let (n, b) = check_source(&relative(root, &f), &text, &docs);
        count += n;
        broken.extend(b);
    }
    if broken.is_empty() {
        Ok(count)
    } else {
        let list: Vec<String> = broken.iter().map(ToString::to_string).collect();
        Err(format!(
            "{} of {count} references in comments name nothing in docs/ or PROTOCOL.md:\n  {}",
            broken.len(),
            list.join("\n  ")
        ))
    }
}

pub(crate) fn relative(root: &Path, f: &Path) -> String {
    f.strip_prefix(root)
        .unwrap_or(f)
        .to_string_lossy()
        .replace('\\', "/")
}

/// Files ending in `.ext` below `dir`, skipping build output and hidden folders.
pub(crate) fn walk(dir: &Path, ext: &str, out: &mut Vec<std::path::PathBuf>) -> Result<(), String> {
    let entries = fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries {
        let entry = entry.map_err(|e| format!("{}: {e}", dir.display()))?;
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if path.is_dir() {
            if !(name.starts_with('.') || name == "target") {
                walk(&path, ext, out)?;
            }
        } else if path.extension().is_some_and(|e| e == ext) {
            out.push(path);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn docs() -> Docs {
        let mut d = Docs::default();
        d.add(
            "docs/FILTER.md",
            "# Filter\n## §2 Frames\n## §9 Divergence\n**Eq. 5-6, pose** and **Eq. 17**: gate\n",
        );
        d.add(
            "docs/notes/issue15-cold-start.md",
            "## §6 Use\n- **Eq. C4, start.**\n- **Eq. C6, age.**\n",
        );
        d.add("docs/notes/issue14-registration.md", "## Eq. R1: fit\n");
        d.add("protocol/PROTOCOL.md", "## 6. Sizes\n");
        d
    }

    fn broken(source: &str) -> Vec<String> {
        check_source("x.rs", source, &docs())
            .1
            .into_iter()
            .map(|b| b.to_string())
            .collect()
    }

    #[test]
    fn citations_that_exist_pass() {
        // Lines as strings: written as comments here, the repository's own check would read
        // the deliberate breaks below as this file's citations.
        let src = [
            "//! Frames (docs/FILTER.md §2), divergence (docs/FILTER.md §9, paper §4.6).",
            "/// The gate (eq. 17) and the pose (eq. 5-6); sizes (PROTOCOL.md §6).",
            "/// The fit (eq. R1 of issue14-registration.md); the start (eqs. C4-C6,",
            "/// docs/notes/issue15-cold-start.md, §6).",
            "/// Lambda Twist eq. 4; the rate (Bar-Shalom, Li & Kirubarajan 2001, §6.2.2).",
            "let x = 1; // trailing: docs/FILTER.md §9 test 1",
            "let url = \"https://example.org/§1\";",
        ]
        .join("\n");
        let src = src.as_str();
        assert_eq!(broken(src), Vec::<String>::new());
        assert_eq!(check_source("x.rs", src, &docs()).0, 12);
    }

    /// The deliberate breaks: a section the document lacks, an equation no document has, a
    /// document outside the repository, a bare section, and a citation split over two lines.
    #[test]
    fn broken_citations_fail() {
        let src = [
            "/// See docs/FILTER.md §4 and (eq. 99).",
            "// The design (DESIGN.md §3).",
            "//! The paper's test cases (§5).",
            "/// Quaternion test (docs/FILTER.md",
            "/// §12, test 3), gate eq. 17 / 18.",
        ]
        .join("\n");
        let src = src.as_str();
        assert_eq!(
            broken(src),
            [
                "x.rs:1: `§4`: docs/FILTER.md has no section 4",
                "x.rs:1: `eq. 99`: no document defines equation 99",
                "x.rs:2: `§3`: DESIGN.md is not a document of the repository",
                "x.rs:3: `§5`: a section with no document",
                "x.rs:5: `§12`: docs/FILTER.md has no section 12",
                "x.rs:5: `eq. 17 / 18`: no document defines equation 18",
            ]
        );
    }

    #[test]
    fn a_range_needs_both_ends() {
        assert_eq!(
            broken("/// (eqs. C4-C5 of issue15-cold-start.md)"),
            ["x.rs:1: `eqs. C4-C5`: docs/notes/issue15-cold-start.md has no equation C4-C5"]
        );
    }

    /// The repository itself: what `cargo xtask test` runs.
    #[test]
    fn the_repositorys_references_resolve() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .expect("xtask lives one level below the workspace root");
        if let Err(e) = check(root) {
            panic!("{e}");
        }
    }
}
