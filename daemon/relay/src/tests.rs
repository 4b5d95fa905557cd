use super::*;

fn opts(dir: &Path, names: &[&str]) -> RelayOptions {
    RelayOptions {
        listen: "127.0.0.1:0".parse().unwrap(),
        names: names.iter().map(|s| s.to_string()).collect(),
        cert: CertSource::SelfSigned { dir: dir.into() },
        access: AccessList::Open,
    }
}

#[tokio::test]
async fn a_self_signed_certificate_is_made_once_kept_and_remade_when_the_names_change() {
    let d = tempfile::tempdir().unwrap();
    let r = RunningRelay::start(&opts(d.path(), &["127.0.0.1"]))
        .await
        .unwrap();
    assert!(r.url().starts_with("https://127.0.0.1:"), "{}", r.url());
    assert_eq!(r.cert_file(), Some(d.path().join(CERT_FILE).as_path()));
    let first = std::fs::read(d.path().join(CERT_FILE)).unwrap();
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(d.path().join(KEY_FILE))
        .unwrap()
        .permissions()
        .mode();
    assert_eq!(mode & 0o777, 0o600, "the relay's key is private");
    r.shutdown().await;
    // Same names: the same certificate (peers' pins stay good).
    let r = RunningRelay::start(&opts(d.path(), &["127.0.0.1"]))
        .await
        .unwrap();
    assert_eq!(std::fs::read(d.path().join(CERT_FILE)).unwrap(), first);
    r.shutdown().await;
    // New names: a new certificate.
    let r = RunningRelay::start(&opts(d.path(), &["127.0.0.1", "relay.example"]))
        .await
        .unwrap();
    assert_ne!(std::fs::read(d.path().join(CERT_FILE)).unwrap(), first);
    read_pinned_cert(r.cert_file().unwrap()).unwrap();
    r.shutdown().await;
}

#[tokio::test]
async fn a_relay_without_a_name_or_with_a_bad_one_says_so() {
    let d = tempfile::tempdir().unwrap();
    let mut o = opts(d.path(), &[]);
    o.listen = "0.0.0.0:0".parse().unwrap();
    let e = RunningRelay::start(&o).await.unwrap_err().to_string();
    assert!(e.contains("--name"), "{e}");
    let e = RunningRelay::start(&opts(d.path(), &["bad name/x"]))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad name/x"), "{e}");
    // A specific listen address is its own name.
    let o = opts(d.path(), &[]);
    let r = RunningRelay::start(&o).await.unwrap();
    assert!(r.url().starts_with("https://127.0.0.1:"));
    r.shutdown().await;
}

#[tokio::test]
async fn certificate_files_that_are_missing_or_not_pem_are_named() {
    let d = tempfile::tempdir().unwrap();
    let cert = d.path().join("c.pem");
    let key = d.path().join("k.pem");
    let mut o = opts(d.path(), &["127.0.0.1"]);
    o.cert = CertSource::Files {
        cert: cert.clone(),
        key: key.clone(),
    };
    let e = RunningRelay::start(&o).await.unwrap_err().to_string();
    assert!(e.contains("c.pem"), "{e}");
    std::fs::write(&cert, "not a certificate\n").unwrap();
    let e = RunningRelay::start(&o).await.unwrap_err().to_string();
    assert!(e.contains("c.pem") && e.contains("no CERTIFICATE"), "{e}");
    // A real pair of files (as an ACME client leaves them) works.
    let made = rcgen::generate_simple_self_signed(vec!["127.0.0.1".into()]).unwrap();
    std::fs::write(&cert, made.cert.pem()).unwrap();
    let e = RunningRelay::start(&o).await.unwrap_err().to_string();
    assert!(e.contains("k.pem"), "{e}");
    std::fs::write(&key, made.key_pair.serialize_pem()).unwrap();
    let r = RunningRelay::start(&o).await.unwrap();
    assert_eq!(r.cert_file(), Some(cert.as_path()));
    r.shutdown().await;
    let e = read_pinned_cert(&key).unwrap_err().to_string();
    assert!(e.contains("no certificate to pin"), "{e}");
}
