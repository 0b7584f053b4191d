//! The runner behind `cargo fw-bench [--json] [--check]`.
//!
//! 1. builds this crate for `thumbv7em-none-eabihf` at the firmware's profile (`firmware`: fat
//!    LTO, the firmware crate at opt-level "s");
//! 2. reads the marker symbols and the code from the ELF;
//! 3. runs it under QEMU (`netduinoplus2`), counting every executed instruction from the trace;
//! 4. checks the calibration regions (exact counts, else exit 2), prints the table (and with
//!    `--json` one JSON object on the last line), and with `--check` exits 1 naming every key
//!    over its budget (`fw-bench/budgets.toml`).

mod elf;
mod qemu;
mod report;
mod trace;

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::Duration;

const USAGE: &str = "usage: cargo fw-bench [--json] [--check] [--budgets FILE] [--elf FILE] \
                     [--qemu BIN] [--timeout SECONDS] [--locked]";

/// The device target and profile (the firmware's).
const TARGET: &str = "thumbv7em-none-eabihf";
const PROFILE: &str = "firmware";

struct Args {
    json: bool,
    check: bool,
    budgets: PathBuf,
    elf: Option<PathBuf>,
    qemu: String,
    timeout: Duration,
    locked: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        json: false,
        check: false,
        budgets: Path::new(env!("CARGO_MANIFEST_DIR")).join("budgets.toml"),
        elf: None,
        qemu: "qemu-system-arm".into(),
        timeout: Duration::from_secs(600),
        locked: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |what: &str| it.next().ok_or(format!("{arg} needs {what}"));
        match arg.as_str() {
            "--json" => a.json = true,
            "--check" => a.check = true,
            "--locked" => a.locked = true,
            "--budgets" => a.budgets = value("a file")?.into(),
            "--elf" => a.elf = Some(value("a file")?.into()),
            "--qemu" => a.qemu = value("a program")?,
            "--timeout" => {
                let s = value("seconds")?;
                a.timeout = Duration::from_secs(s.parse().map_err(|_| format!("--timeout {s}"))?);
            }
            "-h" | "--help" => return Err(USAGE.into()),
            _ => return Err(format!("unknown argument `{arg}`\n{USAGE}")),
        }
    }
    Ok(a)
}

/// Build the device side and return the ELF's path.
fn build(locked: bool) -> Result<PathBuf, String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut cmd = Command::new(cargo);
    cmd.current_dir(&root)
        .args([
            "build",
            "-p",
            "fw-bench",
            "--profile",
            PROFILE,
            "--target",
            TARGET,
        ])
        .arg("--message-format=json-render-diagnostics")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    if locked {
        cmd.arg("--locked");
    }
    let out = cmd.output().map_err(|e| format!("cargo build: {e}"))?;
    if !out.status.success() {
        return Err("building the bench program failed".into());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    text.lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["reason"] == "compiler-artifact" && v["target"]["name"] == "fw-bench")
        .find_map(|v| v["executable"].as_str().map(PathBuf::from))
        .ok_or_else(|| "cargo did not report the bench program's ELF".into())
}

fn run() -> Result<ExitCode, String> {
    let args = parse_args()?;
    let budgets = std::fs::read_to_string(&args.budgets)
        .map_err(|e| format!("{}: {e}", args.budgets.display()))?;
    let budgets = report::parse_budgets(&budgets)?;
    let elf = match &args.elf {
        Some(p) => p.clone(),
        None => build(args.locked)?,
    };
    let data = std::fs::read(&elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let layout = elf::layout(&data)?;
    let (major, minor) = qemu::version(&args.qemu)?;
    eprintln!(
        "fw-bench: running {} under QEMU {major}.{minor} ({}), one trace line per instruction…",
        elf.display(),
        qemu::MACHINE
    );
    let run = qemu::run(&args.qemu, &elf, &layout, args.timeout)?;
    let calibration = report::check_calibration(&layout, &run.counts)?;
    let r = report::report(&layout, &run.counts)?;

    println!(
        "Firmware cost on an emulated Cortex-M4: QEMU {major}.{minor} `{}`, profile `{PROFILE}`, \
         instructions (not cycles)",
        qemu::MACHINE
    );
    for m in &run.messages {
        println!("{m}");
    }
    println!("fw-bench: counter calibration exact: {calibration}");
    println!(
        "fw-bench: {} instructions traced ({} in the scripted run) in {:.1} s",
        report::group(r.total_insns),
        report::group(r.script_insns),
        run.wall.as_secs_f64()
    );
    println!();
    print!("{}", report::table(&r, &budgets));
    let over = report::over_budget(&r.figures, &budgets);
    for o in &over {
        eprintln!("fw-bench: over budget: {o}");
    }
    if args.json {
        println!();
        println!(
            "{}",
            serde_json::to_string(&r.figures).map_err(|e| e.to_string())?
        );
    }
    if args.check && !over.is_empty() {
        eprintln!(
            "fw-bench: --check: {} key(s) over budget ({})",
            over.len(),
            args.budgets.display()
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// Entry point of the host build.
pub fn main() -> ExitCode {
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("fw-bench: {e}");
            ExitCode::from(2)
        }
    }
}
