//! Names and paths that come from data files, checked before they are joined to a folder: a
//! name that becomes a file or folder name must be exactly one path component, and a relative
//! path must stay inside its dataset folder (no absolute paths, no `..` climbing out).
//! The checks are lexical: they look at the text, not at what is on disk.

use std::path::{Component, Path};

/// The longest name a file system takes for one path component, in bytes.
const MAX_NAME_BYTES: usize = 255;

/// Checks that `name` is exactly one ordinary path component: not empty, not `.` or `..`, and
/// without `/`, `\` or NUL, so joining it to a folder names something inside that folder.
pub fn one_component(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= MAX_NAME_BYTES
        && name != "."
        && name != ".."
        && !name.contains(['/', '\\', '\0'])
        && matches!(
            Path::new(name).components().collect::<Vec<_>>().as_slice(),
            [Component::Normal(_)]
        );
    if ok {
        return Ok(());
    }
    Err(format!(
        "a plain name (one path component of at most {MAX_NAME_BYTES} bytes, no `/`, `\\` or \
         `..`), found {}",
        shown(name)
    ))
}

/// The first item of `items` (names in a list) that an earlier one repeats.
pub fn first_repeated<T: Eq + std::hash::Hash>(items: &[T]) -> Option<&T> {
    let mut seen = std::collections::HashSet::new();
    items.iter().find(|item| !seen.insert(*item))
}

/// The characters of a name a message shows at most.
const SHOWN_CHARS: usize = 60;

/// `name` quoted for a message, cut to its first 60 characters with its length said, so a
/// name of any length makes a message of bounded length.
pub fn shown(name: &str) -> String {
    quoted(name, SHOWN_CHARS)
}

/// `text` quoted, cut to its first `chars` characters with its length said when it was cut.
pub fn quoted(text: &str, chars: usize) -> String {
    match head(text, chars) {
        (all, None) => format!("{all:?}"),
        (head, Some(count)) => format!("{head:?}… ({count} characters)"),
    }
}

/// `text` cut to its first `chars` characters, its length said when it was cut.
pub fn cut(text: &str, chars: usize) -> String {
    match head(text, chars) {
        (all, None) => all.to_string(),
        (head, Some(count)) => format!("{head}… ({count} characters)"),
    }
}

/// `text`'s first `chars` characters, and its length in characters where that cuts it.
fn head(text: &str, chars: usize) -> (&str, Option<usize>) {
    match text.char_indices().nth(chars) {
        None => (text, None),
        Some((end, _)) => (&text[..end], Some(text.chars().count())),
    }
}

/// Checks that `rel`, joined to a folder `depth` levels below the dataset folder, names
/// something inside the dataset folder: relative, and its `..` never climb above it.
pub fn confined(rel: &str, depth: usize) -> Result<(), String> {
    let outside = || {
        format!(
            "a path inside the dataset folder (relative, not climbing out with `..`), found \
             {rel:?}"
        )
    };
    if rel.contains('\0') || rel.starts_with('\\') {
        return Err(outside());
    }
    let mut level = depth;
    for c in Path::new(rel).components() {
        match c {
            Component::Normal(_) => level += 1,
            Component::CurDir => {}
            Component::ParentDir => level = level.checked_sub(1).ok_or_else(outside)?,
            Component::RootDir | Component::Prefix(_) => return Err(outside()),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_one_component() {
        for ok in ["view_1", "v5 x", "a.b", "..x"] {
            assert!(one_component(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            ".",
            "..",
            "a/b",
            "../../tmp/evil",
            "/tmp",
            "a\\b",
            "x/",
            "a\0",
            &"v".repeat(256),
        ] {
            assert!(one_component(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn repeats_are_found_and_long_names_cut() {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            first_repeated(&names(&["a", "b", "a", "b"])).map(String::as_str),
            Some("a")
        );
        assert_eq!(first_repeated(&names(&["a", "b"])), None);
        assert_eq!(shown("view_1"), "\"view_1\"");
        let long = "x".repeat(100 << 20);
        let s = shown(&long);
        assert!(s.len() < 120 && s.contains("104857600 characters"), "{s}");
    }

    #[test]
    fn paths_stay_inside() {
        assert!(confined("train/0001", 1).is_ok());
        assert!(confined("./particles/0001.npz", 2).is_ok());
        assert!(confined("../box.pt", 1).is_ok());
        assert!(confined("../../view_2/train/particles/1.npz", 2).is_ok());
        for bad in ["../box.pt", "/etc/passwd", "a/../../b", "\\\\host\\x"] {
            assert!(confined(bad, 0).is_err(), "{bad}");
        }
        assert!(confined("../../../x", 2).is_err());
    }
}
