//! ARCHITECTURE.md's floors are the crate's own imports: every module named on exactly one floor,
//! and every `crate::` and `super::` path in a module's code (not its tests or comments) leading
//! to a floor below its own. The same for the floors inside `vision`. Read from the sources, so
//! that a new import that runs back up, or closes a circle, fails here and not in a review.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// A module path (`vision::clump`) and the source of its file.
fn modules(root: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            // main.rs is the binary, a crate of its own that uses this one as `lfi_bridge`; a
            // module's tests in a file of their own (`decide/tests.rs`) are tests.
            if path.extension().is_none_or(|e| e != "rs") || path == root.join("main.rs") || path.file_stem().is_some_and(|s| s == "tests")
            {
                continue;
            }
            let rel = path.strip_prefix(root).expect("under src").with_extension("");
            let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
            if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
                parts.pop();
            }
            let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            out.insert(parts.join("::"), text);
        }
    }
    out
}

/// The code of a file without its comments and its unit tests (`#[cfg(test)] mod tests` comes
/// last in every file here).
fn code(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(at) => &text[..at],
        None => text,
    };
    text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// The first identifier of each path that follows `prefix` (`crate::`, `super::`), including
/// each item of a brace group (`crate::{a::X, b}` gives a and b).
fn heads(code: &str, prefix: &str) -> Vec<(usize, String)> {
    let ident = |s: &str| -> String { s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect() };
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(at) = rest.find(prefix) {
        let before = rest[..at].chars().last();
        rest = &rest[at + prefix.len()..];
        let pos = code.len() - rest.len();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            // Top-level items of the group.
            let (mut depth, mut start) = (0usize, 0usize);
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => {
                        out.push((pos, ident(group[start..i].trim())));
                        break;
                    }
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        out.push((pos, ident(group[start..i].trim())));
                        start = i + 1;
                    }
                    _ => {}
                }
            }
        } else {
            out.push((pos, ident(rest)));
        }
    }
    out.retain(|h| !h.1.is_empty());
    out
}

/// Byte ranges of the inline modules (`mod name { .. }`) in a file's code.
fn inline_modules(code: &str) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(at) = code[from..].find("mod ") {
        let start = from + at;
        from = start + 4;
        let before = code[..start].chars().last();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let name: String = code[from..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        if name.is_empty() || !code[from + name.len()..].trim_start().starts_with('{') {
            continue;
        }
        let open = from + name.len() + code[from + name.len()..].find('{').unwrap_or(0);
        let mut depth = 0usize;
        for (i, c) in code[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        out.push(open..open + i);
                        break;
                    }
                }
                _ => {}
            }
        }
    }
    out
}

/// Module -> the modules its code names (by their full path), among `mods`.
fn imports(mods: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let mut out = BTreeMap::new();
    for (m, text) in mods {
        let code = code(text);
        let mut deps = BTreeSet::new();
        for (_, h) in heads(&code, "crate::") {
            if mods.contains_key(&h) {
                deps.insert(h);
            }
        }
        // `super::` of a file module is its parent; of a `mod.rs`, its parent's parent alike
        // (the module path already names the folder).
        let parent = m.rsplit_once("::").map_or("", |(p, _)| p);
        let inline = inline_modules(&code);
        for (at, h) in heads(&code, "super::") {
            // Inside an inline `mod raw { .. }`, `super::` is this file's own module.
            if inline.iter().any(|r| r.contains(&at)) {
                continue;
            }
            // `super::super::x` (a folder module's file) climbs one module more per `super`.
            let (mut base, mut h, mut from) = (parent, h, at);
            while h == "super" {
                base = base.rsplit_once("::").map_or("", |(p, _)| p);
                from += "super::".len();
                h = code[from..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            }
            let child = if base.is_empty() { h } else { format!("{base}::{h}") };
            deps.insert(if mods.contains_key(&child) { child } else { base.to_string() });
        }
        deps.remove(m);
        out.insert(m.clone(), deps);
    }
    out
}

/// The floors of the named code block after `heading` in ARCHITECTURE.md, top first: each line
/// is a comma-separated list of modules, then two spaces and what they hold.
fn floors(doc: &str, heading: &str) -> Vec<Vec<String>> {
    let after = &doc[doc.find(heading).unwrap_or_else(|| panic!("ARCHITECTURE.md has no {heading:?}"))..];
    let block = after.split("```").nth(1).expect("a code block after the heading");
    block
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split("  ").next().unwrap_or("").split(',').map(|n| n.trim().to_string()).collect())
        .collect()
}

/// Checks that the modules in `scope` (named by `name` on the floors) each stand on one floor
/// and import only from floors below.
fn check(floors: &[Vec<String>], scope: &BTreeMap<String, BTreeSet<String>>, what: &str) -> Vec<String> {
    let mut level: BTreeMap<&str, usize> = BTreeMap::new();
    let mut problems = Vec::new();
    for (i, floor) in floors.iter().enumerate() {
        for n in floor {
            if level.insert(n, floors.len() - i).is_some() {
                problems.push(format!("{what}: {n} stands on two floors"));
            }
        }
    }
    for (m, deps) in scope {
        let Some(&lm) = level.get(m.as_str()) else {
            problems.push(format!("{what}: module {m} is on no floor"));
            continue;
        };
        for d in deps {
            match level.get(d.as_str()) {
                Some(&ld) if ld < lm => {}
                Some(_) => problems.push(format!("{what}: {m} imports {d}, which is not on a floor below")),
                None => problems.push(format!("{what}: {m} imports {d}, which is on no floor")),
            }
        }
    }
    for n in level.keys() {
        if !scope.contains_key(*n) {
            problems.push(format!("{what}: {n} is on a floor but is no module"));
        }
    }
    problems
}

#[test]
fn the_floors_of_architecture_md_are_the_crates_imports() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let mods = modules(&root.join("src"));
    let deps = imports(&mods);
    let top = |m: &str| m.split("::").next().unwrap_or("").to_string();
    // The crate's floors: each top-level module with everything inside it; the crate root
    // (lib.rs and main.rs) is "lib".
    let mut crate_level: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (m, ds) in &deps {
        let from = if m.is_empty() { "lib".to_string() } else { top(m) };
        let entry = crate_level.entry(from.clone()).or_default();
        entry.extend(ds.iter().map(|d| if d.is_empty() { "lib".to_string() } else { top(d) }).filter(|d| *d != from));
    }
    let mut problems = check(&floors(&doc, "## Floors"), &crate_level, "crate");
    // Inside vision: its files, with mod.rs (the estimator) as "vision".
    let short = |x: &str| x.split("::").nth(1).unwrap_or("vision").to_string();
    let mut inside: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (m, ds) in deps.iter().filter(|(m, _)| *m == "vision" || m.starts_with("vision::")) {
        let from = short(m);
        let named = ds.iter().filter(|d| *d == "vision" || d.starts_with("vision::")).map(|d| short(d)).filter(|d| *d != from);
        let named: Vec<String> = named.collect();
        inside.entry(from).or_default().extend(named);
    }
    problems.extend(check(&floors(&doc, "### Floors inside `vision`"), &inside, "vision"));
    assert!(problems.is_empty(), "ARCHITECTURE.md's floors and the imports disagree:\n{}", problems.join("\n"));
}

/// The invariants ARCHITECTURE.md states as what a module may not know, checked on its code
/// (comments and tests left out): each module, and the words that would break its invariant.
#[test]
fn the_negative_invariants_of_architecture_md_hold() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let mods = modules(&root.join("src"));
    let files = ["std::fs", "File::", "read_to_string", "std::net"];
    let rules: &[(&str, &str, &[&str])] = &[
        (
            "vision",
            "`vision` knows nothing about Modbus, tokio, TOML or files.",
            &["tokio", "toml", "modbus", "registers", "std::fs", "File::", "std::net"],
        ),
        ("registers", "`registers` is pure data", &["tokio", "std::fs", "std::net", "Instant::now", "Mutex"]),
        ("handshake", "`handshake` knows no\nsockets and no clock", &["tokio", "std::net", "Instant::now", "SystemTime::now"]),
        ("robot", "`robot::Link` knows no\nsockets and no clock", &["tokio", "std::net", "Instant::now", "SystemTime::now"]),
        ("eval", "`eval` does no I/O.", &files),
        ("appliance", "`appliance` knows no HTTP", &["axum", "crate::http", "tower"]),
        ("opcua", "`opcua` knows no HTTP", &["axum", "crate::http"]),
    ];
    let mut problems = Vec::new();
    for (module, said, words) in rules {
        assert!(doc.contains(said), "ARCHITECTURE.md no longer says {said:?}: update this test with it");
        // The module itself and, for a folder, everything in it (robot's driver, `robot::link`,
        // is the one shell the rule leaves out).
        let inside = mods.iter().filter(|(m, _)| *m == module || (m.starts_with(&format!("{module}::")) && *m != "robot::link"));
        for (m, text) in inside {
            let code = code(text);
            for w in *words {
                if code.contains(w) {
                    problems.push(format!("{m} uses {w:?}, but ARCHITECTURE.md says {said:?}"));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
