//! Run the bench program under `qemu-system-arm` and stream its execution trace into the
//! counter through a FIFO (the trace is never written to disk).
//!
//! QEMU translates one guest instruction per translation block (`-accel
//! tcg,one-insn-per-tb=on`, `-singlestep` before QEMU 8.1) and, with `-d exec,nochain`, logs
//! every block it executes: one `Trace …` line per executed instruction, with its PC.

use std::fs::File;
use std::io::Read;
use std::os::fd::AsRawFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

use super::trace::{trace_pc, Counter, Counts, Layout};

/// The machine: an STM32F405 (Cortex-M4F) with flash at 0x0800_0000 and 128 KiB SRAM at
/// 0x2000_0000, which holds the firmware's memory map (512 KiB / 128 KiB).
pub const MACHINE: &str = "netduinoplus2";

/// Stop a run that exceeds this many instructions (the program is looping).
const MAX_INSNS: u64 = 200_000_000;

/// What a run produced.
pub struct Run {
    /// The counter's result.
    pub counts: Counts,
    /// The program's own output (semihosting), lines starting with `fw-bench:`.
    pub messages: Vec<String>,
    /// Wall time of the run.
    pub wall: Duration,
}

/// QEMU's version, e.g. (7, 2).
pub fn version(qemu: &str) -> Result<(u32, u32), String> {
    let out = Command::new(qemu).arg("--version").output().map_err(|e| {
        format!("cannot run `{qemu}`: {e} (install it: apt-get install qemu-system-arm)")
    })?;
    let text = String::from_utf8_lossy(&out.stdout);
    parse_version(&text).ok_or_else(|| format!("cannot read the version of `{qemu}`: {text}"))
}

/// Major and minor from `QEMU emulator version 7.2.22 (…)`.
pub fn parse_version(text: &str) -> Option<(u32, u32)> {
    let v = text.split("version ").nth(1)?.split_whitespace().next()?;
    let mut it = v.split('.').map(|x| x.parse::<u32>().ok());
    Some((it.next()??, it.next()??))
}

/// The arguments that make QEMU log one line per executed instruction.
pub fn trace_args(version: (u32, u32)) -> Vec<&'static str> {
    let mut a = vec!["-d", "exec,nochain"];
    if version >= (8, 1) {
        a.extend(["-accel", "tcg,one-insn-per-tb=on"]);
    } else {
        a.push("-singlestep");
    }
    a
}

/// Run `elf` and count.
pub fn run(qemu: &str, elf: &Path, layout: &Layout, timeout: Duration) -> Result<Run, String> {
    let ver = version(qemu)?;
    let dir = std::env::temp_dir().join(format!("fw-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let fifo = dir.join("trace.fifo");
    let _ = std::fs::remove_file(&fifo);
    let status = Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .map_err(|e| format!("mkfifo: {e}"))?;
    if !status.success() {
        return Err(format!("mkfifo {} failed", fifo.display()));
    }
    let result = run_with_fifo(qemu, ver, elf, layout, &fifo, timeout);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn run_with_fifo(
    qemu: &str,
    ver: (u32, u32),
    elf: &Path,
    layout: &Layout,
    fifo: &PathBuf,
    timeout: Duration,
) -> Result<Run, String> {
    let started = Instant::now();
    let mut child = Command::new(qemu)
        .args([
            "-M", MACHINE, "-display", "none", "-monitor", "none", "-serial", "none",
        ])
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-kernel")
        .arg(elf)
        .args(trace_args(ver))
        .arg("-D")
        .arg(fifo)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start `{qemu}`: {e}"))?;
    let pid = child.id();
    // The program's output (semihosting goes to QEMU's stderr or stdout, by version).
    let collect = |r: Option<Box<dyn Read + Send>>| {
        thread::spawn(move || {
            let mut s = String::new();
            if let Some(mut r) = r {
                let _ = r.read_to_string(&mut s);
            }
            s
        })
    };
    let out_t = collect(
        child
            .stdout
            .take()
            .map(|r| Box::new(r) as Box<dyn Read + Send>),
    );
    let err_t = collect(
        child
            .stderr
            .take()
            .map(|r| Box::new(r) as Box<dyn Read + Send>),
    );
    // Wait for QEMU in a thread: when it exits without ever opening the FIFO, open it for
    // writing ourselves so the reader below gets its end of file instead of blocking forever.
    let (done_tx, done_rx) = mpsc::channel();
    let fifo_w = fifo.clone();
    let waiter = thread::spawn(move || {
        let status = child.wait();
        let _ = done_tx.send(());
        // Non-blocking: if the reader is gone already, this fails at once instead of waiting.
        let _ = std::fs::OpenOptions::new()
            .write(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(&fifo_w);
        status
    });
    // A watchdog: kill QEMU after the timeout.
    let watchdog = thread::spawn(move || {
        if done_rx.recv_timeout(timeout).is_err() {
            let _ = Command::new("kill")
                .arg(pid.to_string())
                .stderr(Stdio::null())
                .status();
            return true;
        }
        false
    });
    let counted = count(fifo, layout).inspect_err(|_| {
        let _ = Command::new("kill")
            .arg(pid.to_string())
            .stderr(Stdio::null())
            .status();
    });
    let status = waiter
        .join()
        .map_err(|_| "waiter thread")?
        .map_err(|e| format!("waiting for QEMU: {e}"))?;
    let timed_out = watchdog.join().unwrap_or(false);
    let output = out_t.join().unwrap_or_default() + &err_t.join().unwrap_or_default();
    let messages: Vec<String> = output
        .lines()
        .filter(|l| l.starts_with("fw-bench:"))
        .map(str::to_owned)
        .collect();
    if timed_out {
        return Err(format!("QEMU did not finish within {timeout:?}"));
    }
    if !status.success() {
        return Err(format!(
            "the bench program failed ({status}):\n{}",
            output.trim_end()
        ));
    }
    let counts = counted?;
    Ok(Run {
        counts,
        messages,
        wall: started.elapsed(),
    })
}

fn count(fifo: &Path, layout: &Layout) -> Result<Counts, String> {
    let f = File::open(fifo).map_err(|e| format!("{}: {e}", fifo.display()))?;
    // QEMU writes one line per write: a 1 MiB pipe (Linux' default ceiling for it) lets it run
    // ahead instead of waking the reader at every line. A refusal only costs speed.
    // SAFETY: fcntl on a descriptor we own, with an integer argument.
    unsafe {
        libc::fcntl(f.as_raw_fd(), libc::F_SETPIPE_SZ, 1 << 20);
    }
    let mut f = f;
    let mut counter = Counter::new(layout);
    // Read in large chunks; after a short read, wait a little so that QEMU fills the pipe
    // instead of waking this reader at every line (that ping-pong would double the run time).
    let mut buf = vec![0u8; 1 << 20];
    let mut have = 0;
    loop {
        let n = f
            .read(&mut buf[have..])
            .map_err(|e| format!("reading the trace: {e}"))?;
        if n == 0 {
            break;
        }
        have += n;
        let mut start = 0;
        while let Some(nl) = buf[start..have].iter().position(|&b| b == b'\n') {
            if let Some(pc) = trace_pc(&buf[start..start + nl]) {
                counter.exec(pc)?;
            }
            start += nl + 1;
        }
        buf.copy_within(start..have, 0);
        have -= start;
        if have == buf.len() {
            return Err("a trace line longer than 1 MiB".into());
        }
        if counter.instructions() > MAX_INSNS {
            return Err(format!("more than {MAX_INSNS} instructions: stopped"));
        }
        if n < 1 << 18 {
            thread::sleep(Duration::from_millis(2));
        }
    }
    if let Some(pc) = trace_pc(&buf[..have]) {
        counter.exec(pc)?;
    }
    counter.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn picks_the_single_step_option_by_version() {
        assert_eq!(
            parse_version("QEMU emulator version 7.2.22 (Debian 1:7.2+dfsg)\n"),
            Some((7, 2))
        );
        assert_eq!(
            parse_version("QEMU emulator version 10.0.2\n"),
            Some((10, 0))
        );
        assert_eq!(parse_version("something else"), None);
        assert!(trace_args((7, 2)).contains(&"-singlestep"));
        assert!(trace_args((8, 0)).contains(&"-singlestep"));
        assert!(trace_args((8, 1)).contains(&"tcg,one-insn-per-tb=on"));
        assert!(trace_args((10, 0)).contains(&"tcg,one-insn-per-tb=on"));
    }
}
