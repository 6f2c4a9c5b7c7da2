//! The docs cannot drift from the binary or the repository:
//! - every `nst3d <command> ...` line in README.md and every Markdown file
//!   under docs/ (code blocks and inline code) parses with the current
//!   binary — run with `NST3D_PARSE_ONLY=1`, which stops right after
//!   argument parsing;
//! - where the docs call a flag's value the default (`` `--ema 0.8` (the
//!   default) ``), it is what `--help` says;
//! - every page and picture they link to exists;
//! - the crate graph in docs/ARCHITECTURE.md is `cargo metadata`'s
//!   (`tools/crate_graph.py --check`);
//! - no doc or code comment names a session, an issue number, a commit
//!   hash or a developer's machine path (`tools/no_references.py`).
//!
//! Lines with an ellipsis (`nst3d volume ... --chunk 31-60`) or a shell
//! variable (`$COMMON`) are fragments, not command lines: they are counted
//! and skipped.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const COMMANDS: [&str; 5] = ["volume", "strands", "train", "bench", "preview"];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// README.md and every Markdown file under docs/, at any depth.
fn doc_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|e| e == "md") {
                out.push(p);
            }
        }
    }
    let mut docs = Vec::new();
    walk(&repo().join("docs"), &mut docs);
    docs.sort();
    let mut files = vec![repo().join("README.md")];
    files.extend(docs);
    files
}

/// Text pieces that may hold command lines: each code block's logical lines
/// (`\` continuations joined) and each inline code span (across line breaks).
fn pieces(text: &str) -> Vec<(String, bool)> {
    let mut out = Vec::new();
    let mut prose = String::new();
    let mut in_block = false;
    let mut logical = String::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if in_block {
            match line.trim_end().strip_suffix('\\') {
                Some(head) => logical.push_str(head),
                None => {
                    logical.push_str(line);
                    out.push((std::mem::take(&mut logical), true));
                }
            }
        } else {
            prose.push_str(line);
            prose.push(' ');
        }
    }
    // Inline spans: text between single backticks.
    let mut rest = prose.as_str();
    while let Some(a) = rest.find('`') {
        let after = &rest[a + 1..];
        let Some(b) = after.find('`') else { break };
        out.push((after[..b].to_string(), false));
        rest = &after[b + 1..];
    }
    out
}

/// The `nst3d <command> ...` invocation in `piece`, cut at the first shell
/// operator or comment, if there is one.
fn invocation(piece: &str) -> Option<String> {
    let mut start = None;
    for (i, _) in piece.match_indices("nst3d ") {
        let before = piece[..i].chars().last();
        let next = piece[i + 6..].split_whitespace().next().unwrap_or("");
        if matches!(before, None | Some(' ') | Some('/') | Some('(') | Some('$')) && COMMANDS.contains(&next) {
            start = Some(i);
            break;
        }
    }
    let cmd = &piece[start?..];
    let mut end = cmd.len();
    let mut quote = None;
    let bytes = cmd.as_bytes();
    for (i, c) in cmd.char_indices() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), _) => {}
            (None, '\'' | '"') => quote = Some(c),
            (None, '|' | ';' | '>' | '&') => {
                end = i;
                break;
            }
            (None, '#') if i > 0 && bytes[i - 1] == b' ' => {
                end = i;
                break;
            }
            _ => {}
        }
    }
    Some(cmd[..end].trim().trim_end_matches(" 2").to_string())
}

/// Shell words of a command line (quotes and backslash escapes).
fn words(cmd: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut has = false;
    let mut quote = None;
    let mut chars = cmd.chars();
    while let Some(c) = chars.next() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => cur.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                has = true;
            }
            (None, '\\') => cur.extend(chars.next()),
            (None, c) if c.is_whitespace() => {
                if has || !cur.is_empty() {
                    out.push(std::mem::take(&mut cur));
                }
                has = false;
            }
            (None, c) => cur.push(c),
        }
    }
    if has || !cur.is_empty() {
        out.push(cur);
    }
    out
}

struct Found {
    file: String,
    cmd: String,
    /// From a code block (a command to copy) rather than inline code in
    /// prose, where `nst3d volume --model` names a flag and may leave out
    /// required arguments.
    block: bool,
}

/// A value written as a placeholder (`--upsample K`, `--input GROOM`,
/// `--warmup Warmup`): an upper-case start, no digit, dot or slash.
fn placeholder(word: &str) -> bool {
    !word.starts_with('-')
        && word.starts_with(|c: char| c.is_ascii_uppercase())
        && !word.contains(|c: char| c.is_ascii_digit() || c == '.' || c == '/')
}

fn command_lines() -> (Vec<Found>, usize) {
    let mut found = Vec::new();
    let mut fragments = 0;
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        let name = f.strip_prefix(repo()).unwrap_or(&f).display().to_string();
        for (p, block) in pieces(&text) {
            let Some(cmd) = invocation(&p) else { continue };
            let fragment = ["...", "…", "$", "<", "["].iter().any(|m| cmd.contains(m))
                || words(&cmd).iter().any(|w| placeholder(w));
            if fragment {
                fragments += 1;
                continue;
            }
            found.push(Found { file: name.clone(), cmd, block });
        }
    }
    (found, fragments)
}

fn nst3d() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nst3d"))
}

#[test]
fn every_documented_command_line_parses() {
    let (found, fragments) = command_lines();
    assert!(found.len() >= 40, "only {} command lines found in the docs: is the extraction broken?", found.len());
    let mut bad = Vec::new();
    for f in &found {
        let w = words(&f.cmd);
        let out = nst3d().args(&w[1..]).env("NST3D_PARSE_ONLY", "1").output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        // Prose names a command or a flag (`nst3d volume --model`): the
        // flag must exist, its value and the required arguments may be left out.
        let mention = !f.block
            && (err.contains("required arguments were not provided")
                || (err.contains("a value is required for") && w.last().is_some_and(|l| l.starts_with("--"))));
        if !out.status.success() && !mention {
            bad.push(format!("{}: `{}`\n    {}", f.file, f.cmd, err.lines().next().unwrap_or("")));
        }
    }
    eprintln!("{} command lines parsed, {fragments} fragments skipped", found.len());
    assert!(bad.is_empty(), "{} documented command lines do not parse:\n{}", bad.len(), bad.join("\n"));
}

/// `[default: X]` of each long flag in `nst3d <cmd> --help`, per command.
fn help_defaults() -> BTreeMap<String, Vec<(String, String)>> {
    let mut map: BTreeMap<String, Vec<(String, String)>> = BTreeMap::new();
    for cmd in COMMANDS {
        let help = String::from_utf8(nst3d().args([cmd, "--help"]).output().unwrap().stdout).unwrap();
        let mut flag: Option<String> = None;
        for line in help.lines() {
            if let Some(rest) =
                line.strip_prefix("      --").or_else(|| line.get(8..).filter(|_| line.starts_with("  -")))
            {
                flag = Some(rest.split_whitespace().next().unwrap_or("").to_string());
            }
            if let (Some(f), Some(i)) = (&flag, line.find("[default: ")) {
                let v = &line[i + 10..];
                map.entry(f.clone()).or_default().push((cmd.to_string(), v[..v.find(']').unwrap()].to_string()));
                flag = None;
            }
        }
    }
    map
}

/// Sentences of the docs' prose that give `--flag value` as the default.
fn claimed_defaults(text: &str) -> Vec<(String, String, String)> {
    let prose: String = text.split("```").step_by(2).collect::<Vec<_>>().join(" ").replace('\n', " ");
    let mut out = Vec::new();
    let mut rest = prose.as_str();
    while let Some(a) = rest.find("`--") {
        let span = &rest[a + 3..];
        let Some(b) = span.find('`') else { break };
        let code = &span[..b];
        let tail: String = span[b + 1..].chars().take(30).collect::<String>().to_lowercase();
        let mut parts = code.split_whitespace();
        if let (Some(flag), Some(value), None) = (parts.next(), parts.next(), parts.next()) {
            let t = tail.trim_start_matches([',', ' ', '(', ';']);
            if t.starts_with("the default") || t.starts_with("default") || t.starts_with("is the default") {
                out.push((flag.to_string(), value.to_string(), code.to_string()));
            }
        }
        rest = &span[b + 1..];
    }
    out
}

#[test]
fn defaults_quoted_in_the_docs_are_the_binarys() {
    let defaults = help_defaults();
    assert!(defaults.get("ema").is_some(), "--help parsing found no default for --ema");
    let mut bad = Vec::new();
    let mut checked = 0;
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        for (flag, value, code) in claimed_defaults(&text) {
            let Some(known) = defaults.get(&flag) else { continue };
            checked += 1;
            if !known.iter().any(|(_, d)| {
                d == &value || d.parse::<f64>().ok() == value.parse::<f64>().ok() && d.parse::<f64>().is_ok()
            }) {
                let name = f.strip_prefix(repo()).unwrap_or(Path::new("?")).display().to_string();
                bad.push(format!("{name}: `{code}` is called the default; --help says {known:?}"));
            }
        }
    }
    eprintln!("{checked} quoted defaults checked");
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn the_extraction_finds_what_a_reader_sees() {
    let md = "Run `nst3d volume --input a.vdb\n--out b.vdb` now.\n```\nnst3d strands --groom g.ply \\\n  --out 'o ####.usda' | tee log  # note\n```\n";
    let cmds: Vec<String> = pieces(md).iter().filter_map(|(p, _)| invocation(p)).collect();
    assert_eq!(cmds, ["nst3d strands --groom g.ply   --out 'o ####.usda'", "nst3d volume --input a.vdb --out b.vdb"]);
    assert_eq!(words(&cmds[0]), ["nst3d", "strands", "--groom", "g.ply", "--out", "o ####.usda"]);
    assert!(
        placeholder("GROOM")
            && placeholder("FrameStart-FrameEnd")
            && !placeholder("Bangs_100.hair")
            && !placeholder("-K")
    );
    let claims = claimed_defaults("EMA `--ema 0.8` (the default) and `--lr-scale 0.3`, the default.");
    assert_eq!(claims.len(), 2);
}

#[test]
fn the_docs_cover_every_file_under_docs() {
    let files = doc_files();
    let names: Vec<String> = files.iter().map(|f| f.strip_prefix(repo()).unwrap().display().to_string()).collect();
    for nested in ["docs/guide/volumes.md", "docs/design/volumes.md", "docs/ARCHITECTURE.md"] {
        assert!(names.iter().any(|n| n == nested), "{nested} is not among the checked docs: {names:?}");
    }
}

/// `path` with `.` and `..` resolved lexically.
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

/// The targets of the Markdown links and images in `text` (`[t](x)`,
/// `![t](x)`), outside code blocks, without `#anchors`; web links left out.
fn link_targets(text: &str) -> Vec<String> {
    let prose: String = text.split("```").step_by(2).collect::<Vec<_>>().join("\n");
    let mut out = Vec::new();
    let mut rest = prose.as_str();
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        let Some(j) = after.find(')') else { break };
        let target = after[..j].split('#').next().unwrap_or("").trim();
        if !target.is_empty() && !target.contains("://") && !target.starts_with("mailto:") {
            out.push(target.to_string());
        }
        rest = &after[j + 1..];
    }
    out
}

#[test]
fn every_linked_page_and_picture_exists() {
    let mut bad = Vec::new();
    let mut checked = 0;
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        let dir = f.parent().unwrap();
        for target in link_targets(&text) {
            checked += 1;
            let path = normalize(&dir.join(&target));
            if !path.exists() {
                let name = f.strip_prefix(repo()).unwrap_or(&f).display().to_string();
                bad.push(format!("{name}: links to {target}, which does not exist"));
            }
        }
    }
    assert!(checked >= 20, "only {checked} links found: is the extraction broken?");
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

fn python_check(script: &str, args: &[&str]) {
    let out = Command::new("python3").arg(repo().join(script)).args(args).current_dir(repo()).output().unwrap();
    assert!(
        out.status.success(),
        "{script} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn the_crate_graph_in_the_architecture_doc_is_cargo_metadatas() {
    python_check("tools/crate_graph.py", &["--check"]);
}

#[test]
fn docs_and_comments_name_no_session_issue_commit_or_machine_path() {
    python_check("tools/no_references.py", &[]);
}

#[test]
fn link_extraction_skips_code_web_links_and_anchors() {
    let md = "See [a](guide/a.md#x) and ![p](../img/p.png), [w](https://e.org).\n```\n[c](not/me.md)\n```\n";
    assert_eq!(link_targets(md), ["guide/a.md", "../img/p.png"]);
}

/// The preset values the strand guide's settings table quotes for
/// `--style-scale` and `--orientation` ("the preset's: 2 for `fur-ball`,
/// 1.5 for `grass`, else 1") are each preset's.
#[test]
fn preset_values_quoted_in_the_strand_guide_are_the_presets() {
    use nst3d_strands::Preset;
    let text = std::fs::read_to_string(repo().join("docs/guide/strands.md")).unwrap();
    let quoted = |flag: &str| -> Vec<(f32, Vec<String>)> {
        let row = text.lines().find(|l| l.starts_with(&format!("| `--{flag}` |"))).expect("row in the table");
        let cell = row.split('|').nth(2).unwrap().trim();
        let list = cell.strip_prefix("the preset's: ").unwrap_or_else(|| panic!("--{flag}: {cell}"));
        // "3 for `a`, `b` and `c`, 1.5 for `d`, else 0": an item without
        // " for " names more presets of the value before it.
        let names =
            |list: &str| -> Vec<String> { list.split(" and ").map(|n| n.trim_matches('`').to_string()).collect() };
        let mut items: Vec<(f32, Vec<String>)> = Vec::new();
        for item in list.split(", ") {
            match (item.strip_prefix("else "), item.split_once(" for "), items.last_mut()) {
                (Some(v), _, _) => items.push((v.parse().unwrap(), vec![])),
                (None, Some((v, list)), _) => items.push((v.parse().unwrap(), names(list))),
                (None, None, Some(last)) if !last.1.is_empty() => last.1.extend(names(item)),
                _ => panic!("--{flag}: {item}"),
            }
        }
        items
    };
    for (flag, value) in [
        ("style-scale", (|p: Preset| p.params().style_scale) as fn(Preset) -> f32),
        ("orientation", |p: Preset| p.params().orientation),
    ] {
        let items = quoted(flag);
        let named: Vec<&String> = items.iter().flat_map(|(_, n)| n).collect();
        for p in Preset::ALL {
            let want = match items.iter().find(|(_, n)| n.iter().any(|k| k == p.key())) {
                Some((v, _)) => *v,
                None => items.iter().find(|(_, n)| n.is_empty()).expect("an else value").0,
            };
            assert_eq!(value(p), want, "--{flag} of preset {}: the guide says {want}", p.key());
        }
        assert!(named.iter().all(|n| n.parse::<Preset>().is_ok()), "--{flag}: {named:?}");
    }
}
