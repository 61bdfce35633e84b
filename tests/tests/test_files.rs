//! Every integration-test file is built: with `autotests = false` (each crate's tests are one
//! binary of modules, `tests/main.rs`), a file that is neither a module of that binary nor a
//! `[[test]]` target of its own would never compile or run.

use neurofluid_tests::workspace_root;

/// The names in `mod name;` lines of a crate root.
fn modules(main: &str) -> Vec<String> {
    main.lines()
        .filter_map(|l| l.trim().strip_prefix("mod ")?.strip_suffix(';'))
        .map(str::to_string)
        .collect()
}

#[test]
fn every_test_file_is_a_module_of_the_crates_test_binary_or_a_target_of_its_own() {
    let root = workspace_root();
    let mut packages: Vec<_> = std::fs::read_dir(root.join("crates"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    packages.push(root.join("tests"));
    let mut merged = 0;
    for package in packages {
        let manifest = std::fs::read_to_string(package.join("Cargo.toml")).unwrap();
        if !manifest.lines().any(|l| l.trim() == "autotests = false") {
            continue;
        }
        merged += 1;
        let main = std::fs::read_to_string(package.join("tests/main.rs")).unwrap();
        let mods = modules(&main);
        for entry in std::fs::read_dir(package.join("tests")).unwrap() {
            let path = entry.unwrap().path();
            let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
                continue;
            };
            let Some(stem) = name.strip_suffix(".rs") else {
                continue;
            };
            let target = format!("path = \"tests/{name}\"");
            assert!(
                stem == "main" || mods.iter().any(|m| m == stem) || manifest.contains(&target),
                "{}: not a module of tests/main.rs nor a [[test]] of {}",
                path.display(),
                package.join("Cargo.toml").display()
            );
        }
    }
    assert!(merged >= 6, "{merged} crates with merged test binaries");
}
