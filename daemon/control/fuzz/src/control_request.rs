//! Fuzzes the control protocol decoders: the request parser, the client's
//! server-line parser and the bounded line framer must never panic, and
//! whatever parses must re-encode to itself.

use telextiles_control::protocol::{parse_request, parse_server_line, Frame, LineFramer};

const CAP: usize = 256;

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    check_line(data);
    let _ = parse_server_line(data);

    // The same bytes as a stream, split at a data-dependent point.
    let split = data.first().map_or(0, |b| usize::from(*b)).min(data.len());
    let mut framer = LineFramer::new(CAP);
    framer.feed(&data[..split]);
    framer.feed(&data[split..]);
    assert!(framer.pending() <= CAP);
    while let Some(frame) = framer.next_frame() {
        if let Frame::Line(line) = frame {
            assert!(line.len() <= CAP);
            assert!(!line.contains(&b'\n'));
            check_line(&line);
        }
    }
}

fn check_line(line: &[u8]) {
    match parse_request(line) {
        Ok(req) => {
            let encoded = req.command.to_request_line(&req.id);
            let again =
                parse_request(encoded.trim_end().as_bytes()).expect("re-encoded request parses");
            assert_eq!(again, req);
        }
        Err(e) => {
            assert!(!e.error.message.is_empty());
            let reply = e.to_reply_line();
            assert!(reply.ends_with('\n'));
            assert!(parse_server_line(reply.trim_end().as_bytes()).is_ok());
        }
    }
}
