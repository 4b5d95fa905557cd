//! The clock-offset estimator fed peer-chosen timestamps (pongs carry three
//! of the four): never panics or overflows, keeps only samples with a
//! non-negative round trip, and trusts the one with the smallest.
use telextiles_proto::peer::{ClockOffset, ClockSample};

fn u64_at(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    a[..b.len().min(8)].copy_from_slice(&b[..b.len().min(8)]);
    u64::from_le_bytes(a)
}

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let Some((&window, rest)) = data.split_first() else {
        return;
    };
    let mut est = ClockOffset::new(usize::from(window % 20));
    let mut kept = Vec::new();
    for c in rest.chunks(32) {
        let s = ClockSample {
            t1: u64_at(c),
            t2: u64_at(c.get(8..).unwrap_or(&[])),
            t3: u64_at(c.get(16..).unwrap_or(&[])),
            t4: u64_at(c.get(24..).unwrap_or(&[])),
        };
        let (rtt, _) = (s.rtt(), s.offset());
        if est.add(s) {
            assert!(rtt >= 0, "kept a sample with a negative round trip");
            kept.push(s);
        }
        let w = usize::from(window % 20).max(1);
        let recent = &kept[kept.len().saturating_sub(w)..];
        assert_eq!(est.len(), recent.len());
        let best = recent.iter().map(|s| s.rtt()).min();
        assert_eq!(est.rtt_us(), best);
        let _ = est.one_way_us(u64_at(c), u64_at(c.get(4..).unwrap_or(&[])));
    }
}
