//! Standard output of the one-shot commands. A reader that goes away early
//! (`telextilesd sim list | head -3`) is not a failure: the command ends
//! quietly with status 0, as `cat` would, instead of panicking in
//! `println!`. Only stdout is treated so: a broken control socket or serial
//! port is still an error.
use std::io::{self, Write};

/// Why a write to stdout failed: its reader closed it.
#[derive(Debug, thiserror::Error)]
#[error("standard output was closed by its reader")]
pub struct Closed;

/// Standard output whose closed-pipe errors carry [`Closed`].
pub struct Stdout(io::Stdout);

/// Standard output (line-buffered, as `println!` writes it).
pub fn stdout() -> Stdout {
    Stdout(io::stdout())
}

fn mark(e: io::Error) -> io::Error {
    if e.kind() == io::ErrorKind::BrokenPipe {
        io::Error::new(io::ErrorKind::BrokenPipe, Closed)
    } else {
        e
    }
}

impl Write for Stdout {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.write(buf).map_err(mark)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush().map_err(mark)
    }
}

/// Whether `e` (anywhere in its chain) is a write to a closed stdout.
pub fn is_closed(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.is::<Closed>()
            || c.downcast_ref::<io::Error>()
                .and_then(|io| io.get_ref())
                .is_some_and(|inner| inner.is::<Closed>())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_marked_broken_pipe_counts_as_a_closed_stdout() {
        let marked = anyhow::Error::from(mark(io::Error::from(io::ErrorKind::BrokenPipe)));
        assert!(is_closed(&marked));
        assert!(is_closed(&marked.context("writing the index")));
        // A broken pipe elsewhere (a control socket, a serial port) is an
        // error the user must see.
        let socket = anyhow::Error::from(io::Error::from(io::ErrorKind::BrokenPipe));
        assert!(!is_closed(&socket));
        let other = anyhow::Error::from(mark(io::Error::from(io::ErrorKind::PermissionDenied)));
        assert!(!is_closed(&other));
    }
}
