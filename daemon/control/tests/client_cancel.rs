//! The client's reads are cancel safe: a read cancelled in the middle of a
//! line (a `select!` branch losing, a timeout) loses no bytes, so the next
//! read returns the whole line. `telextilesd demo` selects over two event
//! streams and relies on this.
use std::time::Duration;
use telextiles_control::protocol::ServerLine;
use telextiles_control::Client;
use tokio::io::AsyncWriteExt;
use tokio::net::UnixListener;

#[tokio::test]
async fn a_read_cancelled_mid_line_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.sock");
    let listener = UnixListener::bind(&path).unwrap();
    let server = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        for id in 1..=3 {
            let line = format!("{{\"id\":{id},\"ok\":true,\"data\":{{\"n\":{id}}}}}\n");
            let (a, b) = line.split_at(line.len() / 2);
            s.write_all(a.as_bytes()).await.unwrap();
            s.flush().await.unwrap();
            tokio::time::sleep(Duration::from_millis(150)).await;
            s.write_all(b.as_bytes()).await.unwrap();
            s.flush().await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    });
    let mut c = Client::connect(&path).await.unwrap();
    let mut got = Vec::new();
    let mut cancelled = 0;
    while got.len() < 3 {
        match tokio::time::timeout(Duration::from_millis(40), c.read_line()).await {
            Err(_) => cancelled += 1,
            Ok(r) => match r.unwrap() {
                Some(ServerLine::Reply(r)) => got.push(r.into_result().unwrap()["n"].as_u64()),
                other => panic!("unexpected {other:?}"),
            },
        }
    }
    assert_eq!(got, vec![Some(1), Some(2), Some(3)]);
    assert!(
        cancelled >= 3,
        "reads were cancelled mid-line ({cancelled})"
    );
    assert!(c.read_line().await.unwrap().is_none(), "then EOF");
    server.await.unwrap();
}
