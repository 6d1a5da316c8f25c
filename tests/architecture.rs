//! The layer rule of ARCHITECTURE.md: a module uses only modules of its own or a lower layer
//! (read from the source: every `crate::name` outside comments).

use std::path::Path;

/// The layers of ARCHITECTURE.md.
const LAYERS: &[(&str, u32)] = &[
    ("error", 0),
    ("math", 0),
    ("kernel", 0),
    ("particles", 1),
    ("neighbors", 1),
    ("geometry", 2),
    ("operators", 2),
    ("consistent", 2),
    ("diagnostics", 2),
    ("boundary", 2),
    ("poisson", 3),
    ("pair_weights", 3),
    ("projection", 4),
    ("distributed", 5),
    ("setup", 4),
    ("time", 5),
    ("flow", 5),
    ("record", 6),
    ("scene", 7),
    ("reference", 7),
    ("sampling", 7),
    ("plot", 0),
];

fn layer(module: &str) -> Option<u32> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|(_, l)| *l)
}

/// `crate::name` references outside comments.
fn uses(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(k) = rest.find("crate::") {
            let tail = &rest[k + 7..];
            let name: String = tail
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            out.push(name);
            rest = tail;
        }
    }
    out
}

#[test]
fn modules_depend_only_on_their_own_or_lower_layers() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut violations = Vec::new();
    let mut checked = 0;
    for (module, own) in LAYERS {
        let file = src.join(format!("{module}.rs"));
        let dir = src.join(module);
        let mut files = Vec::new();
        if file.exists() {
            files.push(file);
        }
        if dir.is_dir() {
            for e in std::fs::read_dir(&dir).unwrap() {
                let p = e.unwrap().path();
                if p.extension().is_some_and(|x| x == "rs") {
                    files.push(p);
                }
            }
        }
        assert!(
            !files.is_empty(),
            "module {module} of ARCHITECTURE.md not found"
        );
        for f in files {
            checked += 1;
            let text = std::fs::read_to_string(&f).unwrap();
            for used in uses(&text) {
                match layer(&used) {
                    Some(l) if l > *own => violations.push(format!(
                        "{} (layer {own}) uses crate::{used} (layer {l})",
                        f.display()
                    )),
                    None if !["Error", "Result", "prelude"].contains(&used.as_str()) => violations
                        .push(format!(
                            "{}: crate::{used} is not in ARCHITECTURE.md's layers",
                            f.display()
                        )),
                    _ => {}
                }
            }
        }
    }
    assert!(checked > 20, "only {checked} files read");
    assert!(
        violations.is_empty(),
        "layer violations:\n{}",
        violations.join("\n")
    );
}

#[test]
fn every_module_of_lib_rs_has_a_layer() {
    let lib =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).unwrap();
    for line in lib.lines() {
        if let Some(m) = line.trim().strip_prefix("pub mod ") {
            let m: String = m
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            let m = m.as_str();
            if m == "prelude" {
                continue;
            }
            assert!(
                layer(m).is_some(),
                "module {m} has no layer in ARCHITECTURE.md"
            );
        }
    }
}
