//! Fuzzes the roller frame decoder and message parsers: arbitrary bytes,
//! fed whole and in arbitrary chunks, must never panic, never hold more than
//! one frame, and every decoded frame must re-encode to bytes that decode to
//! the same frame.
use telextiles_proto::roller::{Command, FrameDecoder, Reply, MAX_FRAME};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    // The first byte picks a chunk size, the rest is the line.
    let Some((&chunk, line)) = data.split_first() else {
        return;
    };
    let chunk = (chunk as usize % 64) + 1;
    let mut whole = FrameDecoder::new();
    let a: Vec<_> = whole.feed(line).collect();
    let mut pieces = FrameDecoder::new();
    let mut b = Vec::new();
    for part in line.chunks(chunk) {
        b.extend(pieces.feed(part));
    }
    assert_eq!(a, b, "chunking changed the result");
    assert!(whole.buffered() < MAX_FRAME);
    for f in a.into_iter().flatten() {
        if let Ok(c) = Command::from_frame(&f) {
            assert_eq!(c.to_frame(f.seq), f);
        }
        if let Ok(r) = Reply::from_frame(&f) {
            assert_eq!(r.to_frame(f.seq), f);
        }
        let enc = f.encode();
        let mut again = FrameDecoder::new();
        let back: Vec<_> = again.feed(enc.as_bytes()).collect();
        assert_eq!(back, vec![Ok(f)]);
    }
}
