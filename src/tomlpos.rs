//! Where a key sits in TOML text: lines and dotted key paths for error messages that name the
//! file, the line and the key (campaign files, the service configuration).
use std::ops::Range;

/// 1-based line of a byte offset.
pub(crate) fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// Span of the key at a dotted path, e.g. `axes.x.range_um`; `None` when it is not in the text.
pub(crate) fn span_of(text: &str, path: &str) -> Option<Range<usize>> {
    match walk_path(text, path)? {
        (span, false) => Some(span),
        (_, true) => None,
    }
}

/// Span of the deepest part of a dotted path present in the text (the key, else its table).
pub(crate) fn span_of_deepest(text: &str, path: &str) -> Option<Range<usize>> {
    walk_path(text, path).map(|(span, _)| span)
}

/// The span of the deepest key of `path` found (a value ends the walk), and whether a part of
/// the path is missing from the text.
fn walk_path(text: &str, path: &str) -> Option<(Range<usize>, bool)> {
    use toml::de::{DeTable, DeValue};
    let doc = DeTable::parse(text).ok()?;
    let mut table = doc.get_ref();
    let mut best = None;
    let parts: Vec<&str> = path.split('.').collect();
    for (i, part) in parts.iter().enumerate() {
        let Some((k, v)) = table.iter().find(|(k, _)| k.get_ref().as_ref() == *part) else {
            return best.map(|s| (s, true));
        };
        best = Some(k.span());
        match v.get_ref() {
            DeValue::Table(t) if i + 1 < parts.len() => table = t,
            _ => return best.map(|s| (s, false)),
        }
    }
    best.map(|s| (s, false))
}

/// The dotted key whose key or value contains `span` (the deepest one), or, in text that does
/// not parse, the key on that line under its table header (or the header itself).
pub(crate) fn key_at(text: &str, span: Range<usize>) -> Option<String> {
    use toml::de::{DeTable, DeValue};
    fn walk(t: &DeTable<'_>, span: &Range<usize>, prefix: &str) -> Option<String> {
        for (k, v) in t.iter() {
            let name = if prefix.is_empty() {
                k.get_ref().to_string()
            } else {
                format!("{prefix}.{}", k.get_ref())
            };
            let (ks, vs) = (k.span(), v.span());
            let inside =
                |r: &Range<usize>| r.start <= span.start && span.start < r.end.max(r.start + 1);
            if let DeValue::Table(sub) = v.get_ref() {
                if let Some(deeper) = walk(sub, span, &name) {
                    return Some(deeper);
                }
            }
            if inside(&ks) || inside(&vs) {
                return Some(name);
            }
        }
        None
    }
    if let Some(k) = DeTable::parse(text)
        .ok()
        .and_then(|doc| walk(doc.get_ref(), &span, ""))
    {
        return Some(k);
    }
    // The document does not parse (syntax error, duplicate key): read the key off the line,
    // under the last table header above it.
    let at = span.start.min(text.len());
    let line_start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next().unwrap_or("").trim();
    let header = |l: &str| {
        l.strip_prefix('[')
            .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_string())
    };
    if let Some(h) = header(line) {
        return Some(h);
    }
    let table = text[..line_start]
        .lines()
        .rev()
        .find_map(|l| header(l.trim()));
    let key = line
        .split_once('=')
        .map(|(k, _)| k.trim().trim_matches('"').to_string())
        .filter(|k| !k.is_empty());
    match (table, key) {
        (Some(t), Some(k)) => Some(format!("{t}.{k}")),
        (None, Some(k)) => Some(k),
        (t, None) => t,
    }
}
