//! Configuration errors that name the file, the dotted key and, where the text is known, the
//! line and column; and the serde entry points that produce them.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

/// A configuration error: which file, which key, where and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read experiment file {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A key is unknown, has the wrong type or an invalid value, or the TOML does not parse.
    #[error("{}", invalid_message(path, *location, key, message))]
    Invalid {
        /// The file (or `<override>` / `<string>`).
        path: PathBuf,
        /// Line and column (1-based) when known.
        location: Option<(usize, usize)>,
        /// Dotted key, e.g. `joint.dlf_optim.lr` (empty for pure syntax errors).
        key: String,
        /// What went wrong and what was expected.
        message: String,
    },
}

fn invalid_message(
    path: &Path,
    location: Option<(usize, usize)>,
    key: &str,
    message: &str,
) -> String {
    let mut s = path.display().to_string();
    if let Some((line, col)) = location {
        s.push_str(&format!(":{line}:{col}"));
    }
    // a key or a parser's message can be as long as the file: both are cut
    if !key.is_empty() {
        s.push_str(&format!(": key `{}`", neurofluid_core::paths::cut(key, 80)));
    }
    s.push_str(&format!(": {}", neurofluid_core::paths::cut(message, 1000)));
    s
}

impl ConfigError {
    /// The dotted key the error is about (empty when none).
    pub fn key(&self) -> &str {
        match self {
            ConfigError::Invalid { key, .. } => key,
            _ => "",
        }
    }

    pub(crate) fn invalid(path: &Path, key: &str, message: impl Into<String>) -> Self {
        ConfigError::Invalid {
            path: path.to_path_buf(),
            location: None,
            key: key.to_string(),
            message: message.into(),
        }
    }
}

/// 1-based line and column of byte `offset` in `text`.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map_or(before.chars().count(), |nl| {
        before[nl + 1..].chars().count()
    }) + 1;
    (line, col)
}

/// Joins serde's path and the message into a dotted key: `unknown field `x`` at `joint`
/// becomes `joint.x`; `missing field `name`` at `.` becomes `name`.
fn dotted_key(path: &str, message: &str) -> String {
    let base = if path == "." { "" } else { path };
    for prefix in ["unknown field `", "missing field `"] {
        if let Some(rest) = message.strip_prefix(prefix)
            && let Some(end) = rest.find('`')
        {
            let field = &rest[..end];
            if base == field || base.ends_with(&format!(".{field}")) {
                return base.to_string();
            }
            return if base.is_empty() {
                field.to_string()
            } else {
                format!("{base}.{field}")
            };
        }
    }
    base.to_string()
}

/// The value an error `message` of serde's quotes: an unknown variant's name or a value of the
/// wrong type (`invalid type: string "x"`, `` integer `3` ``, `` floating point `1.5` ``,
/// `` boolean `true` ``).
fn quoted_value(message: &str) -> Option<toml::Value> {
    let between = |rest: &str, close: char| rest.find(close).map(|end| rest[..end].to_string());
    if let Some(rest) = message.strip_prefix("unknown variant `") {
        return between(rest, '`').map(toml::Value::String);
    }
    let rest = message.strip_prefix("invalid type: ")?;
    if let Some(rest) = rest.strip_prefix("string \"") {
        return between(rest, '"').map(toml::Value::String);
    }
    let (kind, rest) = rest.split_once(" `")?;
    let text = between(rest, '`')?;
    match kind {
        "integer" => text.parse().ok().map(toml::Value::Integer),
        "floating point" => text.parse().ok().map(toml::Value::Float),
        "boolean" => text.parse().ok().map(toml::Value::Boolean),
        _ => None,
    }
}

/// Where serde names a table for an error in one of its keys (a table with flattened fields,
/// such as `[dlf]`'s rules, loses the field's name), the key of `root` under `key` holding the
/// value the message quotes, where exactly one does.
fn field_in_table(root: &toml::Table, key: &str, message: &str) -> Option<String> {
    let wanted = quoted_value(message)?;
    let mut table = root;
    for part in key.split('.').filter(|p| !p.is_empty()) {
        table = table.get(part)?.as_table()?;
    }
    let mut holding = table.iter().filter(|(_, v)| **v == wanted);
    match (holding.next(), holding.next()) {
        (Some((field, _)), None) if key.is_empty() => Some(field.clone()),
        (Some((field, _)), None) => Some(format!("{key}.{field}")),
        _ => None,
    }
}

/// The dotted key of serde's error `message` at `path` in the experiment `root`, and the
/// message, which for a retired option says where it went.
fn key_and_message(path: &str, message: &str, root: &toml::Table) -> (String, String) {
    let key = dotted_key(path, message);
    let key = field_in_table(root, &key, message).unwrap_or(key);
    let message = match super::legacy::retired_note(&key) {
        Some(note) => format!("{message}: {note}"),
        None => message.to_string(),
    };
    (key, message)
}

/// Deserializes `T` from TOML `text`; errors name `origin`, the dotted key and line:col.
pub fn from_toml_str<T: DeserializeOwned>(text: &str, origin: &Path) -> Result<T, ConfigError> {
    let de = toml::Deserializer::parse(text).map_err(|e| ConfigError::Invalid {
        path: origin.to_path_buf(),
        location: e.span().map(|s| line_col(text, s.start)),
        key: String::new(),
        message: format!("TOML syntax error: {}", e.message()),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let root = text.parse::<toml::Table>().unwrap_or_default();
        let (key, message) = key_and_message(&path, inner.message(), &root);
        ConfigError::Invalid {
            path: origin.to_path_buf(),
            location: inner.span().map(|s| line_col(text, s.start)),
            key,
            message,
        }
    })
}

/// Deserializes `T` from an in-memory TOML table (used after overrides).
pub(crate) fn from_table<T: DeserializeOwned>(
    table: toml::Table,
    origin: &Path,
) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(toml::Value::Table(table.clone())).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let (key, message) = key_and_message(&path, inner.message(), &table);
        ConfigError::Invalid {
            path: origin.to_path_buf(),
            location: None,
            key,
            message,
        }
    })
}

/// Reads a file, with an error naming it.
pub(crate) fn read_text(path: &Path) -> Result<String, ConfigError> {
    neurofluid_core::input_file::read_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })
}
