//! Where in a TOML file's text an error lies: its line and column, and the
//! full name of a key the parser reports twice (its message, `duplicate
//! key`, names none; its span covers the key's last part).

use std::ops::Range;

/// The 1-based line and column (in characters) of byte offset `at` in
/// `text` (the end of the text when `at` lies beyond it or inside a
/// character).
pub(crate) fn line_column(text: &str, at: usize) -> (usize, usize) {
    let before = text.get(..at).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
    (line, column)
}

/// The dotted name of the key a `duplicate key` error's `span` points at:
/// the table header's name when the span lies in a header (`[a.b]` gives
/// `a.b`), else the key as written with the last header before it
/// (`[output]` … `rate_hz = 1` gives `output.rate_hz`; a key inside an
/// inline table `a = { x = 1, x = 2 }` gives `a.x`). `None` when the span
/// lies outside the text.
pub(crate) fn duplicate_key(text: &str, span: Range<usize>) -> Option<String> {
    let name = text.get(span.clone())?.trim();
    let line_start = text.get(..span.start)?.rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next().unwrap_or("");
    if let Some(header) = table_header(line) {
        return Some(header);
    }
    let within = span.start - line_start;
    let key = match line.find('=') {
        Some(eq) if within < eq => line[..eq].trim().to_string(),
        Some(eq) => format!("{}.{name}", line[..eq].trim()),
        None => name.to_string(),
    };
    let table = text[..line_start].lines().rev().find_map(table_header);
    Some(match table {
        Some(t) => format!("{t}.{key}"),
        None => key,
    })
}

/// The name of the table a header line opens (`[a.b]` or `[[a.b]]`, a
/// comment after it allowed), `None` for any other line.
fn table_header(line: &str) -> Option<String> {
    let l = line.trim();
    if !l.starts_with('[') {
        return None;
    }
    let inner = l.trim_start_matches('[');
    let end = inner.find(']')?;
    Some(inner[..end].trim().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The span the toml parser gives a duplicate key, and the name found
    /// from it.
    fn named(text: &str) -> String {
        let e = toml::from_str::<toml::Table>(text).expect_err("a duplicate");
        assert_eq!(e.message(), "duplicate key", "{text:?}");
        duplicate_key(text, e.span().expect("a span")).expect("a name")
    }

    #[test]
    fn a_duplicate_key_is_named_with_its_table() {
        assert_eq!(named("[output]\nrate_hz = 40.0\nrate_hz = 41.0\n"), "output.rate_hz");
        assert_eq!(named("x = 1\nx = 2\n"), "x");
        assert_eq!(named("[a]\nx = 1\n[b.c]  # c\ny = 2\n[b.c]\nz = 3\n"), "b.c");
        assert_eq!(named("a = { x = 1, x = 2 }\n"), "a.x");
        assert_eq!(named("[t]\nb.c = 1\nb.c = 2\n"), "t.b.c");
    }

    #[test]
    fn line_and_column_count_characters_from_one() {
        assert_eq!(line_column("ab\nµx = 1", 0), (1, 1));
        assert_eq!(line_column("ab\nµx = 1", 3), (2, 1));
        assert_eq!(line_column("ab\nµx = 1", 5), (2, 2));
        assert_eq!(line_column("ab", 99), (1, 3));
    }
}
