//! Peer protocol decoders must never panic: control frames (stream decoder
//! fed in arbitrary chunks) and latent datagrams. Whatever decodes must
//! re-encode and decode to the same value.
use telextiles_proto::peer::{decode_control_payload, encode_control, FrameDecoder, LatentFrame};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    if let Ok(f) = LatentFrame::decode(data) {
        let again = f.encode().expect("a decoded frame re-encodes");
        assert_eq!(LatentFrame::decode(&again).expect("round trip"), f);
    }
    if let Ok(m) = decode_control_payload(data) {
        let frame = encode_control(&m).expect("a decoded message re-encodes");
        assert_eq!(decode_control_payload(&frame[4..]).expect("round trip"), m);
    }
    // Stream decoder: split at a data-dependent point.
    let cut = data.first().map_or(0, |&b| b as usize % (data.len() + 1));
    let mut dec = FrameDecoder::new();
    dec.push(&data[..cut]);
    while let Ok(Some(_)) = dec.next_message() {}
    dec.push(&data[cut..]);
    while let Ok(Some(_)) = dec.next_message() {}
}
