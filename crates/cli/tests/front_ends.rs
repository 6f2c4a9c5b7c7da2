//! The command line and the Python package offer the same settings under
//! the same names. Three copies are compared, each read from
//! its source of truth:
//! - the flags of `nst3d <command> --help` (clap, from the CLI's structs);
//! - the keyword arguments of the matching functions in
//!   `python/nst3d/__init__.py`, and the names each passes to `_options(...)`;
//! - the option names `crates/python/src/options.rs` takes onto the
//!   library's settings (an option passed but never taken is an error at
//!   run time; an option never passed is a setting Python cannot reach).
//!
//! A flag in one front end and not the other fails here unless it is in an
//! exception list below, with the reason. Defaults are compared elsewhere:
//! Python passes only what the caller gave, so its defaults are the
//! library's, and each CLI command's unit test checks that its parsed
//! defaults build exactly the library's default settings.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Long flags of `nst3d <cmd> --help`, `_` for `-`, without the global ones.
fn cli_flags(cmd: &str) -> BTreeSet<String> {
    let out = Command::new(env!("CARGO_BIN_EXE_nst3d")).args([cmd, "--help"]).output().expect("run nst3d");
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    help.lines()
        .filter_map(|l| {
            // A flag's own line: "  -x, --name" or "      --name"; wrapped
            // help text is indented further.
            let rest = l.strip_prefix("      --").or_else(|| {
                let b = l.as_bytes();
                (l.len() > 8 && b[..3] == *b"  -" && &l[4..8] == ", --").then(|| &l[8..])
            })?;
            let name: String = rest.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-').collect();
            Some(name.replace('-', "_"))
        })
        .filter(|n| !["threads", "precision", "help", "version"].contains(&n.as_str()))
        .collect()
}

/// The text of Python function `name` (from its `def` to the next top-level
/// or same-indent `def`/`class`).
fn py_function(src: &str, name: &str) -> String {
    let start = src
        .find(&format!("def {name}(\n"))
        .or_else(|| src.find(&format!("def {name}(")))
        .unwrap_or_else(|| panic!("python/nst3d/__init__.py has no def {name}"));
    let indent = src[..start].rsplit('\n').next().unwrap().len();
    let body = &src[start..];
    let end = body[1..]
        .match_indices('\n')
        .map(|(i, _)| i + 2)
        .find(|&i| {
            let line = &body[i..];
            let lead = line.len() - line.trim_start_matches(' ').len();
            lead <= indent
                && (line.trim_start().starts_with("def ")
                    || line.trim_start().starts_with("class ")
                    || line.trim_start().starts_with('@'))
        })
        .unwrap_or(body.len());
    body[..end].to_string()
}

/// Parameter names of a Python function's signature.
fn py_params(func: &str) -> BTreeSet<String> {
    let sig = &func[func.find('(').unwrap() + 1..func.find("\n) ->").or_else(|| func.find(") ->")).unwrap()];
    // One parameter a line (`name: type = default,`): types hold commas.
    sig.split('\n')
        .map(str::trim)
        .filter(|p| !p.is_empty() && *p != "*" && *p != "cls" && *p != "self")
        .filter_map(|p| p.split([':', '=']).next().map(|n| n.trim().to_string()))
        .filter(|n| !n.is_empty() && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        .collect()
}

/// Keys of the function's `_options(...)` call.
fn py_options(func: &str) -> BTreeSet<String> {
    let call = &func[func.find("_options(").unwrap_or_else(|| panic!("no _options call in\n{func}"))..];
    let call = &call[..call.find("\n    )").unwrap_or(call.len())];
    call.split([',', '(', '\n'])
        .filter_map(|p| p.split_once('=').map(|(k, _)| k.trim().to_string()))
        .filter(|k| !k.is_empty())
        .collect()
}

/// Option names a Rust `apply_*` function of options.rs takes: every
/// `o.<getter>("name"` in its body.
fn rs_options(src: &str, func: &str) -> BTreeSet<String> {
    let start = src.find(&format!("pub fn {func}(")).unwrap_or_else(|| panic!("options.rs has no {func}"));
    let body = &src[start..];
    let body = &body[..body.find("\n}\n").unwrap()];
    body.match_indices("o.")
        .filter_map(|(i, _)| {
            let rest = &body[i + 2..];
            let open = rest.find("(\"")?;
            let getter = &rest[..open];
            if getter == "finish" || !getter.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                return None;
            }
            let name = &rest[open + 2..];
            Some(name[..name.find('"')?].to_string())
        })
        .collect()
}

fn set(names: &[&str]) -> BTreeSet<String> {
    names.iter().map(|s| s.to_string()).collect()
}

fn diff(a: &BTreeSet<String>, b: &BTreeSet<String>) -> Vec<String> {
    a.difference(b).cloned().collect()
}

struct Pairing {
    cli: &'static str,
    python: &'static str,
    rust: &'static str,
    /// Parameters that are not options: the data itself, callbacks.
    not_options: &'static [&'static str],
    /// Flags only the command line has, and why.
    cli_only: &'static [&'static str],
    /// Keyword arguments only Python has, and why.
    python_only: &'static [&'static str],
}

const PAIRINGS: &[Pairing] = &[
    Pairing {
        cli: "volume",
        python: "stylize_vdb",
        rust: "apply_volume",
        not_options: &["input", "out", "style", "progress", "projection"],
        cli_only: &[],
        // The old name of `camera`, still accepted with a DeprecationWarning.
        python_only: &["projection"],
    },
    Pairing {
        cli: "volume",
        python: "stylize_volume",
        rust: "apply_volume",
        not_options: &["density", "style", "progress", "report", "projection"],
        // An array in memory: no files, sequences or models (stylize_vdb,
        // Model.stylize); the camera file is read by the CLI's file job only;
        // the colour is written as a grid of the file (one array comes back).
        cli_only: &[
            "color",
            "color_grid",
            "input",
            "out",
            "frames",
            "ema",
            "ema_settle",
            "velocity_grid",
            "velocity_scale",
            "grid",
            "model",
            "tile",
            "tile_margin",
            "chunk",
            "warmup",
            "force",
            "work_dir",
            "camera_file",
            "style_map",
            "style_map_labels",
        ],
        python_only: &["density", "report", "projection"],
    },
    Pairing {
        cli: "strands",
        python: "stylize_groom_file",
        rust: "apply_strands",
        not_options: &["groom", "out", "style", "mesh", "progress"],
        cli_only: &[],
        python_only: &[],
    },
    Pairing {
        cli: "strands",
        python: "stylize_groom",
        rust: "apply_strands",
        not_options: &["points", "counts", "style", "mesh", "progress", "report", "colors"],
        // Arrays in memory: one frame, no files.
        cli_only: &[
            "groom",
            "out",
            "frames",
            "force",
            "work_dir",
            "temporal",
            "ema_sigma",
            "ema_nu",
            "ema_clock",
            "one_euro_alpha",
            "one_euro_beta",
            "one_euro_fmin",
            "fps",
            "style_flow",
        ],
        python_only: &["points", "counts", "report", "colors"],
    },
    Pairing {
        cli: "train",
        python: "train",
        rust: "apply_train",
        not_options: &["input", "frames", "style", "out", "progress"],
        cli_only: &[],
        python_only: &[],
    },
];

#[test]
fn the_cli_and_the_python_package_offer_the_same_settings() {
    let py_src = std::fs::read_to_string(repo().join("python/nst3d/__init__.py")).unwrap();
    let rs_src = std::fs::read_to_string(repo().join("crates/python/src/options.rs")).unwrap();
    let mut problems = Vec::new();
    for p in PAIRINGS {
        let func = py_function(&py_src, p.python);
        let params = py_params(&func);
        let passed = py_options(&func);
        let taken = rs_options(&rs_src, p.rust);
        let flags = cli_flags(p.cli);
        let options: BTreeSet<String> = params.difference(&set(p.not_options)).cloned().collect();
        let mut report = |what: &str, v: Vec<String>| {
            if !v.is_empty() {
                problems.push(format!("{} / {}: {what}: {}", p.cli, p.python, v.join(", ")));
            }
        };
        report("keyword arguments not passed to _options", diff(&options, &passed));
        report("passed to _options but not keyword arguments", diff(&passed, &options));
        report("passed to _options but not taken by options.rs", diff(&passed, &taken));
        let cli_side: BTreeSet<String> = flags.difference(&set(p.cli_only)).cloned().collect();
        let py_side: BTreeSet<String> = params.difference(&set(p.python_only)).cloned().collect();
        let py_side: BTreeSet<String> =
            py_side.into_iter().filter(|n| n != "progress" && n != "mesh" || flags.contains(n)).collect();
        report("CLI flags without a Python keyword", diff(&cli_side, &py_side));
        report("Python keywords without a CLI flag", diff(&py_side, &cli_side));
        for f in p.cli_only {
            if !flags.contains(*f) {
                problems.push(format!("{}: exception '{f}' is no longer a flag", p.cli));
            }
        }
    }
    // Model.load takes the tile flags, --mode and --strength of `nst3d volume --model`.
    let load = py_function(&py_src, "load");
    assert_eq!(py_options(&load), set(&["tile", "tile_margin", "mode", "strength"]));
    assert_eq!(rs_options(&rs_src, "apply_model"), set(&["tile", "tile_margin", "mode", "strength"]));
    assert!(problems.is_empty(), "the front ends disagree:\n{}", problems.join("\n"));
}
