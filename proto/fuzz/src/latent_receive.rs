//! The receive path of latent datagrams, as the link and the receiver's
//! decider run it: a sequence of datagrams (each `u16 LE length | bytes`)
//! is decoded, filtered latest-wins, dequantised, L2-normalised, averaged
//! over the press and matched against centroids by cosine similarity (the
//! decider's running mean and index search). Never panics, and whatever a
//! peer sends, every number the receiver computes stays finite.
use telextiles_proto::peer::{LatentFrame, LatestWins, MAX_DIM};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let mut latest = LatestWins::new();
    let mut mean: Vec<f32> = Vec::new();
    let mut count = 0u32;
    let mut rest = data;
    while rest.len() >= 2 {
        let len = usize::from(u16::from_le_bytes([rest[0], rest[1]]));
        let body = &rest[2..];
        let take = len.min(body.len());
        let (dgram, tail) = body.split_at(take);
        rest = tail;
        let Ok(frame) = LatentFrame::decode(dgram) else {
            continue;
        };
        let v = frame.vector.dequantize();
        assert_eq!(v.len(), frame.vector.dim());
        assert!(v.len() <= MAX_DIM);
        assert!(
            v.iter().all(|x| x.is_finite()),
            "a decoded latent carries a non-finite component"
        );
        if !latest.accept(frame.seq) || v.is_empty() {
            continue;
        }
        // Receiver: normalise (f32, as the decider does).
        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!(norm.is_finite(), "norm of a decoded latent overflowed");
        let unit: Vec<f32> = if norm > 0.0 {
            v.iter().map(|x| x / norm).collect()
        } else {
            v
        };
        if mean.len() != unit.len() || frame.is_final() {
            mean = vec![0.0; unit.len()];
            count = 0;
        }
        count += 1;
        let k = 1.0 / count as f32;
        for (m, x) in mean.iter_mut().zip(&unit) {
            *m += (x - *m) * k;
        }
        // Index search over a few fixed centroids.
        let dim = mean.len();
        let best = (0..4usize)
            .map(|c| {
                let s: f32 = (0..dim)
                    .map(|i| if (i + c) % 4 == 0 { mean[i] } else { 0.0 })
                    .sum();
                s / (dim as f32 / 4.0).sqrt().max(1.0)
            })
            .fold(f32::NEG_INFINITY, f32::max);
        assert!(best.is_finite(), "similarity is not finite");
    }
}
