//! Ctrl-C: the first SIGINT sets the run's interruption flag, so the
//! library stops before the next frame (or between its final stages) with
//! `SlamError::Cancelled`, and its temporary record file and staging folder
//! are removed as it unwinds; `main` then exits with 130 (128 + SIGINT, the
//! shell's convention). A second SIGINT exits at once: the next run to the
//! same output removes what that leaves (`OutputDir`'s leftover cleanup).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// The flag the library polls; set by the handler.
static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// The exit status of a run interrupted by Ctrl-C.
pub const EXIT_INTERRUPTED: u8 = 130;

/// Installs the SIGINT handler (Unix; elsewhere Ctrl-C keeps killing the
/// process) and returns the flag it sets. Installed by the commands that
/// run the pipeline (`with_progress`), not by the viewer's server, whose
/// Ctrl-C still ends it at once.
pub fn install() -> Arc<AtomicBool> {
    let flag = FLAG.get_or_init(|| Arc::new(AtomicBool::new(false))).clone();
    #[cfg(unix)]
    // SAFETY: the handler only does async-signal-safe work (an atomic swap
    // on a flag initialised above, `_exit`).
    unsafe {
        libc::signal(libc::SIGINT, on_sigint as extern "C" fn(libc::c_int) as libc::sighandler_t);
    }
    flag
}

#[cfg(unix)]
extern "C" fn on_sigint(_: libc::c_int) {
    let Some(flag) = FLAG.get() else { return };
    if flag.swap(true, Ordering::SeqCst) {
        // SAFETY: `_exit` is async-signal-safe; nothing is unwound.
        unsafe { libc::_exit(i32::from(EXIT_INTERRUPTED)) }
    }
}
