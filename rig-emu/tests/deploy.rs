//! `vfp deploy` to the binary, and `vfp replay` against what it streams: a model with an effect
//! chain, exported from a host-sim log by `vfp export --augmented`, goes to the virtual rig over
//! a pseudo-terminal exactly as to a board's serial port (the test carries the bytes between the
//! terminal and the rig's USART2 wire), is read back, and then runs on the emulated Cortex-M4:
//! the P̂ the binary streams is the P̂ `vfp replay` computes from the recorded frames with the
//! exported model, bit for bit.
//!
//! Truths: the exported lines (what the board must hold, checked by `vfp deploy`'s read-back and
//! CRC), and the host's replay (the firmware library's estimator compiled for the host, run by
//! the CLI) against the ELF's own arithmetic on the emulated core.

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Child, Output, Stdio};
use std::time::{Duration, Instant};

use host_sim::{Effects, PlantConfig};
use rig_emu::rig::{FLASH_ACR, FLASH_CR};
use rig_emu::wire::Received;
use rig_emu::{default_elf, vfp, Rig, RigConfig};
use serialport::{SerialPort, TTYPort};

fn ok(out: Output, what: &str) -> Vec<u8> {
    assert!(
        out.status.success(),
        "{what}: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// Runs the rig while `child` lives, carrying bytes both ways between the pseudo-terminal's
/// `master` end (the child has the other end open as its serial port) and the rig's host wire,
/// in 2 ms slices of virtual time; the child's output. The rig's bytes go to the terminal from
/// `from` on (what it sent before the child opened the port stays out, as on a real port opened
/// late).
fn serve(rig: &mut Rig, master: &mut TTYPort, mut child: Child, mut from: usize) -> Output {
    let started = Instant::now();
    let mut buf = [0u8; 256];
    loop {
        match master.read(&mut buf) {
            Ok(n) if n > 0 => rig.send(&buf[..n]).expect("the rig runs"),
            _ => {}
        }
        rig.run_for(Duration::from_millis(2)).expect("the rig runs");
        let out: Vec<u8> = rig
            .with(move |s, _| {
                s.board_mut().host().received_bytes()[from..]
                    .iter()
                    .map(|&(_, b)| b)
                    .collect()
            })
            .expect("the rig runs");
        from += out.len();
        if !out.is_empty() {
            // Refused while the child has not opened its end yet: lost, as on a real port.
            let _ = master.write_all(&out);
        }
        if child.try_wait().expect("the child").is_some() {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "the child did not finish in 5 minutes"
        );
    }
    child.wait_with_output().expect("the child's output")
}

#[test]
fn a_deployed_chain_runs_on_the_binary_as_vfp_replay_computes_it() {
    let dir = std::env::temp_dir().join(format!("rig-emu-deploy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The model: hysteresis found on a host-sim log of its preset plant and exported with its
    // effect chain (the loop restricted to that effect and a small baseline: the question here
    // is the board's, not the loop's).
    let sim_log = dir.join("sim.csv");
    ok(
        vfp()
            .args(["simulate", "--preset", "effect:hysteresis", "--cycles", "1"])
            .args(["--flows", "20,60,100", "--seed", "3", "-q", "-o"])
            .arg(&sim_log)
            .output()
            .unwrap(),
        "vfp simulate",
    );
    let lines = ok(
        vfp()
            .arg("export")
            .arg(&sim_log)
            .args(["--chamber", "0", "--n", "3", "--m", "2", "--augmented"])
            .args(["--effect", "hysteresis", "--format", "lines", "-q"])
            .output()
            .unwrap(),
        "vfp export",
    );
    let text = String::from_utf8(lines).unwrap();
    assert!(
        text.lines()
            .any(|l| l.starts_with("model 0 effect hysteresis")),
        "the export carries the effect:\n{text}"
    );
    let model = dir.join("model.txt");
    std::fs::write(&model, &text).unwrap();

    let plant = PlantConfig {
        effects: Effects::preset("hysteresis").unwrap(),
        ..PlantConfig::default()
    };
    let mut rig = Rig::start(&RigConfig {
        elf: default_elf(),
        plant,
        seed: 5,
    })
    .expect("the virtual rig starts");
    rig.ready().unwrap();
    // The stream on before the deploy, so the frames around the model's load are recorded: the
    // deploy reads its replies between the packets, as from a board left streaming.
    let capture_from = rig
        .with(|s, _| s.board_mut().host().received_bytes().len())
        .unwrap();
    assert_eq!(rig.command("telemetry on").unwrap().as_deref(), Some("ok"));

    let (mut master, slave) = TTYPort::pair().expect("a pseudo-terminal");
    let port = slave.name().expect("the terminal's name");
    // `vfp deploy` opens the terminal's other end itself, exclusively: until it does, the
    // master reads a hang-up and what the rig sends is lost, as on a port nobody has open.
    drop(slave);
    master.set_timeout(Duration::from_millis(1)).unwrap();
    let child = vfp()
        .args(["deploy", "--port", &port, "--timeout-s", "10", "-q"])
        .arg(&model)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let from = rig
        .with(|s, _| s.board_mut().host().received_bytes().len())
        .unwrap();
    let out = ok(serve(&mut rig, &mut master, child, from), "vfp deploy");
    let said = String::from_utf8_lossy(&out).to_string();
    assert!(
        said.contains("channel 0:") && said.contains("read back and identical"),
        "{said}"
    );

    // A short run of the protocol with the deployed model, then the stream off.
    assert_eq!(
        rig.command("run 0 0 550 1 200 60 100").unwrap().as_deref(),
        Some("ok")
    );
    assert!(
        rig.until_at_rest(Duration::from_secs(60)).unwrap(),
        "the run ended within 60 virtual seconds"
    );
    assert_eq!(rig.command("telemetry off").unwrap().as_deref(), Some("ok"));
    let (capture, items, flash, last_step_ns) = rig
        .with(move |s, b| {
            let bytes = s.board_mut().host().received_bytes()[capture_from..]
                .iter()
                .map(|&(_, b)| b)
                .collect::<Vec<u8>>();
            let last_step_ns = b.steps.last().map_or(0, |e| e.at_ns);
            (
                bytes,
                b.stream.items().to_vec(),
                b.flash_writes.clone(),
                last_step_ns,
            )
        })
        .unwrap();
    drop(rig);
    // The events (`$E <t_us> <what> …`), printed, and the instant of the first of a kind.
    let events: Vec<&str> = items
        .iter()
        .filter_map(|r| match r {
            Received::Event(_, text) => Some(text.as_str()),
            _ => None,
        })
        .collect();
    eprintln!("events: {events:#?}");
    let first = |what: &str| -> Option<u64> {
        events.iter().find_map(|e| {
            let mut w = e.split_whitespace().skip(1);
            let t = w.next()?.parse().ok()?;
            (w.next()? == what).then_some(t)
        })
    };
    // The committed model goes to flash only once the board is at rest (`store`'s module
    // docs), never while the steppers run: every program or erase the firmware started
    // (FLASH_CR with PG, or SER and STRT) came after the plant's last step. (Whether it was
    // saved is not this test's: rigless's STM32F427 flash model neither programs nor erases, so
    // the store reports `failed` here.)
    first("store").expect("the store write attempted");
    let done = last_step_ns / 1000;
    let operations: Vec<u64> = flash
        .iter()
        .filter(|&&(_, a, v)| a == FLASH_CR && (v & 1 != 0 || v & (1 << 16) != 0))
        .map(|&(t, ..)| t / 1000)
        .collect();
    eprintln!("flash operations at {operations:?} µs, the last step at {done} µs");
    assert!(!operations.is_empty(), "the store touched the flash");
    assert!(
        operations.iter().all(|&t| t > done),
        "flash operations at {operations:?} µs, the last step at {done} µs"
    );
    caches_emptied_after(&flash, *operations.last().unwrap());

    // The frame the new chain first estimated: the first stamped after the load event (module
    // docs of host-sim's `tests/all/chain.rs`: one of the first two after the event − a frame).
    let loaded_us = first("model").expect("the board announced the load");
    let cap = dir.join("rig.capture.bin");
    std::fs::write(&cap, capture).unwrap();
    let log = dir.join("rig.csv");
    ok(
        vfp()
            .arg("record")
            .arg(&cap)
            .args(["--binary", "--strict", "-o"])
            .arg(&log)
            .output()
            .unwrap(),
        "vfp record",
    );
    let (header, rows) = read_log(&log);
    let t_col = column(&header, "time_s");
    let ch_col = column(&header, "chamber");
    let phat_col = column(&header, "p_hat_kpa");
    let board: Vec<(f64, f32)> = rows
        .iter()
        .filter(|r| r[ch_col] == "0")
        .map(|r| (r[t_col].parse().unwrap(), r[phat_col].parse().unwrap()))
        .collect();
    let near = board
        .iter()
        .position(|&(t, _)| t * 1e6 + 40_000.0 > loaded_us as f64)
        .expect("frames after the load");
    let matched = (near..near + 2).find_map(|from| {
        let replayed = replay_from(&log, board[from].0, &model, &dir);
        let n = replayed.len().min(board.len() - from);
        let same = replayed
            .iter()
            .zip(&board[from..])
            .filter(|(r, (_, b))| r.to_bits() == b.to_bits())
            .count();
        eprintln!("from frame {from}: {same} of {n} P̂ identical");
        (n > 300 && same == n).then_some(n)
    });
    assert!(
        matched.is_some(),
        "no start frame near {near} replays the binary's P̂ bit for bit"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn read_log(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty());
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no {name} column in {header:?}"))
}

/// `vfp replay` of `log` from `t0` on (the header and comments kept); P̂ of chamber 0 per frame.
fn replay_from(log: &Path, t0: f64, model: &Path, dir: &Path) -> Vec<f32> {
    let text = std::fs::read_to_string(log).unwrap();
    let mut kept = Vec::new();
    let mut time_col = None;
    for l in text.lines() {
        if l.starts_with('#') || l.is_empty() {
            kept.push(l.to_string());
            continue;
        }
        let Some(tc) = time_col else {
            time_col = l.split(',').position(|c| c == "time_s");
            kept.push(l.to_string());
            continue;
        };
        let t: f64 = l.split(',').nth(tc).unwrap().parse().unwrap();
        if t >= t0 - 1e-7 {
            kept.push(l.to_string());
        }
    }
    let cut = dir.join("cut.csv");
    std::fs::write(&cut, kept.join("\n")).unwrap();
    let out = dir.join("replay.csv");
    ok(
        vfp()
            .arg("replay")
            .arg(model)
            .arg(&cut)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap(),
        "vfp replay",
    );
    let (header, rows) = read_log(&out);
    let col = column(&header, "p_hat_0");
    rows.iter().map(|r| r[col].parse().unwrap()).collect()
}

/// FLASH_ACR's cache bits (RM0390 §3.9.1): enables and resets of the instruction and data
/// caches.
const ICEN: u64 = 1 << 9;
const DCEN: u64 = 1 << 10;
const ICRST: u64 = 1 << 11;
const DCRST: u64 = 1 << 12;

/// After the last flash operation (at `last_us`) the firmware emptied both flash caches, the
/// way RM0390 §3.5.2 allows (reset only while disabled), and turned them back on: a cache left
/// as it was would go on serving words the erase or the program replaced.
fn caches_emptied_after(flash: &[(u64, u64, u64)], last_us: u64) {
    let acr: Vec<u64> = flash
        .iter()
        .filter(|&&(t, a, _)| a == FLASH_ACR && t / 1000 >= last_us)
        .map(|&(.., v)| v)
        .collect();
    eprintln!("FLASH_ACR writes after the last operation: {acr:x?}");
    let reset = acr
        .iter()
        .position(|v| v & (ICRST | DCRST) == ICRST | DCRST)
        .expect("both flash caches reset after the store's last flash operation");
    assert!(
        reset > 0 && acr[reset - 1] & (ICEN | DCEN) == 0,
        "the caches were disabled before their reset: {acr:x?}"
    );
    let now = acr.last().unwrap();
    assert!(
        now & (ICEN | DCEN) == ICEN | DCEN && now & (ICRST | DCRST) == 0,
        "the caches are back on, out of reset: {acr:x?}"
    );
}
