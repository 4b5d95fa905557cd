//! A small tokio client for the control socket (used by `telextilesd ctl`
//! and by tests).

use crate::protocol::{
    parse_server_line, Command, CtlError, Event, RequestId, ServerLine, SubscribeArgs,
};
use serde_json::Value;
use std::io;
use std::path::{Path, PathBuf};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::unix::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::UnixStream;

/// Longest line the client accepts from the server.
pub const CLIENT_MAX_LINE: u64 = 16 * 1024 * 1024;

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("cannot connect to the control socket {path}: {source} (is telextilesd running? see --socket)")]
    Connect {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("control socket I/O failed: {0}")]
    Io(#[from] io::Error),
    #[error("{0}")]
    Protocol(String),
    #[error("the daemon closed the connection")]
    Closed,
}

/// One connection to the daemon.
pub struct Client {
    rd: BufReader<OwnedReadHalf>,
    wr: OwnedWriteHalf,
    next_id: u64,
    /// Bytes of a line read so far. Kept across calls so that a read
    /// cancelled in a `select!` loses nothing (cancel safety).
    partial: Vec<u8>,
}

impl Client {
    pub async fn connect(path: &Path) -> Result<Client, ClientError> {
        let stream = UnixStream::connect(path)
            .await
            .map_err(|source| ClientError::Connect {
                path: path.to_path_buf(),
                source,
            })?;
        let (rd, wr) = stream.into_split();
        Ok(Client {
            rd: BufReader::new(rd),
            wr,
            next_id: 1,
            partial: Vec::new(),
        })
    }

    /// Sends raw bytes (tests use this to send malformed input).
    pub async fn send_raw(&mut self, bytes: &[u8]) -> Result<(), ClientError> {
        self.wr.write_all(bytes).await?;
        Ok(())
    }

    /// Next line from the server; `None` at EOF. Cancel safe: bytes of a
    /// line read before a cancellation are kept for the next call.
    pub async fn read_line(&mut self) -> Result<Option<ServerLine>, ClientError> {
        let room = CLIENT_MAX_LINE.saturating_sub(self.partial.len() as u64);
        (&mut self.rd)
            .take(room)
            .read_until(b'\n', &mut self.partial)
            .await?;
        let line = std::mem::take(&mut self.partial);
        let n = line.len();
        if n == 0 {
            return Ok(None);
        }
        if line.last() != Some(&b'\n') {
            return Err(ClientError::Protocol(if n as u64 >= CLIENT_MAX_LINE {
                format!("server line longer than {CLIENT_MAX_LINE} bytes")
            } else {
                "connection closed in the middle of a line".into()
            }));
        }
        parse_server_line(&line[..line.len() - 1])
            .map(Some)
            .map_err(ClientError::Protocol)
    }

    /// Sends a command and waits for its reply (events received meanwhile
    /// are skipped). Returns the daemon's answer: data or error.
    pub async fn call(
        &mut self,
        command: &Command,
    ) -> Result<Result<Value, CtlError>, ClientError> {
        let id = RequestId::from(self.next_id);
        self.next_id += 1;
        self.wr
            .write_all(command.to_request_line(&id).as_bytes())
            .await?;
        loop {
            match self.read_line().await? {
                None => return Err(ClientError::Closed),
                Some(ServerLine::Reply(r)) if r.id == id => return Ok(r.into_result()),
                Some(ServerLine::Reply(r)) if r.id == RequestId::Null && !r.ok => {
                    // Connection-level error (busy, line too long).
                    return Ok(r.into_result());
                }
                Some(_) => continue,
            }
        }
    }

    /// Subscribes; afterwards read events with [`Client::next_event`].
    pub async fn subscribe(
        &mut self,
        args: SubscribeArgs,
    ) -> Result<Result<Value, CtlError>, ClientError> {
        self.call(&Command::Subscribe(args)).await
    }

    /// Next event (known or unknown kind, as JSON); `None` at EOF.
    pub async fn next_event(&mut self) -> Result<Option<EventLine>, ClientError> {
        loop {
            match self.read_line().await? {
                None => return Ok(None),
                Some(ServerLine::Event(e)) => return Ok(Some(EventLine::Known(e))),
                Some(ServerLine::UnknownEvent(v)) => return Ok(Some(EventLine::Unknown(v))),
                Some(ServerLine::Reply(_)) => continue,
            }
        }
    }
}

/// An event line as received.
#[derive(Debug, Clone, PartialEq)]
pub enum EventLine {
    Known(Event),
    /// An event kind newer than this client.
    Unknown(Value),
}
