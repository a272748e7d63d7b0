//! Running one measured subprocess: wall time, CPU time (user + system) of
//! the child from `wait4`'s rusage, peak resident memory from the child's
//! `VmHWM` in /proc (polled while it runs), with a timeout that kills the
//! child's whole process group.
//!
//! Why not `ru_maxrss`: Linux carries the high-water mark of the address
//! space an `exec` replaces into the child's `maxrss`, so a child forked
//! from a large parent reports at least the parent's size. `VmHWM` belongs
//! to the address space of the new program only. It is a high-water mark,
//! so polling loses at most the growth of the last poll interval.
//!
//! Each run is its own process because rayon's global pool can be set up
//! once per process, and because a crash of one run must not end the suite.

use anyhow::{Context, Result};
use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// How often the child's state is polled while it runs.
const POLL_INTERVAL: Duration = Duration::from_millis(20);
/// Linux reports `ru_maxrss` in KiB.
const KIB_PER_MIB: f64 = 1024.0;
/// Exit status of a Rust panic in the main thread.
const PANIC_EXIT_CODE: i32 = 101;
/// Lines of the log quoted in a failure reason.
const REASON_LOG_LINES: usize = 1;

/// How a measured process ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Exit {
    /// Exit status 0.
    Success,
    /// Any other exit status.
    Code(i32),
    /// Killed by a signal (not ours).
    Signal(i32),
    /// Killed by us after the timeout.
    Timeout,
}

/// Measurements of one process.
#[derive(Debug, Clone)]
pub struct Measured {
    /// How it ended.
    pub exit: Exit,
    /// Wall time, seconds.
    pub wall_s: f64,
    /// User + system CPU time of the child, seconds.
    pub cpu_s: f64,
    /// Peak resident set size of the child, MiB.
    pub peak_rss_mib: f64,
}

impl Measured {
    /// A failure reason when the process did not succeed; `log` is the file
    /// that holds its output (its last non-empty line is quoted).
    pub fn failure_reason(&self, log: &Path, timeout: Duration) -> Option<String> {
        let what = match self.exit {
            Exit::Success => return None,
            Exit::Code(PANIC_EXIT_CODE) => "panic (exit 101)".to_string(),
            Exit::Code(c) => format!("exit status {c}"),
            Exit::Signal(s) => format!("killed by signal {s}"),
            Exit::Timeout => format!("timeout after {} s", timeout.as_secs()),
        };
        let tail = last_lines(log, REASON_LOG_LINES);
        Some(if tail.is_empty() { what } else { format!("{what}: {tail}") })
    }
}

/// `VmHWM` (peak resident set, KiB) from a /proc/<pid>/status file; `None`
/// when unreadable or absent (a zombie has none).
fn read_vm_hwm_kib(path: &str) -> Option<u64> {
    let text = std::fs::read_to_string(path).ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The last `n` non-empty lines of a text file, joined by " | ".
pub fn last_lines(path: &Path, n: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let start = lines.len().saturating_sub(n);
    lines.get(start..).unwrap_or_default().join(" | ")
}

/// Runs `cmd` with stdout and stderr going to `log`, waits at most
/// `timeout`, and returns its measurements. Errors only when the process
/// cannot be started or waited for.
pub fn run_measured(cmd: &mut Command, log: &Path, timeout: Duration) -> Result<Measured> {
    let out = File::create(log).with_context(|| format!("creating {}", log.display()))?;
    let err = out.try_clone().with_context(|| format!("duplicating the handle of {}", log.display()))?;
    cmd.stdin(Stdio::null()).stdout(out).stderr(err);
    // Own process group, so that a timeout also ends helpers (ffmpeg).
    cmd.process_group(0);
    let started = Instant::now();
    let child = cmd.spawn().with_context(|| format!("starting {:?}", cmd.get_program()))?;
    let pid = libc::pid_t::try_from(child.id()).context("child pid out of range")?;
    let mut status: libc::c_int = 0;
    // SAFETY: rusage is a plain C struct for which all-zero bytes are valid.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let mut killed = false;
    let status_path = format!("/proc/{pid}/status");
    let mut hwm_kib: Option<u64> = None;
    loop {
        // SAFETY: pid is our own child; status and usage are valid for writes.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        if r < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(e).context("waiting for a benchmark run");
        }
        if let Some(v) = read_vm_hwm_kib(&status_path) {
            hwm_kib = Some(hwm_kib.map_or(v, |h| h.max(v)));
        }
        if !killed && started.elapsed() > timeout {
            // SAFETY: kill has no memory effects; -pid names the child's group.
            unsafe {
                libc::kill(-pid, libc::SIGKILL);
            }
            killed = true;
        }
        std::thread::sleep(POLL_INTERVAL);
    }
    // The child is reaped by wait4 above; dropping the handle does not wait.
    drop(child);
    let wall_s = started.elapsed().as_secs_f64();
    let tv = |t: libc::timeval| t.tv_sec as f64 + 1e-6 * t.tv_usec as f64;
    let cpu_s = tv(usage.ru_utime) + tv(usage.ru_stime);
    // Fallback for a child that ended before the first poll.
    let peak_rss_mib = hwm_kib.map_or(usage.ru_maxrss as f64, |h| h as f64) / KIB_PER_MIB;
    let exit = if killed {
        Exit::Timeout
    } else if libc::WIFEXITED(status) {
        match libc::WEXITSTATUS(status) {
            0 => Exit::Success,
            c => Exit::Code(c),
        }
    } else if libc::WIFSIGNALED(status) {
        Exit::Signal(libc::WTERMSIG(status))
    } else {
        Exit::Code(-1)
    };
    Ok(Measured { exit, wall_s, cpu_s, peak_rss_mib })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measures_success_failure_and_timeout() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("log.txt");
        let t = Duration::from_secs(20);
        let m = run_measured(Command::new("sh").args(["-c", "echo hello"]), &log, t).unwrap();
        assert_eq!(m.exit, Exit::Success);
        assert!(m.failure_reason(&log, t).is_none());
        assert_eq!(last_lines(&log, 1), "hello");

        let m = run_measured(Command::new("sh").args(["-c", "echo boom >&2; exit 3"]), &log, t).unwrap();
        assert_eq!(m.exit, Exit::Code(3));
        assert_eq!(m.failure_reason(&log, t).unwrap(), "exit status 3: boom");

        let short = Duration::from_millis(200);
        let m = run_measured(Command::new("sh").args(["-c", "sleep 30"]), &log, short).unwrap();
        assert_eq!(m.exit, Exit::Timeout);
        assert!(m.wall_s < 10.0, "the timeout must end the child early: {}", m.wall_s);

        // A small child of a large parent reports its own peak, not the
        // parent's (ru_maxrss would report at least the parent's 256 MiB).
        let big = vec![1u8; 256 << 20];
        let m = run_measured(Command::new("sh").args(["-c", "sleep 0.3"]), &log, t).unwrap();
        assert!(big.iter().step_by(4096).all(|&b| b == 1));
        assert!(m.peak_rss_mib > 0.0 && m.peak_rss_mib < 64.0, "peak RSS of sleep: {} MiB", m.peak_rss_mib);
        drop(big);

        // A child that allocates and touches 64 MiB shows at least that peak.
        let m = run_measured(
            Command::new("python3").args(["-c", "b = bytearray(64 << 20); b[::4096] = b'x' * len(b[::4096])"]),
            &log,
            t,
        );
        if let Ok(m) = m
            && m.exit == Exit::Success
        {
            assert!(m.peak_rss_mib > 60.0, "peak RSS {}", m.peak_rss_mib);
        }
    }
}
