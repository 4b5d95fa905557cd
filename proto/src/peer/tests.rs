use super::*;
use alloc::vec;
use proptest::prelude::*;

fn hello() -> Hello {
    Hello {
        protocol_version: PROTOCOL_VERSION,
        device_name: "studio-left".into(),
        encoder_hash: "ab".repeat(32),
        index_fingerprint: "cd".repeat(32),
        embedding_dim: 512,
    }
}

fn unit(v: Vec<f32>) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.into_iter().map(|x| x / n).collect()
}

fn all_messages() -> Vec<Control> {
    let latent = LatentFrame {
        seq: 9,
        capture_us: 123_456,
        press_id: 3,
        flags: FLAG_FINAL,
        vector: QuantVec::quantize_i8(&[0.5, -0.25, 1.0]),
    };
    vec![
        Control::Hello(hello()),
        Control::HelloAck,
        Control::Mismatch {
            reasons: vec![
                MismatchReason::ProtocolVersion { ours: 1, theirs: 2 },
                MismatchReason::EncoderHash {
                    ours: "a".into(),
                    theirs: "b".into(),
                },
            ],
        },
        Control::PressStart {
            press_id: 1,
            capture_us: 5,
        },
        Control::PressStop {
            press_id: 1,
            capture_us: 6,
            final_latent: Some(latent),
        },
        Control::PressStop {
            press_id: 2,
            capture_us: 7,
            final_latent: None,
        },
        Control::Ping { id: 4, t1_us: 100 },
        Control::Pong {
            id: 4,
            t1_us: 100,
            t2_us: 150,
            t3_us: 160,
        },
        Control::Error {
            code: ErrorCode::Protocol,
            message: "bad".into(),
        },
        Control::Pair(PairingMessage::Start(crate::pairing::PairingStart {
            version: 1,
            role: crate::pairing::PairingRole::EntersCode,
            pake: vec![7; 33],
        })),
        Control::Pair(PairingMessage::Abort(
            crate::pairing::PairingAbort::WrongCode,
        )),
    ]
}

#[test]
fn control_roundtrip_through_stream_decoder_in_odd_chunks() {
    let msgs = all_messages();
    let mut wire = Vec::new();
    for m in &msgs {
        wire.extend(encode_control(m).unwrap());
    }
    for chunk in [1usize, 3, 7, 64, wire.len()] {
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        for c in wire.chunks(chunk) {
            dec.push(c);
            while let Some(m) = dec.next_message().unwrap() {
                got.push(m);
            }
        }
        assert_eq!(got, msgs, "chunk size {chunk}");
        assert_eq!(dec.buffered(), 0);
    }
}

#[test]
fn oversized_frame_prefix_is_refused_before_buffering_it() {
    let mut dec = FrameDecoder::new();
    dec.push(&((MAX_CONTROL_FRAME as u32) + 1).to_le_bytes());
    assert!(matches!(
        dec.next_message(),
        Err(PeerError::FrameTooLarge { .. })
    ));
}

#[test]
fn limits_are_enforced_on_encode_and_decode() {
    let mut h = hello();
    h.device_name = "x".repeat(MAX_NAME_LEN + 1);
    let m = Control::Hello(h);
    assert_eq!(
        encode_control(&m),
        Err(PeerError::Limit("device name too long"))
    );
    // Hand-encode the oversized message, bypassing validation: decode refuses it.
    let payload = bincode::serde::encode_to_vec(&m, bincode::config::standard()).unwrap();
    assert_eq!(
        decode_control_payload(&payload),
        Err(PeerError::Limit("device name too long"))
    );
    let big = Control::Pair(PairingMessage::Start(crate::pairing::PairingStart {
        version: 1,
        role: crate::pairing::PairingRole::ShowsCode,
        pake: vec![0; MAX_PAKE_MESSAGE_LEN + 1],
    }));
    assert!(encode_control(&big).is_err());
}

#[test]
fn trailing_bytes_are_an_error() {
    let mut f = encode_control(&Control::HelloAck).unwrap();
    f.push(0);
    let len = (f.len() - 4) as u32;
    f[..4].copy_from_slice(&len.to_le_bytes());
    let mut dec = FrameDecoder::new();
    dec.push(&f);
    assert!(matches!(
        dec.next_message(),
        Err(PeerError::TrailingBytes { extra: 1 })
    ));
}

#[test]
fn hello_check_lists_every_difference_with_readable_text() {
    let a = hello();
    assert_eq!(check_hello(&a, &a.clone()), Ok(()));
    let mut b = hello();
    b.encoder_hash = "ff".repeat(32);
    b.index_fingerprint = "ee".repeat(32);
    let r = check_hello(&a, &b).unwrap_err();
    assert_eq!(r.len(), 2);
    let text = alloc::format!("{}", r[0]);
    assert!(text.contains("encoder model differs"), "{text}");
    assert!(text.contains("abababababab"), "{text}");
    assert!(text.contains("ffffffffffff"), "{text}");
    let text = alloc::format!("{}", r[1]);
    assert!(text.contains("textile index differs"), "{text}");
}

#[test]
fn latent_datagram_roundtrip_and_size() {
    let v: Vec<f32> = unit((0..512).map(|i| ((i * 37 % 101) as f32) - 50.0).collect());
    for vector in [QuantVec::quantize_i8(&v), QuantVec::quantize_f16(&v)] {
        let f = LatentFrame {
            seq: u64::MAX - 1,
            capture_us: 42,
            press_id: 7,
            flags: FLAG_FINAL,
            vector,
        };
        let b = f.encode().unwrap();
        assert_eq!(b.len(), f.encoded_len());
        assert_eq!(LatentFrame::decode(&b).unwrap(), f);
    }
    // 512-d int8 + header fits the 1200-byte QUIC minimum datagram budget.
    assert_eq!(
        LatentFrame {
            seq: 0,
            capture_us: 0,
            press_id: 0,
            flags: 0,
            vector: QuantVec::quantize_i8(&v)
        }
        .encoded_len(),
        DATAGRAM_HEADER_LEN + 4 + 512
    );
    assert!(matches!(quantize_to_fit(&v, 1288), Some(QuantVec::F16(_))));
    assert!(matches!(
        quantize_to_fit(&v, 1000),
        Some(QuantVec::I8 { .. })
    ));
    assert!(quantize_to_fit(&v, 500).is_none());
}

#[test]
fn latent_decode_rejects_bad_input() {
    let f = LatentFrame {
        seq: 1,
        capture_us: 2,
        press_id: 3,
        flags: 0,
        vector: QuantVec::quantize_i8(&[1.0, 0.0]),
    };
    let b = f.encode().unwrap();
    assert!(matches!(
        LatentFrame::decode(&b[..b.len() - 1]),
        Err(PeerError::Truncated { .. })
    ));
    let mut bad = b.clone();
    bad[0] = 9;
    assert_eq!(
        LatentFrame::decode(&bad),
        Err(PeerError::BadDatagramVersion(9))
    );
    let mut bad = b.clone();
    bad[1] = 7;
    assert_eq!(LatentFrame::decode(&bad), Err(PeerError::BadEncoding(7)));
    let mut bad = b.clone();
    bad[DATAGRAM_HEADER_LEN..DATAGRAM_HEADER_LEN + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(matches!(
        LatentFrame::decode(&bad),
        Err(PeerError::Limit(_))
    ));
}

#[test]
fn f16_conversion_matches_known_values() {
    let cases: [(f32, u16); 9] = [
        (0.0, 0x0000),
        (-0.0, 0x8000),
        (1.0, 0x3c00),
        (-2.0, 0xc000),
        (65504.0, 0x7bff),
        (65520.0, 0x7c00),        // rounds to inf
        (5.960_464_5e-8, 0x0001), // smallest subnormal
        (0.333_333_34, 0x3555),
        (f32::INFINITY, 0x7c00),
    ];
    for (x, h) in cases {
        assert_eq!(f32_to_f16(x), h, "{x}");
    }
    assert!(f16_to_f32(f32_to_f16(f32::NAN)).is_nan());
    // Every finite f16 survives f16 -> f32 -> f16.
    for h in 0u16..=0xffff {
        let exp = (h >> 10) & 0x1f;
        if exp == 0x1f {
            continue;
        }
        assert_eq!(f32_to_f16(f16_to_f32(h)), h, "{h:#06x}");
    }
}

#[test]
fn int8_quantisation_error_is_bounded_by_half_a_step() {
    let v = unit(
        (0..512)
            .map(|i| ((i * 7919 % 1000) as f32) / 500.0 - 1.0)
            .collect(),
    );
    let q = QuantVec::quantize_i8(&v);
    let QuantVec::I8 { scale, .. } = q else {
        unreachable!()
    };
    for (a, b) in v.iter().zip(q.dequantize()) {
        assert!((a - b).abs() <= scale / 2.0 + 1e-7, "{a} vs {b}");
    }
    // Degenerate inputs quantise without panicking.
    assert_eq!(QuantVec::quantize_i8(&[0.0; 4]).dequantize(), vec![0.0; 4]);
    assert_eq!(
        QuantVec::quantize_i8(&[f32::NAN, 1.0]).dequantize(),
        vec![0.0, 1.0]
    );
}

/// The figure quoted in docs/peer-protocol.md: what int8 (and f16)
/// quantisation costs in cosine similarity and nearest-neighbour decisions.
#[test]
fn quantisation_cost_on_random_unit_vectors() {
    // Easy: independent centroids (pairwise cosine ~0), moderate noise.
    let easy = quant_cost(512, 119, 2000, 0.0, 0.9, 1);
    std::println!("easy: {easy:?}");
    assert!(easy.i8_nn_agreement >= 0.999, "{easy:?}");
    // Hard: centroids with pairwise cosine ~0.8 and noise so large that the
    // float decision is right only ~half the time: many near-ties.
    let r = quant_cost(512, 119, 4000, 0.8, 3.5, 2);
    std::println!("hard: {r:?}");
    assert!(r.float_accuracy < 0.9, "not a hard case: {r:?}");
    assert!(r.i8_nn_agreement >= 0.97, "{r:?}");
    assert!(r.i8_max_cos_err < 0.01, "{r:?}");
    assert!(r.f16_nn_agreement >= 0.999, "{r:?}");
    assert!(r.f16_max_cos_err < 0.001, "{r:?}");
    assert!(
        r.i8_mean_cos_err < 0.001 && r.f16_mean_cos_err < 0.0001,
        "{r:?}"
    );
    assert_eq!(r.queries, 4000);
}

#[derive(Debug)]
pub struct QuantCost {
    /// Float nearest-centroid decision equals the query's true class.
    pub float_accuracy: f64,
    pub i8_mean_cos_err: f64,
    pub i8_max_cos_err: f64,
    pub i8_nn_agreement: f64,
    pub f16_mean_cos_err: f64,
    pub f16_max_cos_err: f64,
    pub f16_nn_agreement: f64,
    pub queries: usize,
}

/// `classes` random unit centroids in `dim` dimensions; each query is a
/// random centroid plus isotropic noise with `noise_norm` (relative), so the
/// nearest-centroid decision is often close. Compares the decision and the
/// cosine similarity to every centroid for the float query vs its int8/f16
/// quantised version.
pub fn quant_cost(
    dim: usize,
    classes: usize,
    queries: usize,
    centroid_cos: f32,
    noise_norm: f32,
    seed: u64,
) -> QuantCost {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let gauss = |rng: &mut rand_chacha::ChaCha8Rng| {
        // Box-Muller
        let u1: f32 = rng.gen_range(1e-7f32..1.0);
        let u2: f32 = rng.gen_range(0.0f32..1.0);
        (-2.0 * u1.ln()).sqrt() * (2.0 * core::f32::consts::PI * u2).cos()
    };
    let shared = unit((0..dim).map(|_| gauss(&mut rng)).collect());
    let (a, b) = (centroid_cos.sqrt(), (1.0 - centroid_cos).sqrt());
    let cents: Vec<Vec<f32>> = (0..classes)
        .map(|_| {
            let r = unit((0..dim).map(|_| gauss(&mut rng)).collect());
            unit(shared.iter().zip(&r).map(|(s, r)| a * s + b * r).collect())
        })
        .collect();
    let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
    let nn = |q: &[f32]| {
        let mut best = (0usize, f32::MIN);
        for (i, c) in cents.iter().enumerate() {
            let s = dot(q, c);
            if s > best.1 {
                best = (i, s);
            }
        }
        best.0
    };
    let (mut i8_sum, mut i8_max, mut i8_agree) = (0f64, 0f64, 0usize);
    let (mut f16_sum, mut f16_max, mut f16_agree) = (0f64, 0f64, 0usize);
    let mut n = 0usize;
    let mut float_right = 0usize;
    for _ in 0..queries {
        let class = rng.gen_range(0..classes);
        let c = &cents[class];
        let noise = unit((0..dim).map(|_| gauss(&mut rng)).collect());
        let q = unit(
            c.iter()
                .zip(&noise)
                .map(|(a, b)| a + noise_norm * b)
                .collect(),
        );
        let truth = nn(&q);
        if truth == class {
            float_right += 1;
        }
        let qi = unit(QuantVec::quantize_i8(&q).dequantize());
        let qh = unit(QuantVec::quantize_f16(&q).dequantize());
        if nn(&qi) == truth {
            i8_agree += 1;
        }
        if nn(&qh) == truth {
            f16_agree += 1;
        }
        for cent in &cents {
            let s = dot(&q, cent) as f64;
            let ei = (dot(&qi, cent) as f64 - s).abs();
            let eh = (dot(&qh, cent) as f64 - s).abs();
            i8_sum += ei;
            f16_sum += eh;
            i8_max = i8_max.max(ei);
            f16_max = f16_max.max(eh);
            n += 1;
        }
    }
    QuantCost {
        float_accuracy: float_right as f64 / queries as f64,
        i8_mean_cos_err: i8_sum / n as f64,
        i8_max_cos_err: i8_max,
        i8_nn_agreement: i8_agree as f64 / queries as f64,
        f16_mean_cos_err: f16_sum / n as f64,
        f16_max_cos_err: f16_max,
        f16_nn_agreement: f16_agree as f64 / queries as f64,
        queries,
    }
}

#[test]
fn latest_wins_drops_stale_and_duplicate_frames() {
    let mut lw = LatestWins::new();
    let got: Vec<bool> = [1u64, 3, 2, 3, 4, 0, 10, 9]
        .iter()
        .map(|&s| lw.accept(s))
        .collect();
    assert_eq!(
        got,
        vec![true, true, false, false, true, false, true, false]
    );
    assert_eq!(lw.last(), Some(10));
    assert_eq!((lw.accepted(), lw.dropped()), (4, 4));
    assert!(!lw.accept(0));
    assert!(LatestWins::new().accept(0));
}

#[test]
fn clock_offset_prefers_the_min_rtt_sample() {
    // Peer clock = ours + 1_000_000 µs. Symmetric 500 µs each way.
    let off = 1_000_000u64;
    let sym = ClockSample {
        t1: 10_000,
        t2: 10_500 + off,
        t3: 10_600 + off,
        t4: 11_100,
    };
    assert_eq!(sym.rtt(), 1_000);
    assert_eq!(sym.offset(), off as i64);
    // Queued: 20 ms extra on the way back, biases offset by -10 ms.
    let queued = ClockSample {
        t1: 20_000,
        t2: 20_500 + off,
        t3: 20_600 + off,
        t4: 41_100,
    };
    let mut est = ClockOffset::new(8);
    assert!(est.offset_us().is_none());
    assert!(est.add(queued));
    assert_eq!(est.offset_us(), Some(off as i64 - 10_000));
    assert!(est.add(sym));
    assert_eq!(est.offset_us(), Some(off as i64));
    assert_eq!(est.rtt_us(), Some(1_000));
    // Frame captured at peer time 50_000+off, received 300 µs later.
    assert_eq!(est.one_way_us(50_000 + off, 50_300), Some(300));
    // Nonsense sample (peer sent before it received) is ignored.
    assert!(!est.add(ClockSample {
        t1: 5,
        t2: 10,
        t3: 9,
        t4: 20
    }));
    // The window forgets: after 8 queued samples the good one is gone.
    for _ in 0..8 {
        est.add(queued);
    }
    assert_eq!(est.offset_us(), Some(off as i64 - 10_000));
    assert_eq!(est.len(), 8);
}

/// A decoded latent only ever carries finite components of bounded size
/// (issue 19: an int8 scale near f32::MAX or an f16 infinity/NaN decoded
/// fine and reached the receiver as inf/NaN).
#[test]
fn latents_with_non_finite_or_huge_components_are_refused() {
    let frame = |vector| LatentFrame {
        seq: 1,
        capture_us: 2,
        press_id: 3,
        flags: 0,
        vector,
    };
    let ok = frame(QuantVec::I8 {
        scale: 1.0 / 127.0,
        data: vec![127, -127],
    });
    let mut huge = ok.encode().unwrap();
    huge[DATAGRAM_HEADER_LEN..DATAGRAM_HEADER_LEN + 4].copy_from_slice(&f32::MAX.to_le_bytes());
    assert_eq!(
        LatentFrame::decode(&huge),
        Err(PeerError::Limit("latent scale too large"))
    );
    for bits in [0x7c00u16, 0xfc00, 0x7e00] {
        let f = frame(QuantVec::F16(vec![0x3c00, bits]));
        assert!(f.encode().is_err());
        let mut b = frame(QuantVec::F16(vec![0x3c00, 0x3c00])).encode().unwrap();
        let n = b.len();
        b[n - 2..].copy_from_slice(&bits.to_le_bytes());
        assert_eq!(
            LatentFrame::decode(&b),
            Err(PeerError::Limit("latent component not finite"))
        );
    }
    // The sender's quantiser never produces such frames.
    let q = QuantVec::quantize_f16(&[f32::INFINITY, f32::NAN, 1.0e6, -1.0e6, 0.5]);
    assert_eq!(q.dequantize(), vec![0.0, 0.0, 65504.0, -65504.0, 0.5]);
    assert!(frame(q).encode().is_ok());
}

/// Peer-chosen timestamps at the ends of the u64 range (issue 19: the old
/// `as i64` arithmetic overflowed and panicked in checked builds).
#[test]
fn clock_arithmetic_on_extreme_peer_timestamps_saturates() {
    let max = u64::MAX;
    let s = ClockSample {
        t1: 0,
        t2: max,
        t3: max,
        t4: 0,
    };
    assert_eq!(s.rtt(), 0);
    assert_eq!(s.offset(), i64::MAX);
    let s = ClockSample {
        t1: max,
        t2: 0,
        t3: max,
        t4: max,
    };
    assert_eq!(s.rtt(), i64::MIN);
    assert_eq!(s.offset(), i64::MIN + 1);
    let mut est = ClockOffset::new(4);
    assert!(est.add(ClockSample {
        t1: 0,
        t2: max,
        t3: max,
        t4: 0
    }));
    assert_eq!(est.offset_us(), Some(i64::MAX));
    assert_eq!(est.one_way_us(0, max), Some(i64::MAX));
    assert_eq!(est.one_way_us(max, 0), Some(i64::MIN));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn clock_offset_never_panics(t in proptest::collection::vec(any::<u64>(), 4..40), cap in any::<u64>(), recv in any::<u64>()) {
        let mut est = ClockOffset::new(3);
        for c in t.chunks_exact(4) {
            let s = ClockSample { t1: c[0], t2: c[1], t3: c[2], t4: c[3] };
            let _ = (s.rtt(), s.offset());
            est.add(s);
            let _ = (est.offset_us(), est.rtt_us(), est.one_way_us(cap, recv));
        }
    }

    #[test]
    fn control_decoder_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let _ = decode_control_payload(&bytes);
        let mut dec = FrameDecoder::new();
        dec.push(&bytes);
        while let Ok(Some(_)) = dec.next_message() {}
    }

    #[test]
    fn datagram_decoder_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..1200)) {
        let _ = LatentFrame::decode(&bytes);
    }

    #[test]
    fn mutated_valid_frames_never_panic(idx in 0usize..11, flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8)) {
        let mut b = encode_control(&all_messages()[idx]).unwrap();
        for (i, x) in flips {
            let n = b.len();
            b[i % n] ^= x;
        }
        let mut dec = FrameDecoder::new();
        dec.push(&b);
        let _ = dec.next_message();
    }

    #[test]
    fn datagram_roundtrip_any(seq in any::<u64>(), cap in any::<u64>(), press in any::<u32>(),
                              v in proptest::collection::vec(-1.0f32..1.0, 0..600), f16 in any::<bool>()) {
        let vector = if f16 { QuantVec::quantize_f16(&v) } else { QuantVec::quantize_i8(&v) };
        let f = LatentFrame { seq, capture_us: cap, press_id: press, flags: 0, vector };
        let b = f.encode().unwrap();
        prop_assert_eq!(LatentFrame::decode(&b).unwrap(), f);
    }
}
