//! Printing to stdout that ends the process quietly when stdout is a closed
//! pipe (`colslam info MODEL | head -1`): `println!` panics there (Rust
//! ignores SIGPIPE, so the write fails with EPIPE). Resetting SIGPIPE to its
//! default instead would also let a write to a closed socket of the viewer or
//! to a peer process's pipe kill the process; this touches stdout only.

use std::io::Write;

/// Writes one line to stdout. When the reader of stdout has gone, nothing
/// more can be shown and the output already written was all it wanted, so
/// the process exits with status 0 without a message (like a filter killed by
/// SIGPIPE, but a success for `set -o pipefail`); any other write error is
/// reported on stderr with status 1.
pub fn line(args: std::fmt::Arguments<'_>) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.write_all(b"\n")).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to stdout: {e}");
        std::process::exit(1);
    }
}

/// `println!` through [`line`] (exported for the `colslam` binary, which
/// prints the same way).
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout::line(format_args!($($arg)*))
    };
}
pub use outln;
