//! The raster modules import one way: read every `super::` path in `src/raster/*.rs` (use
//! lines and inline paths, outside `#[cfg(test)] mod tests`) and check that
//! - each names a sibling module, not something re-exported by `mod.rs` (the façade, which
//!   nothing below it may import),
//! - the module graph has no cycle,
//! - no module shares its name with a name `mod.rs` re-exports (`raster::forward` is the
//!   whole forward pass, never also a module).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

type Graph = BTreeMap<String, BTreeSet<String>>;

/// The source without its `#[cfg(test)] mod tests { ... }` block (whose `super` is the file
/// itself) and without line comments.
fn code_of(src: &str) -> String {
    let mut out = String::new();
    let mut lines = src.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim();
        if t == "#[cfg(test)]" && lines.peek().is_some_and(|l| l.trim() == "mod tests {") {
            // Inline test modules close at the first line that is exactly "}".
            for l in lines.by_ref() {
                if l == "}" {
                    break;
                }
            }
            continue;
        }
        let code = match line.find("//") {
            Some(i) => &line[..i],
            None => line,
        };
        out.push_str(code);
        out.push('\n');
    }
    out
}

fn ident_at(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// First segments of every `super::...` path: `super::a::X` gives a, `super::{a, b::Y}`
/// gives a and b, `super::X` gives X.
fn super_targets(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices("super::") {
        // `super::super::x` inside a nested module reaches the same level as `super::x` here.
        let rest = code[i + "super::".len()..].trim_start_matches("super::");
        if let Some(group) = rest.strip_prefix('{') {
            let body = &group[..group.find('}').unwrap_or(group.len())];
            for item in body.split(',') {
                let name = ident_at(item.trim());
                if !name.is_empty() {
                    out.insert(name.to_string());
                }
            }
        } else {
            let name = ident_at(rest);
            if !name.is_empty() && name != "super" {
                out.insert(name.to_string());
            }
        }
    }
    out
}

/// Names brought in by `pub use a::{x, y};` / `pub use a::x;` lines (last path segments).
fn reexported_names(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices("pub use ") {
        let stmt = &code[i + "pub use ".len()..];
        let stmt = &stmt[..stmt.find(';').unwrap_or(stmt.len())];
        let items = match (stmt.find('{'), stmt.rfind('}')) {
            (Some(a), Some(b)) => &stmt[a + 1..b],
            _ => stmt.rsplit("::").next().unwrap_or(""),
        };
        for item in items.split(',') {
            let name = item.trim().rsplit("::").next().unwrap_or("");
            if !name.is_empty() {
                out.insert(ident_at(name).to_string());
            }
        }
    }
    out
}

/// A cycle of the graph (its nodes in order, first repeated at the end), if any.
fn find_cycle(graph: &Graph) -> Option<Vec<String>> {
    // 0 = unvisited, 1 = on the current path, 2 = done.
    fn visit(
        node: &str,
        graph: &Graph,
        state: &mut BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(node.to_string(), 1);
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                1 => {
                    let start = path.iter().position(|p| p == next).unwrap();
                    let mut cycle = path[start..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(c) = visit(next, graph, state, path) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        path.pop();
        state.insert(node.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for node in graph.keys() {
        if state.get(node.as_str()).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(node, graph, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

/// Module name -> its code, for every file of `src/raster` except the façade `mod.rs`.
fn raster_modules() -> BTreeMap<String, String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/raster");
    let mut out = BTreeMap::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "rs") {
            let name = path.file_stem().unwrap().to_str().unwrap().to_string();
            if name != "mod" {
                out.insert(name, code_of(&std::fs::read_to_string(&path).unwrap()));
            }
        }
    }
    out
}

#[test]
fn raster_modules_import_only_downward() {
    let modules = raster_modules();
    assert!(modules.len() > 10, "read {} modules", modules.len());
    let mut graph = Graph::new();
    let mut through_facade = Vec::new();
    for (name, code) in &modules {
        let mut deps = BTreeSet::new();
        for target in super_targets(code) {
            if modules.contains_key(&target) {
                deps.insert(target);
            } else {
                through_facade.push(format!("{name} -> super::{target}"));
            }
        }
        graph.insert(name.clone(), deps);
    }
    assert!(
        through_facade.is_empty(),
        "import these from the module that defines them, not from raster/mod.rs: {through_facade:?}"
    );
    // The layering the kernels rely on, spelled out (a sanity check of the reader too).
    assert!(graph["blend_avx2"].contains("tile_walk"));
    assert!(graph["forward_blend"].contains("blend_avx2"));
    assert!(graph["backward_pass"].contains("backward_blend"));
    assert_eq!(
        find_cycle(&graph),
        None,
        "import cycle among the raster modules"
    );
}

#[test]
fn no_module_shares_a_name_with_a_function() {
    // `raster::X` must mean one thing: the façade's re-exported names against the modules.
    let modules = raster_modules();
    let mod_rs =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/raster/mod.rs"))
            .unwrap();
    let exported = reexported_names(&code_of(&mod_rs));
    let clashes: Vec<_> = modules.keys().filter(|m| exported.contains(*m)).collect();
    assert!(
        clashes.is_empty(),
        "raster::{clashes:?} is both a module and a re-export"
    );
    assert!(exported.contains("forward") && exported.contains("backward"));
}

#[test]
fn the_checker_finds_cycles() {
    let graph = |edges: &[(&str, &str)]| {
        let mut g = Graph::new();
        for (a, b) in edges {
            g.entry(a.to_string()).or_default().insert(b.to_string());
            g.entry(b.to_string()).or_default();
        }
        g
    };
    // The layout before the split: forward -> blend_avx2 -> backward -> forward.
    let cyclic = graph(&[
        ("gradients", "backward"),
        ("backward", "forward"),
        ("forward", "blend_avx2"),
        ("blend_avx2", "backward"),
        ("blend_avx2", "forward"),
    ]);
    let cycle = find_cycle(&cyclic).expect("a cycle");
    assert_eq!(cycle.first(), cycle.last());
    assert!(cycle.contains(&"blend_avx2".to_string()));
    assert_eq!(
        find_cycle(&graph(&[("a", "a")])),
        Some(vec!["a".into(), "a".into()])
    );
    let layered = graph(&[
        ("top", "mid"),
        ("top", "low"),
        ("mid", "low"),
        ("other", "low"),
    ]);
    assert_eq!(find_cycle(&layered), None);
}

#[test]
fn the_reader_sees_use_lines_and_inline_paths() {
    let src = "//! super::in_doc is a comment\n\
               use super::lanes::{exp_neg, LANES};\n\
               use super::{features, project_batch::Lanes};\n\
               use super::ALPHA_MIN; // super::trailing comment\n\
               pub use super::tile_walk::{ISECT_FIXED, for_each_splat};\n\
               fn blend_tile() { super::blend_avx2::blend_tile(); }\n\
               #[cfg(test)]\n\
               mod tests {\n    use super::*;\n    use super::super::only_in_tests::X;\n}\n";
    let code = code_of(src);
    let want: BTreeSet<String> = [
        "lanes",
        "features",
        "project_batch",
        "ALPHA_MIN",
        "tile_walk",
        "blend_avx2",
    ]
    .map(String::from)
    .into();
    assert_eq!(super_targets(&code), want);
    let exported: BTreeSet<String> = ["ISECT_FIXED", "for_each_splat"].map(String::from).into();
    assert_eq!(reexported_names(&code), exported);
}
