//! Checks on the repository as a whole.
//!
//! **Layers.** The library's modules stay in layers: a module uses only its own subtree
//! and modules of strictly lower layers. The check reads `src/` as text and
//! names every `crate::<module>` path (in code; comments, doc comments and
//! string literals are ignored, as are `#[cfg(test)]` items and the
//! `tests.rs` / `*_tests.rs` files) that reaches a higher layer or another
//! module of the same layer, and every `super::` in a module's top file
//! (which would reach the crate root, around the check).
//!
//! **Public surface.** The library declares at most [`PUBLIC_ITEM_BUDGET`]
//! `pub` items (functions, types, constants, modules, re-exports), counted
//! line by line as `grep -rEn '^\s*pub (fn|struct|enum|trait|type|const|static|mod|use|unsafe fn|async fn)\b'`
//! over `src/` without the paths and lines that name `tests`. Research-only
//! items (`research_pub!`, `research_use!`) do not count: without the
//! feature `research` they are crate-internal.
//!
//! **Size.** In the product crates (the library, the CLI, the Python
//! bindings, the report, online and history crates) no function is longer
//! than 120 lines from `fn` to its closing brace and no source file longer
//! than 1 000 lines outside its test items.
//!
//! **Self-contained.** No source, test, example, manifest, script or doc
//! refers to data beside the repository (a sibling `shared` folder): everything a clone
//! needs is in it (`data/`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The layers, lowest first: `(layer, top-level module)`.
const LAYERS: &[(u32, &str)] = &[
    (0, "error"),      // Error, Result, the QP errors
    (0, "progress"),   // progress events
    (0, "simd"),       // the instruction-set choice of the AVX2 builds
    (1, "model"),      // θ, the equations, parameters, extrinsics, physical limits
    (1, "output"),     // atomic writes, output paths checked against inputs
    (2, "drive"),      // drives, CSV, concat, segments, plausibility checks
    (3, "io"),         // manifest import, bags, Parquet, parameter files
    (3, "sim"),        // the drive simulator
    (4, "identify"),   // Gauss-Newton, covariance, estimation with extrinsics
    (5, "compensate"), // input compensation and its QP
    (5, "eiv"),        // the errors-in-variables estimator
    (6, "assess"),     // Ē_p, validation, reachable minimum, verdict, warnings
    (7, "calibrate"),  // the methods, settings, validation on other drives, cross-run
    (8, "experiment"), // the paper's §6 experiment
];

fn layer_of(module: &str) -> Option<u32> {
    LAYERS.iter().find(|(_, m)| *m == module).map(|(l, _)| *l)
}

/// One use of another top-level module.
#[derive(Debug)]
struct Use {
    file: PathBuf,
    line: usize,
    target: String,
}

/// `text` with comments, string and char literals blanked (newlines kept, so
/// line numbers stay).
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let blank = |s: &str, out: &mut String| out.extend(s.chars().map(|c| if c == '\n' { '\n' } else { ' ' }));
    while i < b.len() {
        let rest = &text[i..];
        let end = if rest.starts_with("//") {
            rest.find('\n').unwrap_or(rest.len())
        } else if rest.starts_with("/*") {
            rest.find("*/").map_or(rest.len(), |e| e + 2)
        } else if let Some(hashes) = raw_string_start(rest) {
            let close = format!("\"{}", "#".repeat(hashes));
            let open = 2 + hashes;
            rest[open..].find(&close).map_or(rest.len(), |e| open + e + close.len())
        } else if rest.starts_with('"') {
            string_end(rest)
        } else if rest.starts_with('\'') && is_char_literal(rest) {
            rest[1..].find('\'').map_or(rest.len(), |e| e + 2)
        } else {
            let c = rest.chars().next().map_or(1, char::len_utf8);
            out.push_str(&rest[..c]);
            i += c;
            continue;
        };
        blank(&rest[..end], &mut out);
        i += end;
    }
    out
}

/// `r"`, `r#"`, … at the start of `s`: the number of `#`.
fn raw_string_start(s: &str) -> Option<usize> {
    let t = s.strip_prefix('r')?;
    let hashes = t.len() - t.trim_start_matches('#').len();
    t[hashes..].starts_with('"').then_some(hashes)
}

/// The length of the string literal at the start of `s` (escapes honoured).
fn string_end(s: &str) -> usize {
    let mut escaped = false;
    for (i, c) in s.char_indices().skip(1) {
        match c {
            '\\' if !escaped => escaped = true,
            '"' if !escaped => return i + 1,
            _ => escaped = false,
        }
    }
    s.len()
}

/// A char literal (`'a'`, `'\n'`, `'\''`) rather than a lifetime (`'a`).
fn is_char_literal(s: &str) -> bool {
    let mut it = s.chars().skip(1);
    match it.next() {
        Some('\\') => true,
        Some(_) => it.next() == Some('\''),
        None => false,
    }
}

/// The byte index of the `}` that closes the `{` at `open` in `code`.
fn closing_brace(code: &str, open: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (i, c) in code[open..].char_indices() {
        match c {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return Some(open + i);
                }
            }
            _ => {}
        }
    }
    None
}

/// The byte ranges of the `#[cfg(test)]` items in `code` (a `mod tests {
/// … }`, a test-only function or `use`), from the attribute to the item's end.
fn test_items(code: &str) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(at) = code[from..].find("#[cfg(test)]").map(|p| p + from) {
        let body = &code[at..];
        // The item ends at the first `;` before any `{`, or at the `}` matching its first `{`.
        let (semi, brace) = (body.find(';'), body.find('{'));
        let end = match (semi, brace) {
            (Some(s), Some(b)) if s < b => s + 1,
            (Some(s), None) => s + 1,
            (_, Some(b)) => closing_brace(body, b).map_or(body.len(), |c| c + 1),
            (None, None) => body.len(),
        };
        out.push(at..at + end);
        from = at + end;
    }
    out
}

/// `code` with every `#[cfg(test)]` item ([`test_items`]) blanked (newlines kept).
fn without_test_items(code: &str) -> String {
    let mut out = code.to_string();
    for range in test_items(code) {
        let blanked: String = code[range.clone()].chars().map(|c| if c == '\n' { '\n' } else { ' ' }).collect();
        out.replace_range(range, &blanked);
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The first path segment after `crate::` at each use in `code`, with its
/// line; a `crate::{a::X, b}` group gives each member.
fn crate_paths(code: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let line_at = |pos: usize| code[..pos].matches('\n').count() + 1;
    let mut from = 0;
    while let Some(at) = code[from..].find("crate::").map(|p| p + from) {
        from = at + "crate::".len();
        if code[..at].chars().next_back().is_some_and(is_ident) {
            continue; // e.g. `my_crate::`
        }
        let rest = &code[from..];
        if let Some(group) = rest.strip_prefix('{') {
            let mut depth = 0usize;
            let mut start = true;
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => start = true,
                    c if start && is_ident(c) => {
                        let name: String = group[i..].chars().take_while(|c| is_ident(*c)).collect();
                        out.push((line_at(from + 1 + i), name));
                        start = false;
                    }
                    _ => {}
                }
            }
        } else {
            let name: String = rest.chars().take_while(|c| is_ident(*c)).collect();
            if !name.is_empty() {
                out.push((line_at(at), name));
            }
        }
    }
    out
}

/// The first path segment after each `super::` in `code`, with its line.
fn super_paths(code: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(at) = code[from..].find("super::").map(|p| p + from) {
        from = at + "super::".len();
        if code[..at].chars().next_back().is_some_and(is_ident) {
            continue;
        }
        let name: String = code[from..].chars().take_while(|c| is_ident(*c) || *c == '{' || *c == '*').collect();
        out.push((code[..at].matches('\n').count() + 1, name));
    }
    out
}

/// The names `lib.rs` re-exports at the crate root, each with the module it
/// comes from (`pub use assess::trust::{Verdict, …}` and
/// `pub use assess::{trust::Verdict, …}` map `Verdict` to `assess`).
fn root_reexports(lib: &str) -> BTreeMap<String, String> {
    let code = code_only(lib);
    let mut out = BTreeMap::new();
    for stmt in code.split(';') {
        let Some(path) = stmt.trim().strip_prefix("pub use ") else { continue };
        let module: String = path.chars().take_while(|c| is_ident(*c)).collect();
        let names = match (path.find('{'), path.rfind("::")) {
            (Some(b), _) => path[b + 1..].replace(['{', '}'], ""),
            (None, Some(c)) => path[c + 2..].to_string(),
            (None, None) => continue,
        };
        // `assess::{trust::{Verdict, Guards}, warning::Warning}`: each name
        // after its last `::`.
        for n in names.split(',') {
            let n = n.trim().rsplit("::").next().unwrap_or("").trim();
            if !n.is_empty() && n != "self" {
                out.insert(n.to_string(), module.clone());
            }
        }
    }
    out
}

/// The top-level module of a source file (`assess/trust.rs` → `assess`).
fn module_of(rel: &Path) -> Option<String> {
    let first = rel.components().next()?.as_os_str().to_str()?;
    Some(first.strip_suffix(".rs").unwrap_or(first).to_string())
}

fn is_test_file(path: &Path) -> bool {
    path.file_name().and_then(|n| n.to_str()).is_some_and(|n| n == "tests.rs" || n.ends_with("_tests.rs"))
}

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).expect("read src").map(|e| e.expect("entry").path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// Every use of another top-level module, per using module.
fn uses(src: &Path) -> BTreeMap<String, Vec<Use>> {
    let lib = std::fs::read_to_string(src.join("lib.rs")).expect("lib.rs");
    let reexports = root_reexports(&lib);
    let mut files = Vec::new();
    sources(src, &mut files);
    let mut out: BTreeMap<String, Vec<Use>> = BTreeMap::new();
    for file in files {
        let rel = file.strip_prefix(src).expect("under src").to_path_buf();
        if rel == Path::new("lib.rs") || is_test_file(&rel) {
            continue;
        }
        let module = module_of(&rel).expect("module");
        let text = std::fs::read_to_string(&file).expect("read");
        let code = without_test_items(&code_only(&text));
        // In a module's top file `super::` is the crate root: it must name the module with `crate::`.
        let top = rel.components().count() == 1
            || rel.file_name().is_some_and(|n| n == "mod.rs") && rel.components().count() == 2;
        if top {
            for (line, first) in super_paths(&code) {
                out.entry(module.clone()).or_default().push(Use {
                    file: rel.clone(),
                    line,
                    target: format!("?super::{first}"),
                });
            }
        }
        for (line, first) in crate_paths(&code) {
            let target = if layer_of(&first).is_some() {
                first
            } else if let Some(m) = reexports.get(&first) {
                m.clone()
            } else {
                format!("?{first}")
            };
            if target != module {
                out.entry(module.clone()).or_default().push(Use { file: rel.clone(), line, target });
            }
        }
    }
    out
}

#[test]
fn modules_use_only_lower_layers() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut problems = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).expect("under src");
        let m = module_of(rel).expect("module");
        if m != "lib" && layer_of(&m).is_none() {
            problems.push(format!("src/{}: module `{m}` is in no layer of the table", rel.display()));
        }
    }
    for (module, list) in uses(&src) {
        let from = layer_of(&module).expect("checked above");
        for u in list {
            let at = format!("src/{}:{}", u.file.display(), u.line);
            match layer_of(&u.target) {
                None if u.target.starts_with("?super::") => {
                    problems.push(format!("{at}: `{}` leaves the module; name it with `crate::`", &u.target[1..]))
                }
                None => problems.push(format!("{at}: `crate::{}` is no module of the table", &u.target[1..])),
                Some(to) if to > from => problems
                    .push(format!("{at}: `{module}` (layer {from}) uses `{}` (layer {to}), a higher layer", u.target)),
                Some(to) if to == from => problems.push(format!(
                    "{at}: `{module}` (layer {from}) uses `{}` (layer {to}), another module of its own layer",
                    u.target
                )),
                Some(_) => {}
            }
        }
    }
    assert!(problems.is_empty(), "module layering broken:\n{}", problems.join("\n"));
}

// ---- public surface ----

/// The most `pub` items `src/` may declare (module docs: how they are
/// counted).
const PUBLIC_ITEM_BUDGET: usize = 250;

/// The kinds of item the count looks for after `pub `.
const PUBLIC_KINDS: [&str; 11] =
    ["fn", "struct", "enum", "trait", "type", "const", "static", "mod", "use", "unsafe fn", "async fn"];

/// True when `line` declares a `pub` item: `pub ` at its start (after
/// indentation) followed by one of `PUBLIC_KINDS` as a whole word.
fn declares_public_item(line: &str) -> bool {
    let Some(rest) = line.trim_start().strip_prefix("pub ") else { return false };
    PUBLIC_KINDS.iter().any(|kind| rest.strip_prefix(kind).is_some_and(|after| !after.starts_with(is_ident)))
}

/// `src/` declares at most `PUBLIC_ITEM_BUDGET` public items, so the
/// library's public surface does not grow unnoticed: a new item needs a
/// user outside the crate (the CLI, the Python package, the sibling crates,
/// the fuzz targets) or goes behind `research_pub!`.
#[test]
fn public_items_stay_within_the_budget() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut items = Vec::new();
    for file in &files {
        let rel = file.strip_prefix(&src).expect("under src");
        if rel.to_string_lossy().contains("tests") {
            continue;
        }
        let text = std::fs::read_to_string(file).expect("read");
        for (i, line) in text.lines().enumerate() {
            if declares_public_item(line) && !line.contains("tests") {
                items.push(format!("src/{}:{}: {}", rel.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(items.len() > 50, "the count found only {} public items under {}", items.len(), src.display());
    assert!(
        items.len() <= PUBLIC_ITEM_BUDGET,
        "{} public items, above the budget of {PUBLIC_ITEM_BUDGET}: make the new ones `pub(crate)` (or \
         `research_pub!` when only crates/odocal-lab needs them), or raise the budget with the reason:\n{}",
        items.len(),
        items.join("\n")
    );
}

// ---- self-contained repository ----

/// Build output and version control, relative to the root: not sources.
const GENERATED: [&str; 7] =
    [".git", "target", "crates/odocal-lab/target", "fuzz/target", "fuzz/artifacts", "fuzz/coverage", "out"];

/// Extensions of the text files that can refer to data: sources, tests,
/// manifests, scripts and their documentation. Files without an extension
/// (`.ci/run`) are read too.
const TEXT_EXTENSIONS: [&str; 11] = ["rs", "toml", "py", "sh", "md", "json", "yml", "yaml", "txt", "cff", "cfg"];

/// What a reference to the data folder beside the repository looks like
/// (built with `concat!` so this file does not name it).
const OUTSIDE_REFERENCES: [&str; 2] = [concat!("..", "/shared"), concat!("shared", "/data")];

fn repository_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The text files under `dir` (recursively), leaving out the paths in
/// `skip` (relative to `root`).
fn text_files(root: &Path, dir: &Path, skip: &[&str], out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.unwrap_or_else(|e| panic!("{}: {e}", dir.display())).path();
        let relative = path.strip_prefix(root).expect("under the root");
        if skip.iter().any(|s| relative == Path::new(s)) {
            continue;
        }
        if path.is_dir() {
            text_files(root, &path, skip, out);
        } else if path.extension().is_none_or(|x| TEXT_EXTENSIONS.iter().any(|t| x == *t)) {
            out.push(path);
        }
    }
}

/// The repository is self-contained: the real logs are in `data/`, and no
/// source, test, example, manifest or script reads them from beside it.
#[test]
fn nothing_refers_to_shared_outside_the_repository() {
    let root = repository_root();
    let skip: Vec<&str> = GENERATED.to_vec();
    let mut files = Vec::new();
    text_files(&root, &root, &skip, &mut files);
    files.sort();
    assert!(files.len() > 100, "the walk found only {} files under {}", files.len(), root.display());
    let mut found = Vec::new();
    for file in &files {
        // Binary files without an extension (fuzz corpus inputs) are not text.
        let Ok(text) = std::fs::read_to_string(file) else { continue };
        for (i, line) in text.lines().enumerate() {
            if OUTSIDE_REFERENCES.iter().any(|r| line.contains(r)) {
                let relative = file.strip_prefix(&root).expect("under the root");
                found.push(format!("{}:{}: {}", relative.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "{} line(s) refer to data outside the repository (use data/ at the repository root):\n{}",
        found.len(),
        found.join("\n")
    );
}

/// The product crates: the library and the layers over it that users run.
const PRODUCT_CRATES: [&str; 6] =
    ["odocal", "odocal-cli", "odocal-py", "odocal-report", "odocal-online", "odocal-history"];

/// Longest function (from `fn` to its closing brace) and longest source
/// file (its lines outside test items), in lines.
const MAX_FUNCTION_LINES: usize = 120;
const MAX_FILE_LINES: usize = 1000;

/// Every `fn` with a body in `code` (comments, strings and test items
/// blanked): its name, first line (1-based) and length in lines, from the
/// `fn` keyword to the brace that closes its body.
fn functions(code: &str) -> Vec<(String, usize, usize)> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(at) = code[from..].find("fn ").map(|p| p + from) {
        from = at + 3;
        if code[..at].chars().next_back().is_some_and(is_ident) {
            continue;
        }
        let name: String = code[from..].trim_start().chars().take_while(|c| is_ident(*c)).collect();
        // A function pointer type (`fn(f64) -> f64`) has no name.
        if name.is_empty() {
            continue;
        }
        let rest = &code[from..];
        let Some(open) = rest.find(['{', ';']).filter(|&i| rest.as_bytes()[i] == b'{') else { continue };
        let close = closing_brace(rest, open).unwrap_or(rest.len());
        let first = code[..at].matches('\n').count() + 1;
        let last = code[..from + close].matches('\n').count() + 1;
        out.push((name, first, last - first + 1));
    }
    out
}

/// No function over [`MAX_FUNCTION_LINES`] and no file over
/// [`MAX_FILE_LINES`] lines of code outside tests in the product crates.
#[test]
fn functions_and_files_stay_short() {
    let root = repository_root();
    let mut long = Vec::new();
    let mut checked = 0;
    for krate in PRODUCT_CRATES {
        let mut files = Vec::new();
        sources(&root.join("crates").join(krate).join("src"), &mut files);
        for file in files {
            let relative = file.strip_prefix(&root).expect("under the root").to_path_buf();
            if is_test_file(&file) || relative.components().any(|c| c.as_os_str() == "tests") {
                continue;
            }
            let text = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            let all_code = code_only(&text);
            let code = without_test_items(&all_code);
            let test_lines: usize = test_items(&all_code).iter().map(|r| all_code[r.clone()].lines().count()).sum();
            let lines = text.lines().count() - test_lines;
            if lines > MAX_FILE_LINES {
                long.push(format!("{}: {lines} lines outside tests (at most {MAX_FILE_LINES})", relative.display()));
            }
            for (name, first, length) in functions(&code) {
                checked += 1;
                if length > MAX_FUNCTION_LINES {
                    long.push(format!(
                        "{}:{first}: fn {name} is {length} lines (at most {MAX_FUNCTION_LINES})",
                        relative.display()
                    ));
                }
            }
        }
    }
    assert!(checked > 1000, "only {checked} functions found: the scan is broken");
    assert!(long.is_empty(), "split these into parts with one idea each:\n{}", long.join("\n"));
}

#[test]
fn functions_are_measured_from_fn_to_the_closing_brace() {
    let code = "fn a() {\n    let f: fn(u8) = g;\n}\ntrait T { fn b(&self); }\nimpl X {\n    pub fn c() -> u8 {\n        { 1 }\n    }\n}\n";
    let found = functions(code);
    assert_eq!(found, vec![("a".to_string(), 1, 3), ("c".to_string(), 6, 3)]);
}
