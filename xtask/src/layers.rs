//! The layering check of `cargo xtask test` (issue 19): in each of the module trees of
//! [`TREES`] no module uses, directly or through others, a module that uses it, so that each
//! tree reads in one order, bottom up. The check prints that order (docs/ARCHITECTURE.md §4
//! names fusion-core's) and fails naming the modules of a cycle, in order, with the line of each
//! reference on the way round.
//!
//! The graph of a tree, kept simple on purpose:
//!
//! - a node per module file, its module path from its location: the tree's `lib.rs` or `mod.rs`
//!   is the tree's root (shown as `crate`, or the tree's module name), `a.rs` and `a/mod.rs` are
//!   `a`, `a/b.rs` is `a::b`. An inline module (`mod tests { … }`) belongs to its file;
//! - an edge from a file to each other module of the tree that its code names with a path that
//!   starts with `crate::` or `super::` (an inline module's `super` is its file): in `use`
//!   declarations (groups, `self`, globs and renames included) and anywhere else in code
//!   (`crate::init::reset_covariance(…)`), test code included;
//! - a path goes to the longest module it names (`crate::models::correspondence::update` to
//!   `models::correspondence`). If the next name is an item that module re-exports, the edge goes
//!   to the module the item comes from instead, when that is simple to know: a `pub use` of a
//!   path of the tree names it, or exactly one `pub use …::*` of the module comes from a module
//!   that defines it at its top level (`fn`, `struct`, `const`, …). Otherwise the edge goes to the
//!   module the path names (often a parent);
//! - not read: comments (a doc link may point up the layers, as a book may refer ahead), string
//!   and character literals, `$crate` paths in macros, `pub(in crate::…)` visibilities, and
//!   relative paths (`self::x`, `child::x`, other crates). A parent module reaches its own
//!   children by relative paths, so what a parent takes from its children is not checked, only
//!   what the children and the parent's other users take from it.
//!
//! The order printed groups the modules in layers: a module that uses none of the others is in
//! the first, any other one layer above the highest module it uses. Modules no edge touches (a
//! crate root that only declares and re-exports its modules, a `mod.rs` of declarations) are
//! listed apart.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fs;
use std::path::Path;

use crate::references::{relative, walk};

/// A module tree: its folder from the repository root, and that folder's module path in its
/// crate (empty for a crate's `src`).
pub struct Tree {
    /// Name in messages.
    pub name: &'static str,
    /// Folder from the repository root.
    pub dir: &'static str,
    /// Module path of the folder.
    pub module: &'static [&'static str],
}

/// The trees the check covers.
pub const TREES: &[Tree] = &[
    Tree {
        name: "fusion-core",
        dir: "fusion-core/src",
        module: &[],
    },
    Tree {
        name: "protocol",
        dir: "protocol/src",
        module: &[],
    },
    Tree {
        name: "icm42688",
        dir: "drivers/icm42688/src",
        module: &[],
    },
    Tree {
        name: "sample-path",
        dir: "sample-path/src",
        module: &[],
    },
    Tree {
        name: "isa",
        dir: "host/isa/src",
        module: &[],
    },
    Tree {
        name: "camera",
        dir: "host/camera/src",
        module: &[],
    },
    Tree {
        name: "model",
        dir: "host/model/src",
        module: &[],
    },
    Tree {
        name: "render",
        dir: "host/render/src",
        module: &[],
    },
    Tree {
        name: "features",
        dir: "host/features/src",
        module: &[],
    },
    Tree {
        name: "contour",
        dir: "host/contour/src",
        module: &[],
    },
    Tree {
        name: "vision",
        dir: "host/vision/src",
        module: &[],
    },
    Tree {
        name: "locate",
        dir: "host/locate/src",
        module: &[],
    },
    Tree {
        name: "tracker",
        dir: "host/tracker/src",
        module: &[],
    },
    Tree {
        name: "frames",
        dir: "host/frames/src",
        module: &[],
    },
    Tree {
        name: "vitracker (Python)",
        dir: "python/src",
        module: &[],
    },
    Tree {
        name: "host-vision track",
        dir: "host-vision/src/track",
        module: &["track"],
    },
];

/// A token of Rust source, comments and literals removed.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Tok {
    Ident(String),
    /// `::`
    Sep,
    Punct(char),
}

/// The character at `i`, or `'\0'` past the end.
fn char_at(c: &[char], i: usize) -> char {
    c.get(i).copied().unwrap_or('\0')
}

/// Whether `ch` may start an identifier.
fn ident_start(ch: char) -> bool {
    ch == '_' || ch.is_alphabetic()
}

/// Whether `ch` may continue an identifier.
fn ident_char(ch: char) -> bool {
    ch == '_' || ch.is_alphanumeric()
}

/// Skips identifier characters from `i`; returns the index after them.
fn skip_ident(c: &[char], mut i: usize) -> usize {
    while i < c.len() && ident_char(c[i]) {
        i += 1;
    }
    i
}

/// Skips a string whose opening quote is at `i` (escapes honoured), counting its newlines
/// into `line`; returns the index after it.
fn skip_string(c: &[char], mut i: usize, line: &mut usize) -> usize {
    i += 1;
    while i < c.len() {
        match c[i] {
            '\\' => {
                if char_at(c, i + 1) == '\n' {
                    *line += 1;
                }
                i += 2;
            }
            '"' => return i + 1,
            ch => {
                if ch == '\n' {
                    *line += 1;
                }
                i += 1;
            }
        }
    }
    i
}

/// Skips a raw string whose `r` is at `i`, counting its newlines into `line`; returns the
/// index after it.
fn skip_raw(c: &[char], mut i: usize, line: &mut usize) -> usize {
    i += 1;
    let mut hashes = 0;
    while char_at(c, i) == '#' {
        hashes += 1;
        i += 1;
    }
    i += 1; // the opening quote
    while i < c.len() {
        if c[i] == '"' && (1..=hashes).all(|h| char_at(c, i + h) == '#') {
            return i + 1 + hashes;
        }
        if c[i] == '\n' {
            *line += 1;
        }
        i += 1;
    }
    i
}

/// Skips a character literal whose quote is at `i`, or returns `None` for a lifetime.
fn skip_char(c: &[char], i: usize) -> Option<usize> {
    if char_at(c, i + 1) == '\\' {
        let mut j = i + 3;
        while j < c.len() && c[j] != '\'' && c[j] != '\n' {
            j += 1;
        }
        Some(j + 1)
    } else if char_at(c, i + 2) == '\'' {
        Some(i + 3)
    } else {
        None
    }
}

/// Skips a block comment whose `/*` is at `i` (nested ones too), counting its newlines into
/// `line`; returns the index after it.
fn skip_block_comment(c: &[char], mut i: usize, line: &mut usize) -> usize {
    let mut depth = 1;
    i += 2;
    while i < c.len() && depth > 0 {
        if c[i] == '/' && char_at(c, i + 1) == '*' {
            depth += 1;
            i += 2;
        } else if c[i] == '*' && char_at(c, i + 1) == '/' {
            depth -= 1;
            i += 2;
        } else {
            if c[i] == '\n' {
                *line += 1;
            }
            i += 1;
        }
    }
    i
}

/// The tokens of `src` that matter for paths, with their lines (from 1). Comments (nested
/// block comments too), strings (raw and byte strings too) and character literals are dropped;
/// lifetimes become identifiers, which is harmless here.
fn tokens(src: &str) -> Vec<(Tok, usize)> {
    let c: Vec<char> = src.chars().collect();
    let at = |i: usize| char_at(&c, i);
    let mut out = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < c.len() {
        let ch = c[i];
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch == '/' && at(i + 1) == '*' {
            i = skip_block_comment(&c, i, &mut line);
        } else if ch == '"' {
            i = skip_string(&c, i, &mut line);
        } else if ch == '\'' {
            match skip_char(&c, i) {
                Some(j) => i = j,
                None => i += 1,
            }
        } else if ch == 'b' && at(i + 1) == '"' {
            i = skip_string(&c, i + 1, &mut line);
        } else if ch == 'b' && at(i + 1) == '\'' {
            i = skip_char(&c, i + 1).unwrap_or(i + 2);
        } else if ch == 'b' && at(i + 1) == 'r' && matches!(at(i + 2), '"' | '#') {
            i = skip_raw(&c, i + 1, &mut line);
        } else if ch == 'r'
            && (at(i + 1) == '"' || (at(i + 1) == '#' && matches!(at(i + 2), '"' | '#')))
        {
            i = skip_raw(&c, i, &mut line);
        } else if ch == 'r' && at(i + 1) == '#' && ident_start(at(i + 2)) {
            // A raw identifier.
            let start = i + 2;
            i = skip_ident(&c, start);
            out.push((Tok::Ident(c[start..i].iter().collect()), line));
        } else if ident_start(ch) {
            let start = i;
            i = skip_ident(&c, start);
            out.push((Tok::Ident(c[start..i].iter().collect()), line));
        } else if ch.is_ascii_digit() {
            i = skip_ident(&c, i);
        } else if ch == ':' && at(i + 1) == ':' {
            out.push((Tok::Sep, line));
            i += 2;
        } else {
            out.push((Tok::Punct(ch), line));
            i += 1;
        }
    }
    out
}

fn is_ident(t: Option<&(Tok, usize)>, name: &str) -> bool {
    matches!(t, Some((Tok::Ident(s), _)) if s == name)
}

fn ident_of(t: Option<&(Tok, usize)>) -> Option<&str> {
    match t {
        Some((Tok::Ident(s), _)) => Some(s),
        _ => None,
    }
}

fn is_punct(t: Option<&(Tok, usize)>, p: char) -> bool {
    matches!(t, Some((Tok::Punct(q), _)) if *q == p)
}

/// One leaf of a `use` tree: its path as written, its name where it is used (`as` renames),
/// or `None` for a glob.
#[derive(Clone, Debug, PartialEq, Eq)]
struct UseLeaf {
    path: Vec<String>,
    name: Option<String>,
}

/// Parses the `use` tree starting at `k`, below `prefix`; returns the index after it.
fn use_tree(
    toks: &[(Tok, usize)],
    mut k: usize,
    prefix: Vec<String>,
    out: &mut Vec<UseLeaf>,
) -> usize {
    let mut path = prefix;
    if matches!(toks.get(k), Some((Tok::Sep, _))) {
        k += 1;
    }
    loop {
        match toks.get(k) {
            Some((Tok::Ident(s), _)) => {
                path.push(s.clone());
                k += 1;
                if matches!(toks.get(k), Some((Tok::Sep, _))) {
                    k += 1;
                    continue;
                }
                let mut name = path.last().cloned();
                if name.as_deref() == Some("self") {
                    path.pop();
                    name = path.last().cloned();
                }
                if is_ident(toks.get(k), "as") {
                    name = ident_of(toks.get(k + 1)).map(str::to_string);
                    k += 2;
                }
                out.push(UseLeaf { path, name });
                return k;
            }
            Some((Tok::Punct('*'), _)) => {
                out.push(UseLeaf { path, name: None });
                return k + 1;
            }
            Some((Tok::Punct('{'), _)) => {
                k += 1;
                loop {
                    match toks.get(k) {
                        None => return k,
                        Some((Tok::Punct('}'), _)) => return k + 1,
                        Some((Tok::Punct(','), _)) => k += 1,
                        Some(_) => {
                            let next = use_tree(toks, k, path.clone(), out);
                            // Malformed input: never loop in place.
                            k = next.max(k + 1);
                        }
                    }
                }
            }
            _ => return k,
        }
    }
}

/// What one module file says: its references to paths, its re-exports, its top-level items.
#[derive(Debug, Default)]
struct Reads {
    /// (path as written, module path where it is written, line).
    refs: Vec<(Vec<String>, Vec<String>, usize)>,
    /// `pub use` leaves at the top level (path as written).
    reexports: Vec<UseLeaf>,
    /// Names the file defines at its top level.
    defines: BTreeSet<String>,
}

/// Reads one module file of module path `module`.
fn read(source: &str, module: &[String]) -> Reads {
    let toks = tokens(source);
    let mut reads = Reads::default();
    let mut depth = 0usize;
    // Inline modules open at this point, with the brace depth inside each.
    let mut inline: Vec<(String, usize)> = Vec::new();
    let here = |inline: &[(String, usize)]| -> Vec<String> {
        let mut m = module.to_vec();
        m.extend(inline.iter().map(|(n, _)| n.clone()));
        m
    };
    let mut k = 0;
    while k < toks.len() {
        let (tok, line) = &toks[k];
        match tok {
            Tok::Punct('{') => depth += 1,
            Tok::Punct('}') => {
                depth = depth.saturating_sub(1);
                while inline.last().is_some_and(|(_, d)| *d > depth) {
                    inline.pop();
                }
            }
            Tok::Ident(kw) if kw == "mod" => {
                if let (Some(name), true) =
                    (ident_of(toks.get(k + 1)), is_punct(toks.get(k + 2), '{'))
                {
                    inline.push((name.to_string(), depth + 1));
                }
            }
            Tok::Ident(kw) if kw == "use" => {
                let public = match k.checked_sub(1).map(|p| &toks[p].0) {
                    Some(Tok::Ident(p)) => p == "pub",
                    // `pub(crate) use`: back over the parenthesis.
                    Some(Tok::Punct(')')) => toks[..k]
                        .iter()
                        .rposition(|(t, _)| *t == Tok::Punct('('))
                        .and_then(|p| p.checked_sub(1))
                        .is_some_and(|p| is_ident(toks.get(p), "pub")),
                    _ => false,
                };
                let mut leaves = Vec::new();
                let end = use_tree(&toks, k + 1, Vec::new(), &mut leaves);
                let m = here(&inline);
                for leaf in &leaves {
                    reads.refs.push((leaf.path.clone(), m.clone(), *line));
                }
                if public && inline.is_empty() && depth == 0 {
                    reads.reexports.extend(leaves);
                }
                k = end.max(k + 1);
                continue;
            }
            Tok::Ident(kw)
                if (kw == "crate" || kw == "super")
                    && matches!(toks.get(k + 1), Some((Tok::Sep, _))) =>
            {
                let before = |back: usize| k.checked_sub(back).map(|p| &toks[p]);
                // `$crate::…` in a macro, and `pub(in crate::…)` (not `for x in crate::…`).
                let skipped = is_punct(before(1), '$')
                    || (is_ident(before(1), "in")
                        && is_punct(before(2), '(')
                        && is_ident(before(3), "pub"));
                let mut path = vec![kw.clone()];
                let mut j = k + 1;
                while matches!(toks.get(j), Some((Tok::Sep, _))) {
                    match ident_of(toks.get(j + 1)) {
                        Some(s) => {
                            path.push(s.to_string());
                            j += 2;
                        }
                        None => break,
                    }
                }
                if !skipped {
                    reads.refs.push((path, here(&inline), *line));
                }
                k = j;
                continue;
            }
            Tok::Ident(kw) if depth == 0 && inline.is_empty() => {
                const ITEMS: &[&str] = &[
                    "fn", "struct", "enum", "const", "static", "type", "trait", "union", "mod",
                ];
                let name = if kw == "macro_rules" && is_punct(toks.get(k + 1), '!') {
                    ident_of(toks.get(k + 2))
                } else if ITEMS.contains(&kw.as_str()) {
                    ident_of(toks.get(k + 1))
                } else {
                    None
                };
                if let Some(n) = name.filter(|n| !ITEMS.contains(n) && *n != "_") {
                    reads.defines.insert(n.to_string());
                }
            }
            _ => {}
        }
        k += 1;
    }
    reads
}

/// The module path of a file at `rel` (from the tree's folder, `/`-separated), below the
/// tree's module path.
fn module_of(tree_module: &[String], rel: &str) -> Vec<String> {
    let mut parts: Vec<&str> = rel.split('/').collect();
    let file = parts.pop().unwrap_or_default();
    let mut m = tree_module.to_vec();
    m.extend(parts.iter().map(|p| p.to_string()));
    let top = m.len() == tree_module.len();
    match file {
        "mod.rs" => {}
        "lib.rs" | "main.rs" if top => {}
        f => m.push(f.trim_end_matches(".rs").to_string()),
    }
    m
}

/// A `crate::` or `super::` path as written, made absolute (from the crate root) where it is
/// written in `module`: `None` for other paths and for a `super` above the crate.
fn absolute(path: &[String], module: &[String]) -> Option<Vec<String>> {
    match path.first().map(String::as_str) {
        Some("crate") => Some(path[1..].to_vec()),
        Some("super") => {
            let mut m = module.to_vec();
            let mut i = 0;
            while path.get(i).map(String::as_str) == Some("super") {
                m.pop()?;
                i += 1;
            }
            m.extend(path[i..].iter().cloned());
            Some(m)
        }
        _ => None,
    }
}

/// One reference that makes an edge: where it is, and how it is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reference {
    /// The file, from the repository root.
    pub file: String,
    /// Line (from 1).
    pub line: usize,
    /// The path as written.
    pub written: String,
}

/// The module graph of one tree.
#[derive(Debug)]
pub struct Graph {
    /// Module names (paths below the tree's module; the root as `crate` or the tree's name).
    pub names: Vec<String>,
    /// Edges `from → to` (the user first), each with its first reference.
    pub edges: BTreeMap<(usize, usize), Reference>,
}

/// Re-exports of each module as absolute paths: by name, and the globs' source modules.
struct Reexports {
    /// Per module: the name it re-exports → the path the item comes from.
    named: Vec<BTreeMap<String, Vec<String>>>,
    /// Per module: the modules its `pub use …::*` come from.
    globs: Vec<Vec<Vec<String>>>,
}

/// Module names as shown: paths below the tree's module, the tree's root as `crate` or the
/// tree's module name.
fn module_names(tree_module: &[String], modules: &[Vec<String>]) -> Vec<String> {
    modules
        .iter()
        .map(|m| {
            if m.len() == tree_module.len() {
                tree_module
                    .last()
                    .cloned()
                    .unwrap_or_else(|| "crate".to_string())
            } else {
                m[tree_module.len()..].join("::")
            }
        })
        .collect()
}

/// The re-exports of each module (of `modules`, read as `reads`) that name paths of the tree,
/// made absolute.
fn reexports(
    reads: &[Reads],
    modules: &[Vec<String>],
    index: &BTreeMap<Vec<String>, usize>,
) -> Reexports {
    let mut named: Vec<BTreeMap<String, Vec<String>>> = vec![BTreeMap::new(); reads.len()];
    let mut globs: Vec<Vec<Vec<String>>> = vec![Vec::new(); reads.len()];
    for (i, r) in reads.iter().enumerate() {
        for leaf in &r.reexports {
            let abs = absolute(&leaf.path, &modules[i]).or_else(|| {
                // A relative path (`self::child::X`, `child::X`) into a child module of this one.
                let rel = match leaf.path.first().map(String::as_str) {
                    Some("self") => &leaf.path[1..],
                    _ => &leaf.path[..],
                };
                let mut p = modules[i].clone();
                p.extend(rel.iter().cloned());
                let child = p.get(..modules[i].len() + 1)?;
                index.contains_key(child).then_some(p)
            });
            let Some(abs) = abs else { continue };
            match &leaf.name {
                Some(n) => {
                    named[i].insert(n.clone(), abs);
                }
                None => globs[i].push(abs),
            }
        }
    }
    Reexports { named, globs }
}

/// The module a path (absolute) names, following re-exports a few steps; `None` for a path
/// outside the tree's modules.
fn target(
    abs: &[String],
    tree_module: &[String],
    index: &BTreeMap<Vec<String>, usize>,
    reads: &[Reads],
    reexports: &Reexports,
) -> Option<usize> {
    let mut abs = abs.to_vec();
    let mut found = None;
    for _ in 0..4 {
        if !abs.starts_with(tree_module) {
            return found;
        }
        let Some((len, m)) = (0..=abs.len())
            .rev()
            .find_map(|len| index.get(&abs[..len]).map(|&m| (len, m)))
        else {
            return found;
        };
        found = Some(m);
        let Some(name) = abs.get(len).cloned() else {
            return found;
        };
        if let Some(src) = reexports.named[m].get(&name) {
            abs = src.clone();
            continue;
        }
        let sources: Vec<&Vec<String>> = reexports.globs[m]
            .iter()
            .filter(|g| {
                index
                    .get(*g)
                    .is_some_and(|&s| reads[s].defines.contains(&name))
            })
            .collect();
        match sources.as_slice() {
            [one] => {
                abs = one.to_vec();
                abs.push(name);
            }
            _ => return found,
        }
    }
    found
}

/// Builds the graph of a tree of module path `tree_module` from its files: (path from the
/// tree's folder, path shown in messages, source).
pub fn graph(tree_module: &[&str], files: &[(String, String, String)]) -> Graph {
    let tree_module: Vec<String> = tree_module.iter().map(|s| s.to_string()).collect();
    let mut modules: Vec<Vec<String>> = Vec::new();
    let mut reads = Vec::new();
    for (rel, _, source) in files {
        let m = module_of(&tree_module, rel);
        reads.push(read(source, &m));
        modules.push(m);
    }
    let index: BTreeMap<Vec<String>, usize> = modules
        .iter()
        .enumerate()
        .map(|(i, m)| (m.clone(), i))
        .collect();
    let names = module_names(&tree_module, &modules);
    let reexports = reexports(&reads, &modules, &index);
    let mut edges = BTreeMap::new();
    for (i, r) in reads.iter().enumerate() {
        for (path, module, line) in &r.refs {
            let Some(abs) = absolute(path, module) else {
                continue;
            };
            let Some(to) = target(&abs, &tree_module, &index, &reads, &reexports) else {
                continue;
            };
            if to != i {
                edges.entry((i, to)).or_insert_with(|| Reference {
                    file: files[i].1.clone(),
                    line: *line,
                    written: path.join("::"),
                });
            }
        }
    }
    Graph { names, edges }
}

impl Graph {
    fn uses(&self, from: usize) -> impl Iterator<Item = usize> + '_ {
        self.edges
            .range((from, 0)..=(from, usize::MAX))
            .map(|(&(_, to), _)| to)
    }

    /// The sets of modules that use each other (strongly connected components), each sorted
    /// by name, with its shortest cycle through its first module by name, in order.
    pub fn cycles(&self) -> Vec<(Vec<usize>, Vec<usize>)> {
        let n = self.names.len();
        // Tarjan's algorithm, iterative over an explicit stack.
        let mut index = vec![usize::MAX; n];
        let mut low = vec![0; n];
        let mut on_stack = vec![false; n];
        let mut stack = Vec::new();
        let mut next = 0;
        let mut components = Vec::new();
        for start in 0..n {
            if index[start] != usize::MAX {
                continue;
            }
            let mut work: Vec<(usize, Vec<usize>)> = vec![(start, self.uses(start).collect())];
            index[start] = next;
            low[start] = next;
            next += 1;
            stack.push(start);
            on_stack[start] = true;
            while let Some((v, pending)) = work.last_mut() {
                let v = *v;
                if let Some(w) = pending.pop() {
                    if index[w] == usize::MAX {
                        index[w] = next;
                        low[w] = next;
                        next += 1;
                        stack.push(w);
                        on_stack[w] = true;
                        work.push((w, self.uses(w).collect()));
                    } else if on_stack[w] {
                        low[v] = low[v].min(index[w]);
                    }
                    continue;
                }
                work.pop();
                if let Some((parent, _)) = work.last() {
                    low[*parent] = low[*parent].min(low[v]);
                }
                if low[v] == index[v] {
                    let mut component = Vec::new();
                    while let Some(w) = stack.pop() {
                        on_stack[w] = false;
                        component.push(w);
                        if w == v {
                            break;
                        }
                    }
                    if component.len() > 1 {
                        components.push(component);
                    }
                }
            }
        }
        let mut cycles: Vec<(Vec<usize>, Vec<usize>)> = components
            .into_iter()
            .map(|component| {
                let inside: BTreeSet<usize> = component.iter().copied().collect();
                let first = *inside
                    .iter()
                    .min_by_key(|&&m| &self.names[m])
                    .expect("a component has modules");
                // Breadth first from `first` back to it, within the component.
                let mut came_from = BTreeMap::new();
                let mut queue = VecDeque::from([first]);
                let mut last = None;
                'search: while let Some(v) = queue.pop_front() {
                    let mut next: Vec<usize> =
                        self.uses(v).filter(|w| inside.contains(w)).collect();
                    next.sort_by_key(|&w| &self.names[w]);
                    for w in next {
                        if w == first {
                            last = Some(v);
                            break 'search;
                        }
                        if let std::collections::btree_map::Entry::Vacant(e) = came_from.entry(w) {
                            e.insert(v);
                            queue.push_back(w);
                        }
                    }
                }
                let mut cycle = vec![first];
                let mut v = last.expect("a component of two or more modules has a cycle");
                while v != first {
                    cycle.push(v);
                    v = came_from[&v];
                }
                cycle[1..].reverse();
                let mut members: Vec<usize> = inside.into_iter().collect();
                members.sort_by_key(|&m| &self.names[m]);
                (members, cycle)
            })
            .collect();
        cycles.sort_by_key(|(_, c)| self.names[c[0]].clone());
        cycles
    }

    /// A cycle in words: the modules in order back to the first, and each reference on the way.
    pub fn describe(&self, cycle: &[usize]) -> String {
        let mut order: Vec<&str> = cycle.iter().map(|&m| self.names[m].as_str()).collect();
        order.push(&self.names[cycle[0]]);
        let mut out = order.join(" → ");
        for (k, &from) in cycle.iter().enumerate() {
            let to = cycle[(k + 1) % cycle.len()];
            let r = &self.edges[&(from, to)];
            out.push_str(&format!(
                "\n      {} → {}: {}:{} `{}`",
                self.names[from], self.names[to], r.file, r.line, r.written
            ));
        }
        out
    }

    /// The modules no reference of the tree leads to or from (a crate root or a `mod.rs` that
    /// only declares and re-exports its children), by name.
    pub fn unconnected(&self) -> Vec<String> {
        let mut linked = BTreeSet::new();
        for &(a, b) in self.edges.keys() {
            linked.insert(a);
            linked.insert(b);
        }
        let mut out: Vec<String> = (0..self.names.len())
            .filter(|m| !linked.contains(m))
            .map(|m| self.names[m].clone())
            .collect();
        out.sort();
        out
    }

    /// The layers, bottom up (names sorted within a layer), if there is no cycle; without the
    /// [`Self::unconnected`] modules.
    pub fn layers(&self) -> Option<Vec<Vec<String>>> {
        if !self.cycles().is_empty() {
            return None;
        }
        fn layer(g: &Graph, m: usize, memo: &mut Vec<Option<usize>>) -> usize {
            if let Some(l) = memo[m] {
                return l;
            }
            let l = g.uses(m).map(|w| layer(g, w, memo) + 1).max().unwrap_or(0);
            memo[m] = Some(l);
            l
        }
        let mut memo = vec![None; self.names.len()];
        let mut layers: Vec<Vec<String>> = Vec::new();
        let unconnected = self.unconnected();
        for m in 0..self.names.len() {
            if unconnected.contains(&self.names[m]) {
                continue;
            }
            let l = layer(self, m, &mut memo);
            if layers.len() <= l {
                layers.resize(l + 1, Vec::new());
            }
            layers[l].push(self.names[m].clone());
        }
        for l in &mut layers {
            l.sort();
        }
        Some(layers)
    }
}

/// A tree's layering: its layers bottom up, and the modules outside them.
#[derive(Debug)]
pub struct Layering {
    /// The tree's name.
    pub tree: &'static str,
    /// [`Graph::layers`].
    pub layers: Vec<Vec<String>>,
    /// [`Graph::unconnected`].
    pub unconnected: Vec<String>,
}

impl std::fmt::Display for Layering {
    /// One numbered line per layer, then the unconnected modules.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (k, l) in self.layers.iter().enumerate() {
            writeln!(f, "  {:2}. {}", k + 1, l.join(", "))?;
        }
        write!(
            f,
            "  (using none of the others and used by none: {})",
            if self.unconnected.is_empty() {
                "-".to_string()
            } else {
                self.unconnected.join(", ")
            }
        )
    }
}

/// Checks every tree of [`TREES`]; returns each tree's layering, or the cycles.
pub fn check(root: &Path) -> Result<Vec<Layering>, String> {
    let mut orders = Vec::new();
    let mut failures = Vec::new();
    for tree in TREES {
        let dir = root.join(tree.dir);
        let mut paths = Vec::new();
        walk(&dir, "rs", &mut paths)?;
        paths.sort();
        let mut files = Vec::new();
        for p in &paths {
            let source = fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            files.push((relative(&dir, p), relative(root, p), source));
        }
        let g = graph(tree.module, &files);
        // A tree that reads as no modules, or as modules that use nothing of each other, would
        // pass whatever its imports: that is the reader broken or the tree moved, not a layering.
        if g.names.len() < 2 || g.edges.is_empty() {
            failures.push(format!(
                "{}: read {} module files and {} references between them in {}: \
                 the check reads nothing there (has the tree moved?)",
                tree.name,
                g.names.len(),
                g.edges.len(),
                tree.dir
            ));
            continue;
        }
        let cycles = g.cycles();
        if !cycles.is_empty() {
            for (members, cycle) in &cycles {
                let names: Vec<&str> = members.iter().map(|&m| g.names[m].as_str()).collect();
                failures.push(format!(
                    "{}: {} modules use each other ({}), for one in the cycle {}",
                    tree.name,
                    members.len(),
                    names.join(", "),
                    g.describe(cycle)
                ));
            }
            continue;
        }
        orders.push(Layering {
            tree: tree.name,
            layers: g.layers().expect("no cycle"),
            unconnected: g.unconnected(),
        });
    }
    if failures.is_empty() {
        Ok(orders)
    } else {
        Err(format!(
            "the module layering has cycles (issue 19; docs/ARCHITECTURE.md §4):\n  {}",
            failures.join("\n  ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tree(files: &[(&str, &str)]) -> Graph {
        let files: Vec<(String, String, String)> = files
            .iter()
            .map(|(p, s)| (p.to_string(), format!("src/{p}"), s.to_string()))
            .collect();
        graph(&[], &files)
    }

    fn edges(g: &Graph) -> Vec<String> {
        g.edges
            .keys()
            .map(|&(a, b)| format!("{} → {}", g.names[a], g.names[b]))
            .collect()
    }

    /// A deliberate cycle: `a` uses `c` through a group, `c` uses `b` in code, `b` uses `a`
    /// through `super` of a nested module; the cycle is found and named in order, with where
    /// each reference is. `d` uses the cycle and is not part of it.
    #[test]
    fn a_cycle_is_found_and_named() {
        let g = tree(&[
            ("lib.rs", "mod a;\nmod b;\nmod c;\nmod d;\n"),
            ("a.rs", "use crate::{c::{self, Thing as Other}};\n"),
            ("b/mod.rs", "pub mod inner;\n"),
            ("b/inner.rs", "pub fn f() { super::super::a::g(); }\n"),
            ("c.rs", "fn h() {\n    crate::b::inner::f();\n}\n"),
            ("d.rs", "use crate::a::g;\n"),
        ]);
        let cycles = g.cycles();
        assert_eq!(cycles.len(), 1, "{:?}", edges(&g));
        let (members, cycle) = &cycles[0];
        let names: Vec<&str> = members.iter().map(|&m| g.names[m].as_str()).collect();
        assert_eq!(names, ["a", "b::inner", "c"]);
        assert_eq!(
            g.describe(cycle),
            "a → c → b::inner → a\n      \
             a → c: src/a.rs:1 `crate::c`\n      \
             c → b::inner: src/c.rs:2 `crate::b::inner::f`\n      \
             b::inner → a: src/b/inner.rs:1 `super::super::a::g`"
        );
        assert!(g.layers().is_none());
    }

    /// The same modules without the back edge: no cycle, and layers bottom up.
    #[test]
    fn an_acyclic_tree_passes_with_its_layers() {
        let g = tree(&[
            ("lib.rs", "pub mod a;\npub mod b;\npub use b::Thing;\n"),
            (
                "a.rs",
                "//! Uses [`crate::b::Thing`] in a doc link only.\nconst S: &str = \"crate::b::x\";\n",
            ),
            ("b/mod.rs", "pub mod inner;\npub use inner::Thing;\n"),
            (
                "b/inner.rs",
                "use crate::a;\npub struct Thing;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n",
            ),
            ("c.rs", "use crate::Thing;\nuse super::b;\n"),
        ]);
        assert!(g.cycles().is_empty());
        assert_eq!(edges(&g), ["b::inner → a", "c → b", "c → b::inner"]);
        assert_eq!(
            g.layers().unwrap(),
            [
                vec!["a".to_string(), "b".to_string()],
                vec!["b::inner".to_string()],
                vec!["c".to_string()],
            ]
        );
        assert_eq!(g.unconnected(), ["crate"]);
    }

    /// Comments, strings, characters, lifetimes, `$crate`, visibilities and relative paths
    /// make no edge; inline modules' `super` is their file; globs re-exported at the root
    /// resolve to the module defining the name.
    #[test]
    fn what_is_not_an_edge() {
        let g = tree(&[
            (
                "lib.rs",
                "pub mod a;\npub mod b;\npub mod c;\npub use a::*;\npub use b::*;\n",
            ),
            (
                "a.rs",
                "/* crate::b::X /* nested */ crate::b::Y */\n\
                 pub(in crate::b) fn f<'a>(s: &'a str) -> char { let _ = r#\"crate::b::\"#; '\"' }\n\
                 macro_rules! m { () => { $crate::b::X } }\n\
                 use b::X;\n\
                 pub const LIMIT: usize = 1;\n\
                 mod tests { use super::*; use self::inner::Z; }\n",
            ),
            ("b.rs", "pub struct X;\n"),
            ("c.rs", "const K: usize = crate::LIMIT;\nuse crate::X;\n"),
            ("d.rs", "fn g() { for _ in crate::b::all() {} }\n"),
        ]);
        assert_eq!(edges(&g), ["c → a", "c → b", "d → b"]);
    }

    /// The repository itself: what `cargo xtask test` runs.
    #[test]
    fn the_repositorys_trees_have_no_cycle() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .expect("xtask lives one level below the workspace root");
        if let Err(e) = check(root) {
            panic!("{e}");
        }
    }
}
