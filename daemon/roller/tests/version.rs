//! Hello and version check against a hand-written fake firmware on a pty.
use std::time::Duration;
use telextiles_proto::roller::{Command, FrameDecoder, Reply, Version};
use telextiles_roller::{DriverConfig, RollerDriver, RollerEvent};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::{SerialPort, SerialStream};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_firmware_with_another_protocol_is_refused_with_a_clear_error() {
    let (mut master, slave) = SerialStream::pair().unwrap();
    let path = slave.name().unwrap();
    let driver = RollerDriver::start(DriverConfig {
        reconnect_min: Duration::from_millis(20),
        ..DriverConfig::path(&path)
    });
    let mut events = driver.subscribe();
    // Answer the first Hello as a firmware speaking protocol 2.
    let mut dec = FrameDecoder::new();
    let mut buf = [0u8; 64];
    let seq = 'hello: loop {
        let n = tokio::time::timeout(Duration::from_secs(5), master.read(&mut buf))
            .await
            .expect("the driver says Hello")
            .unwrap();
        for f in dec.feed(&buf[..n]).flatten() {
            if let Ok(Command::Hello { protocol }) = Command::from_frame(&f) {
                assert_eq!(protocol, telextiles_proto::roller::PROTOCOL_VERSION);
                break 'hello f.seq;
            }
        }
    };
    let v = Version {
        protocol: 2,
        firmware: [9, 0, 0],
        steps_per_rev: 3200,
        slots: 16,
        watchdog_ms: 2000,
        max_speed: 3200,
        accel: 6400,
    };
    master
        .write_all(Reply::Version(v).encode(seq).as_bytes())
        .await
        .unwrap();
    let msg = loop {
        match tokio::time::timeout(Duration::from_secs(5), events.recv()).await {
            Ok(Ok(RollerEvent::Error { message })) => break message,
            Ok(Ok(_)) => continue,
            other => panic!("no error event: {other:?}"),
        }
    };
    assert!(
        msg.contains("protocol 2")
            && msg.contains("firmware 9.0.0")
            && msg.contains("update the firmware"),
        "{msg}"
    );
    assert!(!driver.state().connected);
    drop(slave);
}
