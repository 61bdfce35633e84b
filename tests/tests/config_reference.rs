//! `docs/configuration.md`, the reference of every key of an experiment file, is generated from
//! the config types: their fields and doc comments (read from the sources) and their defaults
//! (an experiment resolved from a minimal file). The test fails when the committed file is not
//! what the types give; `NEUROFLUID_BLESS=1` rewrites it.

use std::collections::BTreeMap;
use std::path::Path;

use neurofluid_tests::workspace_root;
use neurofluid_train::config::{Experiment, Settings};

/// The source files that hold the types of the experiment file.
const SOURCES: &[&str] = &[
    "crates/neurofluid-train/src/config/mod.rs",
    "crates/neurofluid-train/src/config/sections.rs",
    "crates/neurofluid-train/src/optim.rs",
    "crates/neurofluid-train/src/stages/joint/terms/mod.rs",
    "crates/neurofluid-train/src/stages/joint/terms/anchor.rs",
    "crates/neurofluid-train/src/stages/joint/terms/energy.rs",
    "crates/neurofluid-train/src/stages/joint/terms/truth.rs",
    "crates/neurofluid-dlf/src/config.rs",
    "crates/neurofluid-dlf/src/rules.rs",
    "crates/neurofluid-physnerf/src/config.rs",
    "crates/neurofluid-physnerf/src/nerf.rs",
    "crates/neurofluid-core/src/half_matmul.rs",
    "crates/neurofluid-core/src/lr_schedule.rs",
    "crates/neurofluid-core/src/device_search.rs",
];

/// The generated file, relative to the repository root.
const REFERENCE: &str = "docs/configuration.md";

/// A field of a struct: its name, type, doc and whether serde inlines it.
#[derive(Debug, Clone)]
struct Field {
    name: String,
    ty: String,
    doc: String,
    flatten: bool,
    skip: bool,
    /// Whether serde fills it when the file leaves it out (its own `default` or its struct's).
    defaulted: bool,
}

/// What the sources say of the types.
#[derive(Debug, Default)]
struct Types {
    structs: BTreeMap<String, (String, Vec<Field>)>,
    /// Unit-variant enums: their values as written in a file (snake case).
    enums: BTreeMap<String, Vec<String>>,
}

fn snake(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.extend(c.to_lowercase());
    }
    out
}

/// The type a field's table or value is: `Option<T>`, `Vec<T>` and paths reduced to `T`'s name.
fn base_type(ty: &str) -> String {
    let mut t = ty.trim().trim_end_matches(',').to_string();
    for wrapper in ["Option<", "Vec<"] {
        if let Some(inner) = t.strip_prefix(wrapper) {
            t = inner.strip_suffix('>').unwrap_or(inner).to_string();
        }
    }
    let t = t.split('<').next().unwrap_or(&t);
    t.rsplit("::").next().unwrap_or(t).to_string()
}

/// The doc comment lines above a line, joined.
fn joined(doc: &[String]) -> String {
    doc.join(" ").trim().to_string()
}

fn parse(types: &mut Types, text: &str) {
    let lines: Vec<&str> = text.lines().collect();
    let mut doc: Vec<String> = Vec::new();
    let mut attrs: Vec<String> = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i].trim_end();
        if let Some(d) = line.strip_prefix("///") {
            doc.push(d.trim().to_string());
        } else if line.starts_with("#[") {
            attrs.push(line.to_string());
        } else if let Some(rest) = line
            .strip_prefix("pub struct ")
            .filter(|r| r.ends_with('{'))
        {
            let name = rest.split(['<', ' ', '{']).next().unwrap_or("").to_string();
            let struct_doc = joined(&doc);
            let all_default = attrs.iter().any(|a| {
                a.contains("serde(") && (a.contains(" default") || a.contains("(default"))
            });
            let (mut fields, mut fdoc, mut fattrs) = (Vec::new(), Vec::new(), Vec::new());
            i += 1;
            while i < lines.len() && lines[i] != "}" {
                let l = lines[i].trim();
                if let Some(d) = l.strip_prefix("///") {
                    fdoc.push(d.trim().to_string());
                } else if l.starts_with("#[") {
                    fattrs.push(l.to_string());
                } else if let Some(f) = l.strip_prefix("pub ") {
                    if let Some((fname, ty)) = f.split_once(':') {
                        let has = |what: &str| fattrs.iter().any(|a: &String| a.contains(what));
                        fields.push(Field {
                            name: fname.trim().to_string(),
                            ty: ty.trim().trim_end_matches(',').to_string(),
                            doc: joined(&fdoc),
                            flatten: has("flatten"),
                            skip: has("serde(skip)"),
                            defaulted: all_default || has("default"),
                        });
                    }
                    fdoc.clear();
                    fattrs.clear();
                } else if !l.is_empty() {
                    fdoc.clear();
                    fattrs.clear();
                }
                i += 1;
            }
            types.structs.insert(name, (struct_doc, fields));
        } else if let Some(rest) = line.strip_prefix("pub enum ").filter(|r| r.ends_with('{')) {
            let name = rest.split([' ', '{']).next().unwrap_or("").to_string();
            let snake_case = attrs
                .iter()
                .any(|a| a.contains("rename_all = \"snake_case\""));
            let lowercase = attrs
                .iter()
                .any(|a| a.contains("rename_all = \"lowercase\""));
            // an internally tagged enum's variants are tables, not values
            let tagged = attrs.iter().any(|a| a.contains("tag ="));
            let mut variants = Vec::new();
            i += 1;
            while i < lines.len() && lines[i] != "}" {
                let l = lines[i].trim();
                let unit = l.ends_with(',') && l[..l.len() - 1].chars().all(char::is_alphanumeric);
                if unit && lines[i].starts_with("    ") && !lines[i].starts_with("     ") {
                    let v = &l[..l.len() - 1];
                    variants.push(if snake_case {
                        snake(v)
                    } else if lowercase {
                        v.to_lowercase()
                    } else {
                        v.to_string()
                    });
                }
                i += 1;
            }
            if !variants.is_empty() && !tagged {
                types.enums.insert(name, variants);
            }
        } else if let Some(list) = line.strip_prefix("terms! {") {
            // the particle terms: `name: module::Settings,` lines up to the closing brace
            let _ = list;
            let mut fields = Vec::new();
            i += 1;
            while i < lines.len() && lines[i].trim() != "}" {
                if let Some((name, ty)) = lines[i].trim().split_once(':') {
                    fields.push(Field {
                        name: name.trim().to_string(),
                        ty: format!("Option<{}>", ty.trim().trim_end_matches(',')),
                        doc: String::new(),
                        flatten: false,
                        skip: false,
                        defaulted: true,
                    });
                }
                i += 1;
            }
            let doc = "The particle terms of the joint stage, each under its own table; a term is \
                       on when its table is present with a weight above 0 (none: the paper's loss)."
                .to_string();
            types.structs.insert("TermsSection".into(), (doc, fields));
        }
        if !line.starts_with("///") && !line.starts_with("#[") {
            doc.clear();
            attrs.clear();
        }
        i += 1;
    }
}

/// Markdown of a table cell: no bars, no line breaks.
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace('\n', " ")
}

struct Writer<'a> {
    types: &'a Types,
    defaults: &'a BTreeMap<String, String>,
    out: String,
}

impl Writer<'_> {
    /// The section of the table `key` (`""`: the top level) of type `name`: its keys, then its
    /// tables.
    fn section(&mut self, key: &str, name: &str, doc: &str) {
        let Some((struct_doc, fields)) = self.types.structs.get(name) else {
            return;
        };
        let title = if key.is_empty() {
            "The top level".to_string()
        } else {
            format!("`[{key}]`")
        };
        self.out.push_str(&format!("\n## {title}\n\n"));
        let intro = if doc.is_empty() { struct_doc } else { doc };
        if !intro.is_empty() {
            self.out.push_str(&format!("{intro}\n\n"));
        }
        let mut rows = Vec::new();
        let mut tables = Vec::new();
        self.collect(key, fields, &mut rows, &mut tables);
        if !rows.is_empty() {
            self.out
                .push_str("| key | default | meaning |\n|---|---|---|\n");
            for (k, default, meaning) in rows {
                self.out.push_str(&format!(
                    "| `{k}` | {} | {} |\n",
                    cell(&default),
                    cell(&meaning)
                ));
            }
        }
        for (k, ty, doc) in tables {
            self.section(&k, &ty, &doc);
        }
    }

    fn collect(
        &self,
        key: &str,
        fields: &[Field],
        rows: &mut Vec<(String, String, String)>,
        tables: &mut Vec<(String, String, String)>,
    ) {
        for f in fields.iter().filter(|f| !f.skip) {
            let ty = base_type(&f.ty);
            let dotted = if key.is_empty() {
                f.name.clone()
            } else {
                format!("{key}.{}", f.name)
            };
            if let Some((_, inner)) = self.types.structs.get(&ty) {
                if f.flatten {
                    self.collect(key, inner, rows, tables);
                } else {
                    tables.push((dotted, ty, f.doc.clone()));
                }
                continue;
            }
            let default = match self.defaults.get(&dotted) {
                Some(v) => format!("`{v}`"),
                None if self
                    .defaults
                    .keys()
                    .any(|k| k.starts_with(&format!("{dotted}."))) =>
                {
                    // a table of its own (a tagged enum): its keys inline
                    let prefix = format!("{dotted}.");
                    let inner: Vec<String> = self
                        .defaults
                        .iter()
                        .filter_map(|(k, v)| k.strip_prefix(&prefix).map(|k| format!("{k} = {v}")))
                        .collect();
                    format!("`{{ {} }}`", inner.join(", "))
                }
                None if f.ty.starts_with("Option<") => "unset".into(),
                None if f.defaulted => "empty".into(),
                None => "required".into(),
            };
            let mut meaning = f.doc.clone();
            if let Some(values) = self.types.enums.get(&ty) {
                let values: Vec<String> = values.iter().map(|v| format!("`\"{v}\"`")).collect();
                meaning = format!("{meaning} One of {}.", values.join(", "));
            }
            rows.push((f.name.clone(), default, meaning.trim().to_string()));
        }
    }
}

/// The reference as the sources and defaults give it now.
fn generate(root: &Path) -> String {
    let mut types = Types::default();
    for file in SOURCES {
        let text =
            std::fs::read_to_string(root.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        parse(&mut types, &text);
    }
    let minimal = "name = \"reference\"\n[scene]\nbuiltin = \"watercube\"\n";
    let exp = Experiment::from_toml_str(minimal, Path::new("reference.toml")).unwrap();
    let defaults = Settings::all(&exp).0;
    let mut w = Writer {
        types: &types,
        defaults: &defaults,
        out: String::new(),
    };
    w.out.push_str(
        "# Configuration reference\n\n\
         Every key of an experiment file, with its default (the paper's setting where the paper has \
         one) and what it does. Generated from the config types' doc comments and defaults by \
         `tests/tests/config_reference.rs`; do not edit by hand: after changing a config type, \
         `NEUROFLUID_BLESS=1 cargo test -p neurofluid-tests --test end_to_end config_reference` \
         rewrites it, and the tests (CI) fail while it is stale. Defaults are those of a file that \
         sets only `name` and `[scene] builtin`; `preset = \"paper\"` resets the rules to the \
         paper's (docs/options.md). Keys of the previous release are still read, with a warning \
         naming the new key.\n",
    );
    w.section("", "Experiment", "");
    w.out
}

#[test]
fn the_configuration_reference_is_current() {
    let root = workspace_root();
    let now = generate(&root);
    let path = root.join(REFERENCE);
    if std::env::var_os("NEUROFLUID_BLESS").is_some() {
        std::fs::write(&path, &now).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == now,
        "{REFERENCE} is not what the config types give: run `NEUROFLUID_BLESS=1 cargo test -p \
         neurofluid-tests --test end_to_end config_reference` and commit it"
    );
    // every key the defaults hold is in the reference
    let exp = Experiment::from_toml_str(
        "name = \"reference\"\n[scene]\nbuiltin = \"watercube\"\n",
        Path::new("reference.toml"),
    )
    .unwrap();
    for key in Settings::all(&exp).0.keys() {
        // the key's row, or the row of the table it is inline in
        let parts: Vec<&str> = key.split('.').collect();
        let listed = (1..=parts.len()).any(|n| now.contains(&format!("| `{}` |", parts[n - 1])));
        assert!(
            listed || key.starts_with("scene.generate"),
            "{key} is not in the reference"
        );
    }
}
