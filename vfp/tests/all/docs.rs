//! The README and the user guide cannot rot silently. Over `README.md`, `CONTRIBUTING.md`,
//! `CHANGELOG.md`, the crates' READMEs, `docs/*.md` and every page under `docs/guide/src/`:
//! - every relative link and image, and every mdBook `{{#include …}}`, points at a file that
//!   exists inside the repository;
//! - every page of the guide is listed in its `SUMMARY.md` (mdBook would create a missing one
//!   empty);
//! - the command reference (`docs/guide/src/commands.md`) has a section for every subcommand of
//!   `vfp --help`, holding that subcommand's `--help` text as the built tool prints it
//!   (`VFP_DOCS_RECORD=1 cargo test -p vfp --test all docs::` rewrites those blocks);
//! - every `vfp` command line shown in a `sh` or `console` block, or in inline code, names a
//!   subcommand of the built tool, and each long option it passes appears in that subcommand's
//!   `--help`;
//! - every `cargo test|bench|run -p PACKAGE [--test|--bench|--example NAME]` shown (the commands
//!   that reproduce a figure) names a workspace package and a target it has, and every
//!   `cargo fw…`/`cargo vfp` is an alias of `.cargo/config.toml`;
//! - the README stays within 250 lines.
//!
//! Options are checked, not values or whole runs: a renamed or removed flag, command or file
//! fails here; a changed number does not.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Component, Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The Markdown pages the check covers, as paths relative to the repository root.
fn pages() -> Vec<PathBuf> {
    let root = root();
    let mut out: Vec<PathBuf> = [
        "README.md",
        "CONTRIBUTING.md",
        "CHANGELOG.md",
        "python/README.md",
        "host-sim/README.md",
        "data/real/README.md",
    ]
    .iter()
    .map(PathBuf::from)
    .collect();
    for dir in ["docs", "docs/guide/src"] {
        let mut found: Vec<PathBuf> = fs::read_dir(root.join(dir))
            .unwrap_or_else(|e| panic!("{dir}: {e}"))
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "md"))
            .map(|p| p.strip_prefix(&root).unwrap().to_path_buf())
            .collect();
        found.sort();
        out.extend(found);
    }
    out
}

/// A page's lines, sorted for the checks.
struct Page {
    /// (line number, text with code spans replaced by spaces) for lines outside fenced blocks.
    prose: Vec<(usize, String)>,
    /// (line number, span text) for inline code spans outside fenced blocks.
    spans: Vec<(usize, String)>,
    /// (line number, line) inside fenced blocks whose info string is `sh`, `bash` or `console`.
    shell: Vec<(usize, String)>,
}

fn read_page(rel: &Path) -> Page {
    let text = fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel:?}: {e}"));
    let mut page = Page {
        prose: vec![],
        spans: vec![],
        shell: vec![],
    };
    let mut fence: Option<String> = None;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let trimmed = line.trim_start();
        if let Some(info) = trimmed.strip_prefix("```") {
            fence = match fence {
                Some(_) => None,
                None => Some(info.split([',', ' ']).next().unwrap_or("").to_string()),
            };
            continue;
        }
        match fence.as_deref() {
            Some("sh" | "bash") => page.shell.push((n, line.to_string())),
            Some("console") => {
                if let Some(cmd) = line.strip_prefix("$ ") {
                    page.shell.push((n, cmd.to_string()));
                }
            }
            Some(_) => {}
            None => {
                let mut blanked = String::new();
                let mut parts = line.split('`');
                blanked.push_str(parts.next().unwrap_or(""));
                for (k, part) in parts.enumerate() {
                    if k % 2 == 0 {
                        page.spans.push((n, part.to_string()));
                        blanked.push_str(&" ".repeat(part.len() + 2));
                    } else {
                        blanked.push_str(part);
                    }
                }
                page.prose.push((n, blanked));
            }
        }
    }
    page
}

/// `](target)` link targets and `{{#include target}}` paths of a prose line.
fn targets(line: &str) -> Vec<String> {
    let mut out = vec![];
    let mut rest = line;
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let end = after.find(')').unwrap_or(after.len());
        let target = after[..end].split_whitespace().next().unwrap_or("");
        out.push(target.trim_matches(['<', '>']).to_string());
        rest = &after[end..];
    }
    if let Some(inc) = line.trim().strip_prefix("{{#include ") {
        out.push(inc.trim_end_matches("}}").trim().to_string());
    }
    out
}

/// Lexically normalises `a/b/../c` to `a/c`; `None` when it climbs above the start.
fn normalise(path: &Path) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            Component::CurDir => {}
            Component::Normal(x) => out.push(x),
            Component::RootDir | Component::Prefix(_) => return None,
        }
    }
    Some(out)
}

#[test]
fn relative_links_point_at_files_in_the_repository() {
    let root = root();
    let mut bad = vec![];
    for rel in pages() {
        let page = read_page(&rel);
        for (n, line) in &page.prose {
            for t in targets(line) {
                if t.is_empty()
                    || t.starts_with('#')
                    || t.starts_with("http://")
                    || t.starts_with("https://")
                    || t.starts_with("mailto:")
                {
                    continue;
                }
                let file = t.split('#').next().unwrap();
                let joined = rel.parent().unwrap().join(file);
                match normalise(&joined) {
                    Some(p) if root.join(&p).exists() => {}
                    Some(p) => bad.push(format!(
                        "{}:{n}: {t} -> {} does not exist",
                        rel.display(),
                        p.display()
                    )),
                    None => bad.push(format!("{}:{n}: {t} leaves the repository", rel.display())),
                }
            }
        }
    }
    assert!(bad.is_empty(), "broken links:\n{}", bad.join("\n"));
}

#[test]
fn every_guide_page_is_in_the_summary() {
    let summary = read_page(Path::new("docs/guide/src/SUMMARY.md"));
    let listed: Vec<String> = summary.prose.iter().flat_map(|(_, l)| targets(l)).collect();
    let missing: Vec<String> = pages()
        .into_iter()
        .filter(|p| p.starts_with("docs/guide/src") && !p.ends_with("SUMMARY.md"))
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .filter(|name| !listed.contains(name))
        .collect();
    assert!(
        missing.is_empty(),
        "guide pages not in docs/guide/src/SUMMARY.md: {missing:?}"
    );
}

#[test]
fn the_readme_fits_on_a_few_screens() {
    let lines = fs::read_to_string(root().join("README.md"))
        .unwrap()
        .lines()
        .count();
    assert!(
        lines <= 250,
        "README.md has {lines} lines; the limit is 250 (move detail to docs/guide)"
    );
}

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args(args)
        .arg("--help")
        .output()
        .expect("run vfp --help");
    assert!(
        out.status.success(),
        "vfp {args:?} --help failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The subcommands listed under `Commands:` in `vfp --help`, with their own help.
fn subcommands() -> BTreeMap<String, String> {
    let top = help(&[]);
    let mut in_list = false;
    let mut out = BTreeMap::new();
    for line in top.lines() {
        if line.starts_with("Commands:") {
            in_list = true;
            continue;
        }
        if in_list {
            if !line.starts_with("  ") {
                break;
            }
            let name = line.split_whitespace().next().unwrap();
            if name != "help" {
                out.insert(name.to_string(), help(&[name]));
            }
        }
    }
    assert!(
        out.len() >= 5,
        "could not read the subcommands of vfp --help:\n{top}"
    );
    out
}

/// Long options (`--name`) in a piece of a command line.
fn long_options(text: &str) -> Vec<String> {
    let bytes = text.as_bytes();
    let mut out = vec![];
    let mut i = 0;
    while let Some(at) = text[i..].find("--") {
        let s = i + at;
        let before_ok = s == 0 || !(bytes[s - 1].is_ascii_alphanumeric() || bytes[s - 1] == b'-');
        let mut e = s + 2;
        while e < bytes.len() && (bytes[e].is_ascii_alphanumeric() || bytes[e] == b'-') {
            e += 1;
        }
        if before_ok && e > s + 2 && bytes[s + 2].is_ascii_alphabetic() {
            out.push(text[s..e].to_string());
        }
        i = e.max(s + 2);
    }
    out
}

/// The `vfp` invocations in a shell line: (subcommand, rest of the command).
fn invocations(line: &str) -> Vec<(String, String)> {
    let line = match line.find(" #") {
        Some(at) => &line[..at],
        None => line,
    };
    if line.trim_start().starts_with('#') {
        return vec![];
    }
    let mut out = vec![];
    for segment in line
        .split(" | ")
        .flat_map(|s| s.split("&&"))
        .flat_map(|s| s.split(';'))
    {
        let words: Vec<&str> = segment.split_whitespace().collect();
        let mut k = 0;
        while k < words.len()
            && (words[k].contains('=') && !words[k].starts_with('-') || words[k] == "time")
        {
            k += 1;
        }
        if words.get(k) == Some(&"cargo") && words.get(k + 1) == Some(&"vfp") {
            k += 1;
        }
        if words.get(k) != Some(&"vfp") {
            continue;
        }
        let Some(sub) = words.get(k + 1) else {
            continue;
        };
        if !sub.starts_with(|c: char| c.is_ascii_lowercase()) {
            continue; // `vfp …`, `vfp --help`
        }
        out.push((sub.to_string(), words[k + 2..].join(" ")));
    }
    out
}

#[test]
fn shown_commands_and_options_exist() {
    let subs = subcommands();
    let mut bad = vec![];
    let mut checked = 0;
    for rel in pages() {
        let page = read_page(&rel);
        let lines = page.shell.iter().chain(page.spans.iter());
        for (n, line) in lines {
            for (sub, rest) in invocations(line) {
                checked += 1;
                let Some(text) = subs.get(&sub) else {
                    bad.push(format!(
                        "{}:{n}: `vfp {sub}` is not a subcommand of vfp",
                        rel.display()
                    ));
                    continue;
                };
                for opt in long_options(&rest) {
                    let listed = long_options(text).contains(&opt);
                    if !listed && opt != "--help" {
                        bad.push(format!(
                            "{}:{n}: `vfp {sub}` has no option {opt}",
                            rel.display()
                        ));
                    }
                }
            }
        }
    }
    assert!(
        checked >= 50,
        "only {checked} vfp command lines found; is the parser broken?"
    );
    assert!(
        bad.is_empty(),
        "commands in the docs that the built vfp does not have:\n{}",
        bad.join("\n")
    );
}

/// The marked block of a subcommand's help in the command reference.
fn help_block(sub: &str, help: &str) -> String {
    format!(
        "<!-- help:{sub}:begin -->\n```text\n$ vfp {sub} --help\n{}\n```\n<!-- help:{sub}:end -->",
        help.trim_end()
    )
}

#[test]
fn the_command_reference_holds_every_subcommands_help() {
    let path = root().join("docs/guide/src/commands.md");
    let mut reference = fs::read_to_string(&path).unwrap();
    let record = std::env::var_os("VFP_DOCS_RECORD").is_some();
    let mut bad = vec![];
    for (sub, help) in subcommands() {
        let heading = format!("`vfp {sub}");
        if !reference
            .lines()
            .any(|l| l.starts_with("## ") && l.contains(&heading))
        {
            bad.push(format!("no `## vfp {sub}` section"));
        }
        let begin = format!("<!-- help:{sub}:begin -->");
        let end = format!("<!-- help:{sub}:end -->");
        let (Some(a), Some(b)) = (reference.find(&begin), reference.find(&end)) else {
            bad.push(format!("no {begin} … {end} block"));
            continue;
        };
        let block = help_block(&sub, &help);
        if reference[a..b + end.len()] != block {
            if record {
                reference.replace_range(a..b + end.len(), &block);
            } else {
                bad.push(format!(
                    "the help block of `vfp {sub}` differs from `vfp {sub} --help`"
                ));
            }
        }
    }
    if record {
        fs::write(&path, &reference).unwrap();
    }
    assert!(
        bad.is_empty(),
        "docs/guide/src/commands.md:\n{}\n(VFP_DOCS_RECORD=1 cargo test -p vfp --test all docs:: rewrites the help blocks)",
        bad.join("\n")
    );
}

/// The workspace's packages: name → directory (from the root manifest's `members`).
fn packages() -> BTreeMap<String, PathBuf> {
    let root = root();
    let manifest = fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let members = manifest
        .lines()
        .find(|l| l.trim_start().starts_with("members"))
        .expect("the root Cargo.toml lists its members on one line");
    let mut out = BTreeMap::new();
    for dir in members.split('"').skip(1).step_by(2) {
        let text = fs::read_to_string(root.join(dir).join("Cargo.toml")).unwrap();
        let name = text
            .lines()
            .find_map(|l| l.trim().strip_prefix("name = \""))
            .and_then(|rest| rest.split('"').next())
            .unwrap_or_else(|| panic!("{dir}/Cargo.toml has no name"));
        out.insert(name.to_string(), PathBuf::from(dir));
    }
    out
}

/// Problems with one `cargo …` segment of a shown command, if it is one this test checks.
fn cargo_problems(
    segment: &str,
    packages: &BTreeMap<String, PathBuf>,
    aliases: &str,
) -> Vec<String> {
    let words: Vec<&str> = segment.split_whitespace().collect();
    let Some(k) = words.iter().position(|w| *w == "cargo") else {
        return vec![];
    };
    let Some(&verb) = words.get(k + 1) else {
        return vec![];
    };
    if verb.starts_with("fw") || verb == "vfp" {
        let defined = aliases
            .lines()
            .any(|l| l.starts_with(&format!("{verb} = ")));
        return match defined {
            true => vec![],
            false => vec![format!(
                "`cargo {verb}` is not an alias of .cargo/config.toml"
            )],
        };
    }
    if !matches!(verb, "test" | "bench" | "run") {
        return vec![];
    }
    // cargo's own arguments end at `--`; what follows goes to the program.
    let args: Vec<&str> = words[k + 2..]
        .iter()
        .copied()
        .take_while(|w| *w != "--")
        .collect();
    let value = |flag: &str| {
        args.windows(2)
            .filter(|w| w[0] == flag)
            .map(|w| w[1])
            .collect::<Vec<_>>()
    };
    let Some(package) = value("-p").first().copied() else {
        return vec![];
    };
    let Some(dir) = packages.get(package) else {
        return vec![format!("no workspace package `{package}`")];
    };
    let manifest = fs::read_to_string(root().join(dir).join("Cargo.toml")).unwrap();
    let mut out = vec![];
    for (flag, sub) in [
        ("--test", "tests"),
        ("--bench", "benches"),
        ("--example", "examples"),
    ] {
        for name in value(flag) {
            let base = root().join(dir).join(sub);
            let exists = base.join(format!("{name}.rs")).exists()
                || base.join(name).join("main.rs").exists()
                || manifest.contains(&format!("name = \"{name}\""));
            if !exists {
                out.push(format!("`{package}` has no {} target `{name}`", &flag[2..]));
            }
        }
    }
    out
}

#[test]
fn shown_cargo_commands_name_real_packages_and_targets() {
    let packages = packages();
    let config = fs::read_to_string(root().join(".cargo/config.toml")).unwrap();
    let aliases = config
        .split("[alias]")
        .nth(1)
        .expect(".cargo/config.toml has an [alias] table");
    let aliases = aliases.split("\n[").next().unwrap();
    let mut bad = vec![];
    let mut checked = 0;
    for rel in pages() {
        let page = read_page(&rel);
        for (n, line) in page.shell.iter().chain(page.spans.iter()) {
            let line = line.split(" #").next().unwrap();
            for segment in line
                .split(" | ")
                .flat_map(|s| s.split("&&"))
                .flat_map(|s| s.split(';'))
            {
                if segment.contains("cargo ") {
                    checked += 1;
                }
                for problem in cargo_problems(segment, &packages, aliases) {
                    bad.push(format!("{}:{n}: {problem}", rel.display()));
                }
            }
        }
    }
    assert!(
        checked >= 40,
        "only {checked} cargo command lines found; is the parser broken?"
    );
    assert!(
        bad.is_empty(),
        "cargo commands in the docs that do not resolve:\n{}",
        bad.join("\n")
    );
}

/// Every checksummed command line the pages show (`*LLCC <command>`, `LLCC` four upper-case
/// hex digits, in a code span, a code block or a code example's string) is one the firmware accepts from boot, checksum
/// required, and parses: a person who types it as shown gets it executed.
#[test]
fn shown_checksummed_lines_pass_the_firmwares_check() {
    let mut shown = 0;
    let mut bad = vec![];
    for rel in pages() {
        let text = fs::read_to_string(root().join(&rel)).unwrap();
        for (i, line) in text.lines().enumerate() {
            for (at, _) in line.match_indices('*') {
                let rest = &line[at..];
                let prefix = rest.as_bytes().get(1..6);
                let Some([a, b, c, d, b' ']) = prefix else {
                    continue;
                };
                if ![a, b, c, d]
                    .iter()
                    .all(|x| x.is_ascii_digit() || (b'A'..=b'F').contains(x))
                {
                    continue;
                }
                // Up to the end of its code span, or of the string literal in a code example.
                let shown_line = rest.split(['`', '"']).next().unwrap().trim_end();
                shown += 1;
                let mut link = firmware::command::LinkState::default();
                let ok = link
                    .check(shown_line.as_bytes())
                    .is_ok_and(|cmd| firmware::command::parse(cmd).is_ok());
                if !ok {
                    bad.push(format!("{}:{}: {shown_line}", rel.display(), i + 1));
                }
            }
        }
    }
    assert!(shown >= 5, "only {shown} checksummed lines found");
    assert!(
        bad.is_empty(),
        "refused by the firmware:\n{}",
        bad.join("\n")
    );
}
