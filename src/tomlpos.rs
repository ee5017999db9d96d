//! Where a key sits in TOML text: lines and dotted key paths for error messages that name the
//! file, the line and the key (campaign files, the service configuration), the one error type
//! both report with, and the bounded reading of the files they name.
use std::io::Read;
use std::ops::Range;
use std::path::Path;

/// An error pointing into a TOML file: `file:line: key: message` (line 0: the whole file).
/// Campaign files ([`crate::campaign::spec::SpecError`]) and the service configuration
/// ([`crate::api::ConfigError`]) both report with it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{origin}:{line}: {key}: {}", crate::types::shorten_numbers(message))]
pub struct TomlError {
    pub origin: String,
    pub line: usize,
    pub key: String,
    pub message: String,
}

impl TomlError {
    /// The error of `toml::from_str` on `text`: its line and the key it sits on.
    pub(crate) fn from_toml(text: &str, origin: &str, e: &toml::de::Error) -> TomlError {
        // The parser's recursion limit comes without a place: the most deeply nested spot is
        // where it tripped.
        let span = e.span().or_else(|| {
            e.message()
                .contains("recursion")
                .then(|| deepest_nesting(text))
                .flatten()
                .map(|at| at..at + 1)
        });
        TomlError {
            origin: origin.into(),
            line: span.clone().map(|s| line_of(text, s.start)).unwrap_or(0),
            key: span
                .and_then(|s| key_at(text, s))
                .unwrap_or_else(|| "-".into()),
            message: e.message().trim().to_string(),
        }
    }
}

/// Byte offset of the first place where `[`/`{` nesting is deepest (outside strings and
/// comments); None when nothing nests.
fn deepest_nesting(text: &str) -> Option<usize> {
    let (mut depth, mut best, mut at) = (0usize, 0usize, None);
    let mut quote: Option<char> = None;
    let mut comment = false;
    for (i, c) in text.char_indices() {
        match (quote, c) {
            _ if comment => comment = c != '\n',
            (Some(q), c) if c == q => quote = None,
            (Some(_), _) => {}
            (None, '"' | '\'') => quote = Some(c),
            (None, '#') => comment = true,
            (None, '[' | '{') => {
                depth += 1;
                if depth > best {
                    best = depth;
                    at = Some(i);
                }
            }
            (None, ']' | '}') => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    at
}

/// Largest TOML file read (campaigns, stage models, the service configuration).
pub(crate) const MAX_TOML_BYTES: u64 = 1 << 20;

/// Reads a regular file of at most `limit` bytes as UTF-8. Devices, fifos, directories and
/// kernel files (/proc, /sys) are refused before a byte is read (`/dev/zero` would never end),
/// and the read stops one byte past the limit whatever the file's metadata claims.
pub(crate) fn read_bounded(path: &Path, limit: u64) -> Result<String, ReadError> {
    let bytes = read_bounded_bytes(path, limit)?;
    String::from_utf8(bytes).map_err(|_| ReadError::NotUtf8)
}

/// Why [`read_bounded`] refused a file; the text names no path (callers put it in front).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("{}", io_reason(.0))]
    Io(#[from] std::io::Error),
    #[error("not a regular file")]
    NotRegular,
    #[error("larger than {0} bytes")]
    TooLarge(u64),
    #[error("not UTF-8 text")]
    NotUtf8,
}

/// [`read_bounded`] without the UTF-8 check: the bytes of a regular file of at most `limit`
/// bytes (PNG frames).
pub(crate) fn read_bounded_bytes(path: &Path, limit: u64) -> Result<Vec<u8>, ReadError> {
    // Before opening: opening a fifo blocks until someone writes to it.
    let meta = std::fs::metadata(path)?;
    // Kernel files (/proc, /sys) pass for regular ones of size 0.
    let kernel = path
        .canonicalize()
        .is_ok_and(|p| p.starts_with("/proc") || p.starts_with("/sys"));
    if !meta.is_file() || kernel {
        return Err(ReadError::NotRegular);
    }
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(ReadError::NotRegular);
    }
    if meta.len() > limit {
        return Err(ReadError::TooLarge(limit));
    }
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(ReadError::TooLarge(limit));
    }
    Ok(bytes)
}

pub(crate) fn io_reason(e: &std::io::Error) -> String {
    use std::io::ErrorKind as K;
    match e.kind() {
        K::NotFound => "no such file".into(),
        K::PermissionDenied => "permission denied".into(),
        K::IsADirectory => "not a regular file".into(),
        _ => format!("cannot read ({})", e.kind()),
    }
}

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
