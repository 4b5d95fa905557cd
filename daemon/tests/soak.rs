//! Soak: two live daemons pressing and feeling in both directions at 60 fps
//! for a set time (`TELEXTILES_SOAK_S`, default 90 s here; an hour by hand:
//! `TELEXTILES_SOAK_S=3600 cargo nextest run -p telextilesd --test soak --no-capture`).
//! After warm-up the resident memory of each daemon stays within 5 %, no
//! press loses its final decision on the other side, and errors do not grow
//! (errors counted from the end of warm-up to the stop, not during it).
#[path = "harness/mod.rs"]
mod harness;

use harness::*;
use std::time::Duration;

#[test]
fn soak_both_directions() {
    let secs: u64 = std::env::var("TELEXTILES_SOAK_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(90);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (pair, t_start, t_end) = rt.block_on(async {
        let pair = Pair::start(&Setup::default()).await;
        let t_start = mono_us();
        tokio::time::sleep(Duration::from_secs(secs)).await;
        (pair, t_start, mono_us())
    });
    let (ta, tb, a, b) = pair.stop();
    // Warm-up: the first 30 % (at least 20 s): allocator pools, ONNX
    // Runtime arenas and QUIC buffers reach their working size.
    let warm_end = t_start + (secs * 1_000_000 * 3 / 10).max(20_000_000);
    let mut report = Vec::new();
    for (side, to, from_tr, to_tr) in [(&a, &b, &ta, &tb), (&b, &a, &tb, &ta)] {
        let samples = side.samples.lock().unwrap().clone();
        let after: Vec<&(u64, f64, u64)> = samples.iter().filter(|s| s.0 >= warm_end).collect();
        assert!(
            after.len() >= 5,
            "too few samples of {}: {samples:?}",
            side.name
        );
        let rss_ref = after[0].2 as f64;
        let rss_max = after.iter().map(|s| s.2).max().unwrap() as f64;
        let growth = rss_max / rss_ref - 1.0;
        // Presses of `side` that ended well before the end must each have a
        // final decision on the other side.
        let (lost, done) = lost_finals(from_tr, to, t_start, t_end);
        let st = stages(from_tr, to_tr, t_start, t_end);
        // Errors of the run itself: the stop below shuts A down first, and
        // B, redialling a peer that is going away, may report a refused or
        // timed-out dial before it stops too; that is not growth.
        let errs: Vec<(u64, String)> = errors(side)
            .into_iter()
            .filter(|e| (warm_end..t_end).contains(&e.0))
            .collect();
        let mid = warm_end + (t_end - warm_end) / 2;
        let (first, second) = (
            errs.iter().filter(|e| e.0 < mid).count(),
            errs.iter().filter(|e| e.0 >= mid).count(),
        );
        let line = format!(
            "{} -> {}: {} presses finished, {} final decisions lost; {} of {} latents received; \
             capture->decision p50 {:.2} ms p99 {:.2} ms; RSS after warm-up {:.1} MB, max {:.1} MB (+{:.2} %); \
             errors after warm-up {first} + {second}",
            side.name,
            to.name,
            done,
            lost.len(),
            st.received,
            st.sent,
            pct(&st.total_decided, 50.0) / 1000.0,
            pct(&st.total_decided, 99.0) / 1000.0,
            rss_ref / 1e6,
            rss_max / 1e6,
            100.0 * growth
        );
        println!("{line}");
        report.push((line, done, lost, growth, first, second, errs, st));
    }
    for (line, done, lost, growth, first, second, errs, st) in report {
        assert!(
            done >= (secs as usize / 4).max(1),
            "too few presses: {line}"
        );
        assert!(
            lost.is_empty(),
            "final decisions lost for presses {lost:?}: {line}"
        );
        assert!(
            growth <= 0.05,
            "resident memory grew by more than 5 %: {line}"
        );
        assert!(second <= first, "errors grew: {line}\n{errs:#?}");
        assert!(
            st.received as f64 >= 0.9 * st.sent as f64,
            "latents lost on loopback: {line}"
        );
    }
}
