use super::*;
use clap::{CommandFactory, Parser};
use std::collections::HashMap;

#[derive(Parser)]
struct T {
    #[command(flatten)]
    c: ConfigArgs,
}

fn args(a: &[&str]) -> ConfigArgs {
    T::try_parse_from(std::iter::once("t").chain(a.iter().copied()))
        .unwrap_or_else(|e| panic!("{e}"))
        .c
}

fn env_of(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<OsString> {
    let m: HashMap<String, OsString> = pairs
        .iter()
        .map(|(k, v)| (k.to_string(), OsString::from(v)))
        .collect();
    move |k| m.get(k).cloned()
}

fn base_env(dir: &Path) -> Vec<(String, String)> {
    vec![
        ("HOME".into(), dir.join("home").display().to_string()),
        (
            "XDG_RUNTIME_DIR".into(),
            dir.join("run").display().to_string(),
        ),
    ]
}

/// [`base_env`] with `TELEXTILESD_CONFIG` naming the file `cfg`.
fn file_env(dir: &Path, cfg: &Path) -> Vec<(String, String)> {
    let mut env = base_env(dir);
    env.push(("TELEXTILESD_CONFIG".into(), cfg.display().to_string()));
    env
}

/// An environment as [`resolve`] takes it.
fn borrow(env: &[(String, String)]) -> Vec<(&str, &str)> {
    env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect()
}

fn resolve(a: &[&str], env: &[(&str, &str)]) -> Result<Config, ConfigError> {
    Config::resolve(&args(a), &env_of(env))
}

/// The error with `text` as the configuration file `cfg` (left empty
/// afterwards).
fn file_error(cfg: &Path, env: &[(&str, &str)], text: &str) -> String {
    std::fs::write(cfg, text).unwrap();
    let e = resolve(&[], env).unwrap_err().to_string();
    std::fs::write(cfg, "").unwrap();
    e
}

/// The error with `key = value` added to the environment `env`.
fn var_error(env: &[(&str, &str)], key: &str, value: &str) -> String {
    let mut bad = env.to_vec();
    bad.push((key, value));
    resolve(&[], &bad).unwrap_err().to_string()
}

/// The parser's error for `flags`.
fn flag_error(flags: &[&str]) -> String {
    match T::try_parse_from(std::iter::once("t").chain(flags.iter().copied())) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("{flags:?} was taken"),
    }
}

#[test]
fn private_dirs_are_created_0700_whatever_the_umask() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a").join("state");
    create_private_dir(&d).unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o7777;
    assert_eq!(mode(&d), 0o700);
    assert_eq!(mode(&tmp.path().join("a")), 0o700);
    // Existing directories are left alone.
    std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o1777)).unwrap();
    create_private_dir(&d).unwrap();
    assert_eq!(mode(&d), 0o1777);
}

#[test]
fn defaults_follow_xdg() {
    let c = resolve(&[], &[("HOME", "/h"), ("XDG_RUNTIME_DIR", "/run/user/7")]).unwrap();
    assert_eq!(c.state_dir, PathBuf::from("/h/.local/state/telextiles"));
    assert_eq!(c.data_dir, PathBuf::from("/h/.local/share/telextiles"));
    assert_eq!(c.runtime_dir, PathBuf::from("/run/user/7/telextilesd"));
    assert_eq!(
        c.socket,
        PathBuf::from("/run/user/7/telextilesd/control.sock")
    );
    assert_eq!(
        c.model,
        PathBuf::from("/h/.local/share/telextiles/encoder.onnx")
    );
    assert_eq!(
        c.index,
        PathBuf::from("/h/.local/share/telextiles/index.tlxi")
    );
    assert_eq!(c.sensor, SensorSource::Digit { serial: None });
    assert_eq!(c.roller, RollerSource::Auto);
    assert_eq!(c.listen, DEFAULT_LISTEN.parse().unwrap());
    assert!(c.mdns && !c.map && !c.system, "the map is off by default");
    assert_eq!(c.log, "info");
    assert_eq!(c.config_file, None, "absent default file is fine");
    let spec = c.socket_spec().unwrap();
    assert_eq!(spec.access, telextiles_control::Access::User);
    assert!(spec.manage_dir);

    let c = resolve(&["--system"], &[]).unwrap();
    assert_eq!(c.socket, PathBuf::from("/run/telextilesd/control.sock"));
    assert_eq!(c.state_dir, PathBuf::from("/var/lib/telextilesd"));
    assert_eq!(c.group, "telextiles");

    let err = resolve(&[], &[("HOME", "/h")]).unwrap_err().to_string();
    assert!(err.contains("XDG_RUNTIME_DIR is not set"), "{err}");
    // A runtime dir the user names is not the daemon's to chmod.
    let c = resolve(&["--runtime-dir", "/tmp"], &[("HOME", "/h")]).unwrap();
    assert_eq!(c.socket, PathBuf::from("/tmp/control.sock"));
    assert!(!c.socket_spec().unwrap().manage_dir);
    // An explicit socket needs no runtime dir.
    let c = resolve(&["--socket", "/tmp/x/ctl.sock"], &[("HOME", "/h")]).unwrap();
    assert_eq!(c.socket, PathBuf::from("/tmp/x/ctl.sock"));
}

#[test]
fn precedence_flag_env_file_default() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    std::fs::write(
        &cfg,
        "name = \"from-file\"\nsensor = \"replay:presses\"\nroller = \"sim\"\nlisten = \"127.0.0.1:1000\"\nconnect = [\"aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@a:1\"]\nmap = false\nlog = \"debug\"\nmodel = \"m.onnx\"\n",
    )
    .unwrap();
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);

    // File over defaults; relative paths are relative to the file.
    let c = resolve(&[], &env).unwrap();
    assert_eq!(c.config_file.as_deref(), Some(cfg.as_path()));
    assert_eq!(c.name, "from-file");
    assert_eq!(
        c.sensor,
        SensorSource::Replay {
            dir: dir.path().join("presses")
        }
    );
    assert_eq!(c.roller, RollerSource::Sim);
    assert_eq!(c.listen, "127.0.0.1:1000".parse().unwrap());
    assert_eq!(
        c.connect,
        vec!["aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@a:1".to_string()]
    );
    assert!(!c.map);
    assert_eq!(c.model, dir.path().join("m.onnx"));
    assert_eq!(c.log, "debug");

    // Env over file.
    let mut env2 = env.clone();
    env2.extend([
        ("TELEXTILESD_NAME", "from-env"),
        ("TELEXTILESD_SENSOR", "sim:T012"),
        ("TELEXTILESD_CONNECT", "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@b:2, aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa"),
        ("TELEXTILESD_MAP", "yes"),
        ("RUST_LOG", "warn"),
    ]);
    let c = resolve(&[], &env2).unwrap();
    assert_eq!(c.name, "from-env");
    assert_eq!(
        c.sensor,
        SensorSource::Sim {
            textile: Some("T012".into())
        }
    );
    assert_eq!(
        c.connect,
        vec![
            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@b:2".to_string(),
            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa".to_string()
        ]
    );
    assert!(c.map);
    assert_eq!(c.log, "warn", "RUST_LOG beats the file");
    assert_eq!(
        c.roller,
        RollerSource::Sim,
        "untouched keys still come from the file"
    );

    // Flags over env.
    let c = resolve(
        &[
            "--name",
            "from-flag",
            "--sensor",
            "digit:D20001",
            "--connect",
            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@d:4",
            "--map=false",
            "--log",
            "trace",
        ],
        &env2,
    )
    .unwrap();
    assert_eq!(c.name, "from-flag");
    assert_eq!(
        c.sensor,
        SensorSource::Digit {
            serial: Some("D20001".into())
        }
    );
    assert_eq!(
        c.connect,
        vec!["aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@d:4".to_string()]
    );
    assert!(!c.map);
    assert_eq!(c.log, "trace");
    env2.push(("TELEXTILESD_LOG", "error"));
    assert_eq!(
        resolve(&[], &env2).unwrap().log,
        "error",
        "TELEXTILESD_LOG beats RUST_LOG"
    );

    // An explicit --config that does not exist is an error.
    let err = resolve(&["--config", "/nonexistent/t.toml"], &env)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("cannot read config file /nonexistent/t.toml"),
        "{err}"
    );
}

#[test]
fn bad_values_name_their_source() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);

    std::fs::write(&cfg, "name = \"x\"\nsnesor = \"sim\"\n").unwrap();
    let err = resolve(&[], &env).unwrap_err().to_string();
    assert!(err.contains("unknown field `snesor`"), "{err}");
    assert!(err.contains(&cfg.display().to_string()), "{err}");

    std::fs::write(&cfg, "sensor = \"webcam\"\n").unwrap();
    let err = resolve(&[], &env).unwrap_err().to_string();
    assert!(
        err.contains("key `sensor`") && err.contains("unknown sensor source `webcam`"),
        "{err}"
    );

    std::fs::write(&cfg, "listen = 47800\n").unwrap();
    let err = resolve(&[], &env).unwrap_err().to_string();
    assert!(err.contains("listen"), "{err}");

    std::fs::write(&cfg, "").unwrap();
    let mut e2 = env.clone();
    e2.push(("TELEXTILESD_LISTEN", "nope"));
    let err = resolve(&[], &e2).unwrap_err().to_string();
    assert!(err.contains("TELEXTILESD_LISTEN=\"nope\""), "{err}");
    let mut e3 = env.clone();
    e3.push(("TELEXTILESD_MAP", "maybe"));
    assert!(resolve(&[], &e3)
        .unwrap_err()
        .to_string()
        .contains("TELEXTILESD_MAP"));
    let mut e4 = env.clone();
    e4.push(("TELEXTILESD_CONNECT", "hostonly"));
    assert!(resolve(&[], &e4)
        .unwrap_err()
        .to_string()
        .contains("`connect`"));

    let mut c = resolve(&[], &env).unwrap();
    assert!(c.env_filter().is_ok());
    c.log = "info,telextiles_link=debug".into();
    assert!(c.env_filter().is_ok());
    c.log = "info,=[".into();
    let err = c.env_filter().unwrap_err().to_string();
    assert!(err.contains("invalid log filter `info,=[`"), "{err}");

    assert!(T::try_parse_from(["t", "--roller", "wheel"]).is_err());
    assert!("replay:"
        .parse::<SensorSource>()
        .unwrap_err()
        .contains("replay:<dir>"));
    assert_eq!(
        "/dev/ttyUSB0".parse::<RollerSource>().unwrap(),
        RollerSource::Path("/dev/ttyUSB0".into())
    );
}

#[test]
fn every_key_is_a_file_key_a_flag_and_an_env_var() {
    let cmd = T::command();
    let longs: Vec<String> = cmd
        .get_arguments()
        .filter_map(|a| a.get_long().map(str::to_string))
        .collect();
    for key in KEYS {
        let flag = key.replace('_', "-");
        assert!(longs.contains(&flag), "no flag --{flag}");
        let help = cmd
            .get_arguments()
            .find(|a| a.get_long() == Some(flag.as_str()))
            .and_then(|a| a.get_help())
            .map(|h| h.to_string())
            .unwrap_or_default();
        let var = format!("{ENV_PREFIX}{}", key.to_uppercase());
        assert!(help.contains(&var), "--{flag} help does not mention {var}");
        // The file accepts the key...
        let line = format!("{key} = {}\n", sample_toml(key));
        toml::from_str::<FileConfig>(&line).unwrap_or_else(|e| panic!("{line}: {e}"));
    }
    // ...and every flag but --config is a key.
    assert_eq!(longs.len(), KEYS.len() + 1);
    // The env var is honoured for each key (value differs from the default).
    for key in KEYS {
        let var = format!("{ENV_PREFIX}{}", key.to_uppercase());
        let val = sample_env(key);
        // A scale is the scale of a profile: given with one.
        let mut base = vec![("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")];
        if *key == "sensor_mm_per_px" {
            base.push(("TELEXTILESD_SENSOR_PROFILE", "gelsight-mini"));
        }
        // A relay's certificate is the certificate of a relay: given with one.
        if *key == "relay_cert" {
            base.push(("TELEXTILESD_RELAY", "https://relay.example:443"));
        }
        let with: Vec<(&str, &str)> = base.iter().copied().chain([(var.as_str(), val)]).collect();
        let c = resolve(&[], &with).unwrap();
        let d = resolve(&[], &base).unwrap();
        assert_ne!(c, d, "{var} had no effect");
    }
    // Round trip through to_toml.
    let c = resolve(
        &[
            "--connect",
            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@a:1",
            "--sensor",
            "replay:/d",
            "--replay-fps",
            "29.97",
            "--sensor-profile",
            "uvc",
            "--sensor-mm-per-px",
            "0.03",
            "--sensor-mode",
            "1280x720@30",
        ],
        &[("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")],
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.toml");
    std::fs::write(&p, c.to_toml()).unwrap();
    let again = resolve(
        &["--config", p.to_str().unwrap()],
        &[("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")],
    )
    .unwrap();
    assert_eq!(
        Config {
            config_file: None,
            ..again
        },
        c
    );
    // With a relay and its certificate too.
    let c = resolve(
        &[
            "--relay",
            "https://relay.example:443",
            "--relay-cert",
            "/etc/relay.pem",
        ],
        &[("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")],
    )
    .unwrap();
    std::fs::write(&p, c.to_toml()).unwrap();
    let again = resolve(
        &["--config", p.to_str().unwrap()],
        &[("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")],
    )
    .unwrap();
    assert_eq!(
        Config {
            config_file: None,
            ..again
        },
        c
    );
}

#[test]
fn the_contact_detector_is_set_from_flag_env_or_file_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);
    // Unset: the shipped detector.
    std::fs::write(&cfg, "").unwrap();
    let c = resolve(&[], &env).unwrap();
    assert_eq!((c.contact_enter, c.contact_frames), (0.35, 2));
    assert_eq!(c.contact_tile, 0);
    assert_eq!(
        c.contact(),
        telextiles_sensing::contact::ContactConfig::default()
    );
    // The file, then the variable, then the flag.
    std::fs::write(&cfg, "contact_enter = 0.5\ncontact_frames = 3\n").unwrap();
    let c = resolve(&[], &env).unwrap();
    assert_eq!((c.contact_enter, c.contact_frames), (0.5, 3));
    assert_eq!(c.contact().enter, 0.5);
    assert_eq!(c.contact().min_enter_frames, 3);
    let mut with_var = env.clone();
    with_var.push(("TELEXTILESD_CONTACT_ENTER", "0.6"));
    assert_eq!(resolve(&[], &with_var).unwrap().contact_enter, 0.6);
    let c = resolve(
        &["--contact-enter", "0.7", "--contact-frames", "4"],
        &with_var,
    )
    .unwrap();
    assert_eq!((c.contact_enter, c.contact_frames), (0.7, 4));
    // A threshold under the shipped exit (0.2) brings the exit down.
    let c = resolve(&["--contact-enter", "0.1"], &env)
        .unwrap()
        .contact();
    assert!(c.exit < c.enter && c.exit > 0.0, "{c:?}");
    // Out of range anywhere: a clear error naming where.
    let e = file_error(&cfg, &env, "contact_enter = 0\n");
    assert!(
        e.contains("contact_enter") && e.contains("out of range"),
        "{e}"
    );
    let e = file_error(&cfg, &env, "contact_frames = 0\n");
    assert!(
        e.contains("contact_frames") && e.contains("out of range"),
        "{e}"
    );
    // The tile: the file, then the variable, then the flag; 0 to 80.
    std::fs::write(&cfg, "contact_tile = 10\n").unwrap();
    assert_eq!(resolve(&[], &env).unwrap().contact().tile, 10);
    let mut tile_var = env.clone();
    tile_var.push(("TELEXTILESD_CONTACT_TILE", "20"));
    assert_eq!(resolve(&[], &tile_var).unwrap().contact_tile, 20);
    assert_eq!(
        resolve(&["--contact-tile", "0"], &tile_var)
            .unwrap()
            .contact()
            .tile,
        0
    );
    let e = file_error(&cfg, &env, "contact_tile = 81\n");
    assert!(
        e.contains("contact_tile") && e.contains("out of range"),
        "{e}"
    );
    let e = var_error(&env, "TELEXTILESD_CONTACT_ENTER", "high");
    assert!(
        e.contains("TELEXTILESD_CONTACT_ENTER") && e.contains("not a number"),
        "{e}"
    );
    let e = flag_error(&["--contact-frames", "31"]);
    assert!(e.contains("out of range"), "{e}");
    // The offline tools' flags make the same detector.
    let a = ContactArgs {
        contact_enter: Some(0.5),
        contact_frames: Some(3),
        contact_tile: Some(10),
    };
    let mut c = resolve(&[], &env).unwrap();
    (c.contact_enter, c.contact_frames, c.contact_tile) = (0.5, 3, 10);
    assert_eq!(a.contact().unwrap(), c.contact());
    assert_eq!(c.contact().tile, 10);
    assert_eq!(
        ContactArgs::default().contact().unwrap(),
        telextiles_sensing::contact::ContactConfig::default()
    );
}

#[test]
fn the_decision_speed_is_set_from_flag_env_or_file_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);
    // Unset: the shipped decider, the run not encoded.
    std::fs::write(&cfg, "").unwrap();
    let c = resolve(&[], &env).unwrap();
    assert_eq!(
        c.decide(),
        telextiles_sensing::decide::DecideConfig::default()
    );
    assert!(!c.encode_run);
    // The file, then the variable, then the flag.
    std::fs::write(&cfg, "commit_margin = 0.02\nencode_run = true\n").unwrap();
    let c = resolve(&[], &env).unwrap();
    assert_eq!((c.decide().commit_margin, c.encode_run), (0.02, true));
    // Only the commit margin changes in the decider.
    assert_eq!(
        telextiles_sensing::decide::DecideConfig {
            commit_margin: telextiles_sensing::decide::DecideConfig::default().commit_margin,
            ..c.decide()
        },
        telextiles_sensing::decide::DecideConfig::default()
    );
    let mut with_var = env.clone();
    with_var.push(("TELEXTILESD_COMMIT_MARGIN", "0.04"));
    with_var.push(("TELEXTILESD_ENCODE_RUN", "false"));
    let c = resolve(&[], &with_var).unwrap();
    assert_eq!((c.commit_margin, c.encode_run), (0.04, false));
    let c = resolve(&["--commit-margin", "0.16", "--encode-run"], &with_var).unwrap();
    assert_eq!((c.commit_margin, c.encode_run), (0.16, true));
    // `classify` given the same values replays with this daemon's
    // decider and front end.
    let offline = DecisionArgs {
        commit_margin: Some(c.commit_margin),
        encode_run: Some(c.encode_run),
    }
    .pipeline(c.contact());
    assert_eq!(
        (offline.contact, offline.decide, offline.encode_run),
        (c.contact(), c.decide(), c.encode_run)
    );
    // Out of range anywhere: a clear error naming where.
    let e = file_error(&cfg, &env, "commit_margin = 2.5\n");
    assert!(
        e.contains("commit_margin") && e.contains("out of range"),
        "{e}"
    );
    let e = var_error(&env, "TELEXTILESD_COMMIT_MARGIN", "-0.1");
    assert!(
        e.contains("TELEXTILESD_COMMIT_MARGIN") && e.contains("out of range"),
        "{e}"
    );
    let e = flag_error(&["--commit-margin", "NaN"]);
    assert!(e.contains("out of range"), "{e}");
    assert!(
        var_error(&env, "TELEXTILESD_ENCODE_RUN", "sometimes").contains("TELEXTILESD_ENCODE_RUN")
    );
}

#[test]
fn replay_fps_is_a_positive_rate_from_flag_env_or_file() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);
    // A TOML integer or float; unset, None (by the frames' size).
    for (line, want) in [
        ("replay_fps = 30", Some(30.0)),
        ("replay_fps = 12.5", Some(12.5)),
        ("", None),
    ] {
        std::fs::write(&cfg, format!("sensor = \"replay:data\"\n{line}\n")).unwrap();
        assert_eq!(resolve(&[], &env).unwrap().replay_fps, want, "{line}");
    }
    // The flag wins over the variable, which wins over the file.
    std::fs::write(&cfg, "replay_fps = 30\n").unwrap();
    let mut with_var = env.clone();
    with_var.push(("TELEXTILESD_REPLAY_FPS", "15"));
    assert_eq!(resolve(&[], &with_var).unwrap().replay_fps, Some(15.0));
    assert_eq!(
        resolve(&["--replay-fps", "24"], &with_var)
            .unwrap()
            .replay_fps,
        Some(24.0)
    );
    // Out of range anywhere: a clear error naming where.
    let e = file_error(&cfg, &env, "replay_fps = 0\n");
    assert!(
        e.contains("replay_fps") && e.contains("out of range"),
        "{e}"
    );
    let e = var_error(&env, "TELEXTILESD_REPLAY_FPS", "fast");
    assert!(
        e.contains("TELEXTILESD_REPLAY_FPS") && e.contains("not a frame rate"),
        "{e}"
    );
    let e = flag_error(&["--replay-fps", "0"]);
    assert!(e.contains("out of range"), "{e}");
}

#[test]
fn references_are_listed_and_paths_in_the_file_are_relative_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    // A file whose name holds `=` is a path, as on the command line.
    std::fs::write(dir.path().join("a=b.png"), b"").unwrap();
    std::fs::write(
        &cfg,
        "sensor = \"replay:data\"\nreference = [\"ref.png\", \"D20001=refs/d1.png\", \"a=b.png\", \"D2=/abs/d2.png\"]\n",
    )
    .unwrap();
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);
    let d = dir.path().display();
    let c = resolve(&[], &env).unwrap();
    assert_eq!(
        c.reference,
        vec![
            format!("{d}/ref.png"),
            format!("D20001={d}/refs/d1.png"),
            format!("{d}/a=b.png"),
            "D2=/abs/d2.png".to_string(),
        ]
    );
    // The env replaces the file's list (comma-separated), a flag the env's.
    let mut env2 = env.clone();
    env2.push(("TELEXTILESD_REFERENCE", "D1=x.png, y.png"));
    assert_eq!(
        resolve(&[], &env2).unwrap().reference,
        vec!["D1=x.png".to_string(), "y.png".to_string()]
    );
    let c = resolve(&["--reference", "z.png", "--reference", "D9=w.png"], &env2).unwrap();
    assert_eq!(
        c.reference,
        vec!["z.png".to_string(), "D9=w.png".to_string()]
    );
    // None given: empty.
    std::fs::write(&cfg, "").unwrap();
    assert!(resolve(&[], &env).unwrap().reference.is_empty());
}

fn sample_toml(key: &str) -> &'static str {
    match key {
        "system" | "mdns" | "map" => "true",
        "connect" => "[\"aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@x:1\"]",
        "mdns_allow" | "mdns_deny" => "[\"x:1\"]",
        "reference" => "[\"/x.png\"]",
        "replay_fps" => "30",
        "contact_enter" => "0.5",
        "contact_frames" => "3",
        "contact_tile" => "10",
        "commit_margin" => "0.02",
        "encode_run" => "true",
        "motion" => "\"lead:30\"",
        "listen" | "map_bind" => "\"127.0.0.1:9\"",
        "sensor" => "\"sim\"",
        "sensor_profile" => "\"gelsight-mini\"",
        "sensor_mm_per_px" => "0.03",
        "sensor_mode" => "\"640x480@30\"",
        "roller" => "\"sim\"",
        "relay" => "\"https://relay.example:443\"",
        _ => "\"/x\"",
    }
}

fn sample_env(key: &str) -> &'static str {
    match key {
        "system" => "1",
        "mdns" => "false",
        "map" => "true",
        "connect" => "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa@x:1",
        "mdns_allow" | "mdns_deny" => "x:1",
        "reference" => "D1=/x.png",
        "replay_fps" => "29.97",
        "contact_enter" => "0.45",
        "contact_frames" => "4",
        "contact_tile" => "20",
        "commit_margin" => "0.04",
        "encode_run" => "yes",
        "motion" => "confident",
        "listen" | "map_bind" => "127.0.0.1:9",
        "sensor" => "sim",
        "sensor_profile" => "gelsight-mini",
        "sensor_mm_per_px" => "0.03",
        "sensor_mode" => "640x480@30",
        "roller" => "sim",
        "group" => "wheel",
        "log" => "debug",
        "relay" => "https://relay.example:443",
        _ => "/x",
    }
}

#[test]
fn sensor_settings_are_checked_together() {
    let env = [("HOME", "/h"), ("XDG_RUNTIME_DIR", "/r")];
    let e = resolve(&["--sensor-mm-per-px", "0.03"], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("without sensor_profile"), "{e}");
    let e = resolve(&["--sensor-profile", "uvc"], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("uvc needs sensor_mm_per_px"), "{e}");
    let c = resolve(
        &[
            "--sensor",
            "camera:/dev/video2",
            "--sensor-profile",
            "gelsight-mini",
            "--sensor-mode",
            "640x480@25",
        ],
        &env,
    )
    .unwrap();
    assert_eq!(
        c.sensor,
        SensorSource::Camera {
            select: Some("/dev/video2".into())
        }
    );
    assert_eq!(c.sensor.to_string(), "camera:/dev/video2");
    assert_eq!(c.sensor_given().unwrap().profile.name, "gelsight-mini");
    assert_eq!(c.sensor_mode.unwrap().to_string(), "640x480@25");
    // In the file, as the flags.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.toml");
    std::fs::write(&p, "sensor_profile = \"uvc\"\nsensor_mm_per_px = 0.02\n").unwrap();
    let c = resolve(&["--config", p.to_str().unwrap()], &env).unwrap();
    assert_eq!(c.sensor_given().unwrap().mm_per_px, Some(0.02));
    std::fs::write(&p, "sensor_profile = \"gelsite\"\n").unwrap();
    let e = resolve(&["--config", p.to_str().unwrap()], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("digit, gelsight-mini, uvc"), "{e}");
    std::fs::write(&p, "sensor_profile = \"uvc\"\nsensor_mm_per_px = 5\n").unwrap();
    let e = resolve(&["--config", p.to_str().unwrap()], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("out of range"), "{e}");
    std::fs::write(&p, "sensor_mode = \"640x480\"\n").unwrap();
    let e = resolve(&["--config", p.to_str().unwrap()], &env)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("sensor_mode") && e.contains("WIDTHxHEIGHT@FPS"),
        "{e}"
    );
}

#[test]
fn a_peer_to_connect_to_is_named_by_its_key() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("t.toml");
    std::fs::write(&cfg, "").unwrap();
    let owned = file_env(dir.path(), &cfg);
    let env = borrow(&owned);
    let key = "ab".repeat(32);

    // An address alone is refused with the form that works.
    let e = resolve(&["--connect", "10.0.0.2:47800"], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("has no device key"), "{e}");
    assert!(e.contains("KEY@10.0.0.2:47800"), "{e}");

    // A key that is not 32 bytes of hex is refused.
    let e = resolve(&["--connect", "abcd@10.0.0.2:47800"], &env)
        .unwrap_err()
        .to_string();
    assert!(e.contains("`connect`"), "{e}");

    // KEY@HOST:PORT and KEY alone (through a relay) are taken.
    let both = format!("{key}@10.0.0.2:47800,{key}");
    let c = resolve(&["--connect", &both], &env).unwrap();
    assert_eq!(
        c.connect,
        vec![format!("{key}@10.0.0.2:47800"), key.clone()]
    );

    // A key with a bad address is refused.
    let bad = format!("{key}@nohost");
    assert!(resolve(&["--connect", &bad], &env).is_err());
}
