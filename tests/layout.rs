//! The house rules, checked over the repository's sources: no two Rust source files import
//! each other, no hand-written source file is over 1,000 lines, every Rust module file
//! starts with a `//!` line, and the README is a front door of at most 150 lines.
//!
//! Imports are read from the text: `use` trees and inline paths starting with `crate::`,
//! `super::` or `self::` (and `use child::…` of a module the file declares), resolved to the
//! file that defines the item named (following `pub use` re-exports), within each crate
//! root's module tree (`mod x;` → `x.rs` or `x/mod.rs`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use cathlab_tests::repo_root;

/// Most lines a hand-written source file may have.
const MAX_LINES: usize = 1_000;
/// Most lines the README may have.
const MAX_README_LINES: usize = 150;

/// Folders never read: build output, dependencies, generated code.
const SKIPPED: &[&str] = &[
    "target",
    "node_modules",
    ".git",
    "gen",
    "dist",
    "test-results",
];

/// Every file under `dir` (recursively) whose name ends with one of `extensions`.
fn files(dir: &Path, extensions: &[&str], out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            if !SKIPPED.contains(&name.as_str()) && !name.starts_with('.') {
                files(&path, extensions, out);
            }
        } else if extensions.iter().any(|e| name.ends_with(e)) {
            out.push(path);
        }
    }
}

/// The workspace's Rust sources and the web client's and scripts' hand-written sources.
fn sources() -> Vec<PathBuf> {
    let root = repo_root();
    let mut out = Vec::new();
    for dir in [
        "server",
        "client-haptic",
        "tests",
        "fuzz",
        "client-web",
        "scripts",
    ] {
        files(
            &root.join(dir),
            &[".rs", ".ts", ".mjs", ".js", ".py", ".sh", ".wgsl"],
            &mut out,
        );
    }
    out.sort();
    out
}

fn relative(path: &Path) -> String {
    let root = repo_root().canonicalize().unwrap();
    path.canonicalize()
        .ok()
        .and_then(|p| p.strip_prefix(&root).ok().map(Path::to_owned))
        .unwrap_or_else(|| path.to_owned())
        .display()
        .to_string()
}

#[test]
fn no_source_file_is_over_1000_lines() {
    let long: Vec<String> = sources()
        .iter()
        .filter(|p| !p.to_string_lossy().contains("/fuzz/corpus/"))
        .filter_map(|p| {
            let lines = std::fs::read_to_string(p).ok()?.lines().count();
            (lines > MAX_LINES).then(|| format!("{} ({lines} lines)", relative(p)))
        })
        .collect();
    assert!(
        long.is_empty(),
        "source files over {MAX_LINES} lines (cut them by stage or concept):\n  {}",
        long.join("\n  ")
    );
}

#[test]
fn every_rust_module_says_what_it_owns() {
    let silent: Vec<String> = sources()
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
        .filter(|p| {
            let text = std::fs::read_to_string(p).unwrap_or_default();
            !text
                .lines()
                .find(|l| !l.trim().is_empty() && !l.starts_with("#!["))
                .is_some_and(|l| l.starts_with("//!"))
        })
        .map(|p| relative(p))
        .collect();
    assert!(
        silent.is_empty(),
        "Rust files that do not start with a `//!` line:\n  {}",
        silent.join("\n  ")
    );
}

#[test]
fn the_readme_is_a_front_door() {
    let readme = std::fs::read_to_string(repo_root().join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(
        lines <= MAX_README_LINES,
        "README.md has {lines} lines; a front door has at most {MAX_README_LINES} (detail goes in docs/)"
    );
}

/// One Rust file of a crate's module tree.
#[derive(Debug)]
struct Module {
    /// The module's path from the crate root (empty for the root).
    path: Vec<String>,
    /// The file it is written in (inline modules share their parent's).
    file: PathBuf,
    /// The file's text without comments.
    text: String,
}

/// The text without `//` comments (doc comments included) and `/* */` blocks, and with
/// string literals emptied, so paths named in prose or strings are not read as imports.
fn code_only(text: &str) -> String {
    let bytes = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'/' if bytes.get(i + 1) == Some(&b'/') => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            b'/' if bytes.get(i + 1) == Some(&b'*') => {
                i += 2;
                while i + 1 < bytes.len() && !(bytes[i] == b'*' && bytes[i + 1] == b'/') {
                    i += 1;
                }
                i += 2;
            }
            b'"' => {
                // Skip to the closing quote (a raw string's hashes are rare in paths; an
                // escaped quote is skipped with its backslash).
                i += 1;
                while i < bytes.len() && bytes[i] != b'"' {
                    if bytes[i] == b'\\' {
                        i += 1;
                    }
                    i += 1;
                }
                i += 1;
                out.push_str("\"\"");
            }
            b'\'' => {
                // A char literal ('x', '\n', '"') or a lifetime: copy a lifetime, skip a char.
                let end = text[i + 1..]
                    .char_indices()
                    .take(4)
                    .find(|&(_, c)| c == '\'')
                    .map(|(k, _)| i + 1 + k);
                match end {
                    Some(e) if e > i + 1 => {
                        out.push_str("' '");
                        i = e + 1;
                    }
                    _ => {
                        out.push('\'');
                        i += 1;
                    }
                }
            }
            _ => {
                let c = text[i..].chars().next().unwrap();
                out.push(c);
                i += c.len_utf8();
            }
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The `mod x;` declarations of a file (not inline `mod x { … }`), with `#[path]` ignored.
fn declared_modules(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in code.lines() {
        let line = line.trim();
        let rest = line
            .strip_prefix("pub mod ")
            .or_else(|| line.strip_prefix("pub(crate) mod "))
            .or_else(|| line.strip_prefix("mod "));
        if let Some(rest) = rest
            && let Some(name) = rest.strip_suffix(';')
            && name.chars().all(is_ident)
        {
            out.push(name.to_owned());
        }
    }
    out
}

/// The module tree under the root file `root`.
fn module_tree(root: &Path) -> Vec<Module> {
    let mut out = Vec::new();
    let mut stack = vec![(Vec::<String>::new(), root.to_owned())];
    while let Some((path, file)) = stack.pop() {
        let Ok(text) = std::fs::read_to_string(&file) else {
            continue;
        };
        let code = code_only(&text);
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        // Children of lib.rs, main.rs and mod.rs sit beside them; those of x.rs in x/.
        let dir = if path.is_empty() || name == "mod.rs" || name == "main.rs" {
            file.parent().unwrap().to_owned()
        } else {
            file.with_extension("")
        };
        for child in declared_modules(&code) {
            let flat = dir.join(format!("{child}.rs"));
            let nested = dir.join(&child).join("mod.rs");
            let child_file = if flat.exists() { flat } else { nested };
            let mut child_path = path.clone();
            child_path.push(child);
            stack.push((child_path, child_file));
        }
        out.push(Module {
            path,
            file,
            text: code,
        });
    }
    out
}

/// The roots of every crate in a package folder: the library, binaries, tests, benches.
fn crate_roots(package: &Path) -> Vec<PathBuf> {
    let mut roots = Vec::new();
    for root in ["src/lib.rs", "src/main.rs"] {
        if package.join(root).exists() {
            roots.push(package.join(root));
        }
    }
    for dir in ["src/bin", "tests", "benches", "examples", "fuzz_targets"] {
        let Ok(entries) = std::fs::read_dir(package.join(dir)) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "rs") {
                roots.push(path);
            } else if path.join("main.rs").exists() {
                roots.push(path.join("main.rs"));
            }
        }
    }
    roots
}

/// The inline modules (`mod name { … }`) of a file: where each one's body starts and ends,
/// and its name.
fn inline_modules(code: &str) -> Vec<(usize, usize, String)> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(k) = code[from..].find("mod ") {
        let at = from + k;
        from = at + 4;
        if code[..at].chars().next_back().is_some_and(is_ident) {
            continue;
        }
        let name: String = code[at + 4..]
            .chars()
            .take_while(|&c| is_ident(c))
            .collect();
        let after = code[at + 4 + name.len()..].trim_start();
        if name.is_empty() || !after.starts_with('{') {
            continue;
        }
        let open = code.len() - after.len();
        let mut depth = 0;
        for (i, c) in code[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        out.push((open, open + i, name.clone()));
                        break;
                    }
                }
                _ => {}
            }
        }
    }
    out
}

/// The paths a file names, each with the inline modules it is written in: each `use` tree
/// expanded, and every inline `crate::`, `super::` or `self::` path; each as its segments.
fn named_paths(code: &str, children: &[String]) -> Vec<(Vec<String>, Vec<String>)> {
    let inline = inline_modules(code);
    let within = |at: usize| -> Vec<String> {
        inline
            .iter()
            .filter(|(start, end, _)| *start < at && at < *end)
            .map(|(_, _, name)| name.clone())
            .collect()
    };
    let mut out = Vec::new();
    // `use` statements, their brace groups expanded.
    let mut from = 0;
    while let Some(k) = code[from..].find("use ") {
        let at = from + k;
        let tail = &code[at + 4..];
        from = at + 4;
        if code[..at].chars().next_back().is_some_and(is_ident) {
            continue;
        }
        let end = tail.find(';').unwrap_or(tail.len());
        let mut paths = Vec::new();
        expand_use(tail[..end].trim(), &mut Vec::new(), &mut paths);
        let inside = within(at);
        for mut p in paths {
            // `use child::X` of a declared child module means `self::child::X`.
            if inside.is_empty() && p.first().is_some_and(|s| children.contains(s)) {
                p.insert(0, "self".to_owned());
            }
            out.push((inside.clone(), p));
        }
        from = at + 4 + end;
    }
    // Inline paths.
    for start in ["crate::", "super::", "self::"] {
        let mut from = 0;
        while let Some(k) = code[from..].find(start) {
            let at = from + k;
            from = at + start.len();
            if code[..at].chars().next_back().is_some_and(is_ident) {
                continue;
            }
            let segments: Vec<String> = code[at..]
                .split("::")
                .map(|s| s.chars().take_while(|&c| is_ident(c)).collect::<String>())
                .scan(true, |go, s| {
                    let keep = *go && !s.is_empty();
                    *go = keep;
                    keep.then_some(s)
                })
                .collect();
            if segments.len() > 1 {
                out.push((within(at), segments));
            }
        }
    }
    out
}

/// Expands one `use` tree (`a::b::{c, d::e as f, g::*}`) into paths.
fn expand_use(tree: &str, prefix: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    let tree = tree.trim();
    if let Some(open) = tree.find('{') {
        let head = &tree[..open];
        let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
        let pushed: Vec<String> = head
            .split("::")
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(str::to_owned)
            .collect();
        let n = pushed.len();
        prefix.extend(pushed);
        // Split the group at top-level commas.
        let mut depth = 0;
        let mut start = 0;
        for (i, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    expand_use(&inner[start..i], prefix, out);
                    start = i + 1;
                }
                _ => {}
            }
        }
        expand_use(&inner[start..], prefix, out);
        prefix.truncate(prefix.len() - n);
    } else if !tree.is_empty() {
        let tree = tree.split(" as ").next().unwrap_or(tree);
        let mut path = prefix.clone();
        path.extend(
            tree.split("::")
                .map(str::trim)
                .filter(|s| !s.is_empty() && *s != "self")
                .map(str::to_owned),
        );
        out.push(path);
    }
}

/// Whether `code` defines an item named `name`.
fn defines(code: &str, name: &str) -> bool {
    [
        "fn ",
        "struct ",
        "enum ",
        "trait ",
        "type ",
        "const ",
        "static ",
        "union ",
        "mod ",
        "macro_rules! ",
    ]
    .iter()
    .any(|kw| {
        let needle = format!("{kw}{name}");
        code.match_indices(&needle).any(|(i, _)| {
            let after = code[i + needle.len()..].chars().next();
            let before = code[..i].chars().next_back();
            !after.is_some_and(is_ident) && !before.is_some_and(is_ident)
        })
    })
}

/// The file that defines what `path` (absolute, from the crate root) names, following
/// re-exports; `None` outside the crate.
fn resolve(modules: &[Module], path: &[String], depth: usize) -> Option<PathBuf> {
    if depth > 8 {
        return None;
    }
    // The longest prefix that is a module.
    let (module, used) = (0..=path.len())
        .rev()
        .find_map(|n| modules.iter().find(|m| m.path == path[..n]).map(|m| (m, n)))?;
    let Some(item) = path.get(used) else {
        return Some(module.file.clone()); // the module itself
    };
    if item == "*" || defines(&module.text, item) {
        return Some(module.file.clone());
    }
    // A re-export: `pub use x::y::Item;` (or a group naming it) in that module.
    let children = declared_modules(&module.text);
    for (inside, reexport) in named_paths(&module.text, &children) {
        if !inside.is_empty() {
            continue;
        }
        if (reexport.last() == Some(item) || reexport.last().is_some_and(|s| s == "*"))
            && let Some(mut target) = absolute(&module.path, &reexport)
        {
            if target.last().is_some_and(|s| s == "*") {
                target.pop();
                target.push(item.clone());
            }
            if target != path
                && let Some(file) = resolve(modules, &target, depth + 1)
            {
                return Some(file);
            }
        }
    }
    Some(module.file.clone())
}

/// `path` as written in the module at `from`, made absolute (from the crate root).
fn absolute(from: &[String], path: &[String]) -> Option<Vec<String>> {
    let mut out: Vec<String> = match path.first()?.as_str() {
        "crate" => Vec::new(),
        "self" => from.to_vec(),
        "super" => from.to_vec(),
        _ => return None, // another crate, or std
    };
    let mut segments = path.iter().peekable();
    if path[0] == "crate" || path[0] == "self" {
        segments.next();
    }
    while segments.peek().is_some_and(|s| *s == "super") {
        segments.next();
        out.pop()?;
    }
    out.extend(segments.cloned());
    Some(out)
}

/// Every import edge between two different files of one crate.
fn edges(modules: &[Module]) -> BTreeSet<(PathBuf, PathBuf)> {
    let mut out = BTreeSet::new();
    for m in modules {
        let children = declared_modules(&m.text);
        for (inside, path) in named_paths(&m.text, &children) {
            let mut from = m.path.clone();
            from.extend(inside);
            let Some(absolute) = absolute(&from, &path) else {
                continue;
            };
            // Naming a child module itself (a `mod` line's re-export) is the parent's tree,
            // and `use super::*` in a test module inside the file is the file itself.
            if let Some(file) = resolve(modules, &absolute, 0)
                && file != m.file
            {
                out.insert((m.file.clone(), file));
            }
        }
    }
    out
}

/// Every package folder of the repository (the workspace's and the fuzz targets').
fn packages() -> Vec<PathBuf> {
    let root = repo_root();
    let mut packages = Vec::new();
    for dir in ["server", "client-haptic", "tests", "fuzz"] {
        let path = root.join(dir);
        if path.join("Cargo.toml").exists() {
            packages.push(path.clone());
        }
        for entry in std::fs::read_dir(&path).unwrap().flatten() {
            if entry.path().join("Cargo.toml").exists() {
                packages.push(entry.path());
            }
        }
    }
    packages
}

/// The root files of the `[lib]` and `[[bin]]` targets a package's manifest builds without
/// a test harness (`test = false`, with `bench = false`: `--all-targets` builds a target's
/// bench harness, the same test binary, unless that is off too).
fn untested_targets(package: &Path) -> Vec<PathBuf> {
    let Ok(manifest) = std::fs::read_to_string(package.join("Cargo.toml")) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let (mut section, mut path, mut untested, mut unbenched) =
        (String::new(), None::<String>, false, false);
    for line in manifest.lines().map(str::trim).chain(["[end]"]) {
        if line.starts_with('[') {
            let default = (section == "[lib]").then_some("src/lib.rs");
            if untested && let Some(p) = path.as_deref().or(default) {
                assert!(
                    unbenched,
                    "{}: {section} {p} has `test = false` but not `bench = false`: its harness \
                     is still built by --all-targets",
                    package.display()
                );
                out.push(package.join(p));
            }
            (section, path, untested, unbenched) = (line.to_owned(), None, false, false);
        } else if (section == "[lib]" || section == "[[bin]]")
            && let Some((key, value)) = line.split_once('=')
        {
            match key.trim() {
                "path" => path = Some(value.trim().trim_matches('"').to_owned()),
                "test" => untested = value.trim() == "false",
                "bench" => unbenched = value.trim() == "false",
                _ => {}
            }
        }
    }
    out
}

/// A library or binary built without its test harness (to save a compile and a link of a
/// target that holds no test) must hold no test, or the test would silently never run.
#[test]
fn targets_built_without_a_test_harness_hold_no_tests() {
    let mut roots = 0;
    let mut holding = Vec::new();
    for package in packages() {
        for root in untested_targets(&package) {
            roots += 1;
            for module in module_tree(&root) {
                if module.text.contains("#[test]") || module.text.contains("#[cfg(test)]") {
                    holding.push(relative(&module.file));
                }
            }
        }
    }
    assert!(
        roots >= 10,
        "only {roots} targets without a harness found: the reader is broken"
    );
    assert!(
        holding.is_empty(),
        "tests in targets built with `test = false` (they would never run; remove the \
         setting from the target's Cargo.toml): {holding:?}"
    );
}

#[test]
fn no_two_source_files_import_each_other() {
    let packages = packages();
    let mut circles = BTreeMap::new();
    let mut files = 0;
    for package in &packages {
        for crate_root in crate_roots(package) {
            let modules = module_tree(&crate_root);
            files += modules.len();
            let edges = edges(&modules);
            for (a, b) in &edges {
                if a < b && edges.contains(&(b.clone(), a.clone())) {
                    circles.insert(relative(a), relative(b));
                }
            }
        }
    }
    assert!(files > 200, "only {files} files read: the walk is broken");
    let list: Vec<String> = circles.iter().map(|(a, b)| format!("{a} ↔ {b}")).collect();
    assert!(
        circles.is_empty(),
        "files that import each other (move the shared item to the module that owns the \
         concept, below both):\n  {}",
        list.join("\n  ")
    );
}

/// The import reader on a small crate: a circle through a re-export is found, a use of a
/// sibling's item through the parent's re-export is not a circle with the parent.
#[test]
fn the_import_reader_finds_circles_and_follows_reexports() {
    let dir = cathlab_tests::temp_dir("layout");
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("world")).unwrap();
    std::fs::write(
        src.join("lib.rs"),
        "//! root\nmod world;\nmod strand;\npub use world::World;\n",
    )
    .unwrap();
    std::fs::write(
        src.join("world.rs"),
        "//! world\nmod stage;\npub use stage::Stage;\npub struct World;\nuse crate::strand::Strand;\n",
    )
    .unwrap();
    std::fs::write(
        src.join("world/stage.rs"),
        "//! stage\n// use crate::World; (a comment: not read)\npub struct Stage(crate::strand::Strand);\n",
    )
    .unwrap();
    std::fs::write(
        src.join("strand.rs"),
        "//! strand\npub struct Strand;\nfn f(_: &crate::World) {}\nfn g(_: crate::world::Stage) {}\n\
         mod tests {\n    use super::*;\n    mod deeper { use super::super::Strand; }\n}\n",
    )
    .unwrap();
    let modules = module_tree(&src.join("lib.rs"));
    assert_eq!(modules.len(), 4);
    let edges = edges(&modules);
    let has = |a: &str, b: &str| edges.contains(&(src.join(a), src.join(b)));
    // strand names crate::World (re-exported by lib.rs from world.rs): an edge to world.rs.
    assert!(has("strand.rs", "world.rs"));
    assert!(has("world.rs", "strand.rs"));
    // crate::world::Stage is re-exported by world.rs from stage.rs: the edge goes there.
    assert!(has("strand.rs", "world/stage.rs"));
    assert!(has("world/stage.rs", "strand.rs"));
    // The commented-out use is not read: stage.rs does not import world.rs.
    assert!(!has("world/stage.rs", "world.rs"));
    assert!(has("lib.rs", "world.rs"));
    // `use super::*` in an inline test module is the file's own module, not its parent.
    assert!(!has("strand.rs", "lib.rs"));
}
