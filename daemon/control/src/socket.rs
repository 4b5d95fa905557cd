//! Where the control socket lives, who may open it, and how it is bound:
//! private directory, stale-socket replacement, refusal when a live daemon
//! already owns it, unlink on exit.

use std::io;
use std::os::unix::fs::{DirBuilderExt, FileTypeExt, MetadataExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};

/// Socket file name inside the runtime directory.
pub const SOCKET_NAME: &str = "control.sock";
/// Runtime directory name under `$XDG_RUNTIME_DIR`.
pub const USER_DIR_NAME: &str = "telextilesd";
/// Runtime directory in system-wide mode.
pub const SYSTEM_DIR: &str = "/run/telextilesd";
/// Default group allowed to use the system-wide socket.
pub const DEFAULT_GROUP: &str = "telextiles";

/// Who may connect.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Only the daemon's user: directory 0700, socket 0600.
    User,
    /// The daemon's user and a group: directory 0750 and socket 0660, both
    /// chowned to the group (system-wide mode).
    Group { gid: u32 },
}

impl Access {
    pub fn dir_mode(self) -> u32 {
        match self {
            Access::User => 0o700,
            Access::Group { .. } => 0o750,
        }
    }
    pub fn socket_mode(self) -> u32 {
        match self {
            Access::User => 0o600,
            Access::Group { .. } => 0o660,
        }
    }
}

/// The socket to bind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SocketSpec {
    pub path: PathBuf,
    pub access: Access,
    /// Whether the parent directory is ours to create, check and chmod
    /// (true for the default locations; false for a user-given path whose
    /// directory may be shared, e.g. /tmp — it is still created if missing).
    pub manage_dir: bool,
}

impl SocketSpec {
    /// `$XDG_RUNTIME_DIR/telextilesd/control.sock`, user-only.
    pub fn user_default() -> Result<Self, BindError> {
        let rt = std::env::var_os("XDG_RUNTIME_DIR")
            .filter(|v| !v.is_empty())
            .ok_or(BindError::NoRuntimeDir)?;
        Ok(Self::in_dir(
            &PathBuf::from(rt).join(USER_DIR_NAME),
            Access::User,
        ))
    }

    /// `/run/telextilesd/control.sock`, shared with `gid`.
    pub fn system(gid: u32) -> Self {
        Self::in_dir(Path::new(SYSTEM_DIR), Access::Group { gid })
    }

    /// `<dir>/control.sock` with `dir` managed by us.
    pub fn in_dir(dir: &Path, access: Access) -> Self {
        SocketSpec {
            path: dir.join(SOCKET_NAME),
            access,
            manage_dir: true,
        }
    }
}

/// Why the socket could not be bound.
#[derive(Debug, thiserror::Error)]
pub enum BindError {
    #[error("XDG_RUNTIME_DIR is not set, so there is no per-user runtime directory for the control socket; set it (systemd and login sessions do), or pass --socket PATH / --runtime-dir DIR, or use --system")]
    NoRuntimeDir,
    #[error("another telextilesd is already running and answering on {path}; stop it first (`telextilesd ctl shutdown`) or use another --socket")]
    AlreadyRunning { path: PathBuf },
    #[error("{path} exists and is not a socket; refusing to replace it")]
    NotASocket { path: PathBuf },
    #[error("control socket directory {path} is owned by uid {owner}, not by this user (uid {us}); refusing to use it")]
    ForeignDirectory { path: PathBuf, owner: u32, us: u32 },
    #[error("unknown group `{0}` (not a number and not in /etc/group)")]
    UnknownGroup(String),
    #[error("control socket path has no parent directory: {0}")]
    NoParent(PathBuf),
    #[error("cannot {what} {path}: {source}")]
    Io {
        what: &'static str,
        path: PathBuf,
        #[source]
        source: io::Error,
    },
}

fn io_err<'a>(what: &'static str, path: &'a Path) -> impl FnOnce(io::Error) -> BindError + 'a {
    move |source| BindError::Io {
        what,
        path: path.to_path_buf(),
        source,
    }
}

/// Effective uid of this process (owner of `/proc/self`).
pub fn current_uid() -> io::Result<u32> {
    Ok(std::fs::metadata("/proc/self")?.uid())
}

/// A numeric gid or a group name looked up in `/etc/group`.
pub fn resolve_group(group: &str) -> Result<u32, BindError> {
    if let Ok(gid) = group.parse::<u32>() {
        return Ok(gid);
    }
    let text =
        std::fs::read_to_string("/etc/group").map_err(io_err("read", Path::new("/etc/group")))?;
    parse_group_file(&text, group).ok_or_else(|| BindError::UnknownGroup(group.to_string()))
}

/// Looks a group name up in the text of an `/etc/group` file.
pub fn parse_group_file(text: &str, group: &str) -> Option<u32> {
    text.lines().find_map(|l| {
        let mut f = l.split(':');
        let name = f.next()?;
        let _pw = f.next()?;
        let gid = f.next()?;
        (name == group).then(|| gid.trim().parse().ok()).flatten()
    })
}

/// A bound socket file; unlinked on drop if it is still the one we bound.
#[derive(Debug)]
pub struct BoundSocket {
    path: PathBuf,
    dev: u64,
    ino: u64,
}

impl BoundSocket {
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for BoundSocket {
    fn drop(&mut self) {
        if let Ok(m) = std::fs::symlink_metadata(&self.path) {
            if m.dev() == self.dev && m.ino() == self.ino {
                let _ = std::fs::remove_file(&self.path);
            }
        }
    }
}

/// What happened to a socket file found at the path before binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Previous {
    None,
    /// A socket nobody answered on was removed.
    StaleRemoved,
}

/// Creates/checks the directory, replaces a stale socket, refuses a live
/// one, binds, and sets the socket's mode (and group).
pub fn bind(spec: &SocketSpec) -> Result<(UnixListener, BoundSocket, Previous), BindError> {
    let path = &spec.path;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .ok_or_else(|| BindError::NoParent(path.clone()))?;
    prepare_dir(dir, spec)?;

    let mut previous = Previous::None;
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_socket() => match UnixStream::connect(path) {
            Ok(_) => return Err(BindError::AlreadyRunning { path: path.clone() }),
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                std::fs::remove_file(path).map_err(io_err("remove stale socket", path))?;
                previous = Previous::StaleRemoved;
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(io_err("probe existing socket", path)(e)),
        },
        Ok(_) => return Err(BindError::NotASocket { path: path.clone() }),
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(io_err("inspect", path)(e)),
    }

    let listener = bind_with_mode(path, dir, spec.access)?;
    let meta = std::fs::symlink_metadata(path).map_err(io_err("inspect", path))?;
    let bound = BoundSocket {
        path: path.clone(),
        dev: meta.dev(),
        ino: meta.ino(),
    };
    listener
        .set_nonblocking(true)
        .map_err(io_err("configure", path))?;
    Ok((listener, bound, previous))
}

/// Binds the socket so that it appears at `path` already with its final
/// mode (and group): it is bound inside a fresh private (0700) directory
/// next to `path`, given its mode there, where nobody else can reach it,
/// and then hard-linked into place (`link` fails instead of replacing a
/// socket another daemon bound meanwhile). Nothing depends on the umask
/// and there is no window in which the socket is open to others.
fn bind_with_mode(path: &Path, dir: &Path, access: Access) -> Result<UnixListener, BindError> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let private = dir.join(format!(".{SOCKET_NAME}.{}.{stamp}", std::process::id()));
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&private)
        .map_err(io_err("create directory", &private))?;
    let tmp = private.join("s");
    let result = (|| {
        let listener = UnixListener::bind(&tmp).map_err(io_err("bind control socket", path))?;
        std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(access.socket_mode()))
            .map_err(io_err("set permissions of", &tmp))?;
        if let Access::Group { gid } = access {
            std::os::unix::fs::chown(&tmp, None, Some(gid))
                .map_err(io_err("chown (group) of", &tmp))?;
        }
        std::fs::hard_link(&tmp, path).map_err(|e| {
            if e.kind() == io::ErrorKind::AlreadyExists {
                BindError::AlreadyRunning {
                    path: path.to_path_buf(),
                }
            } else {
                io_err("bind control socket", path)(e)
            }
        })?;
        Ok(listener)
    })();
    let _ = std::fs::remove_file(&tmp);
    let _ = std::fs::remove_dir(&private);
    result
}

fn prepare_dir(dir: &Path, spec: &SocketSpec) -> Result<(), BindError> {
    let mode = spec.access.dir_mode();
    let existed = dir.exists();
    if !existed {
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(mode)
            .create(dir)
            .map_err(io_err("create directory", dir))?;
    }
    if !spec.manage_dir && existed {
        return Ok(());
    }
    let meta = std::fs::metadata(dir).map_err(io_err("inspect", dir))?;
    let us = current_uid().map_err(io_err("read uid from", Path::new("/proc/self")))?;
    if meta.uid() != us {
        return Err(BindError::ForeignDirectory {
            path: dir.to_path_buf(),
            owner: meta.uid(),
            us,
        });
    }
    if meta.mode() & 0o7777 != mode {
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(mode))
            .map_err(io_err("set permissions of", dir))?;
    }
    if let Access::Group { gid } = spec.access {
        if meta.gid() != gid {
            std::os::unix::fs::chown(dir, None, Some(gid))
                .map_err(io_err("chown (group) of", dir))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The socket must appear at its path with its final mode: a watcher
    /// polling the path from the moment `bind` starts never sees another
    /// mode (the old bind-then-chmod exposed a umask-dependent mode, 0755
    /// under umask 022, between the two calls).
    #[test]
    fn socket_appears_with_its_final_mode() {
        use std::sync::atomic::{AtomicBool, Ordering};
        use std::sync::Arc;
        let tmp = std::env::temp_dir().join(format!("txc-mode-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir(&tmp).unwrap();
        let spec = SocketSpec {
            path: tmp.join(SOCKET_NAME),
            access: Access::User,
            manage_dir: false,
        };
        for round in 0..100 {
            let done = Arc::new(AtomicBool::new(false));
            let (d, p) = (done.clone(), spec.path.clone());
            let watcher = std::thread::spawn(move || loop {
                let finished = d.load(Ordering::SeqCst);
                if let Ok(m) = std::fs::symlink_metadata(&p) {
                    return Some(m.mode() & 0o7777);
                }
                if finished {
                    return None;
                }
            });
            let (listener, bound, _) = bind(&spec).unwrap();
            done.store(true, Ordering::SeqCst);
            let first = watcher.join().unwrap();
            assert_eq!(first, Some(0o600), "round {round}: first mode seen");
            drop(listener);
            drop(bound);
            assert!(!spec.path.exists());
        }
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert!(left.is_empty(), "no temporaries left: {left:?}");
        std::fs::remove_dir_all(&tmp).unwrap();
    }

    #[test]
    fn group_file_lookup() {
        let text = "root:x:0:\nwheel:x:10:alice\ntelextiles:x:991:bob,carol\nbroken\n";
        assert_eq!(parse_group_file(text, "telextiles"), Some(991));
        assert_eq!(parse_group_file(text, "wheel"), Some(10));
        assert_eq!(parse_group_file(text, "nope"), None);
        assert_eq!(parse_group_file(text, "broken"), None);
        assert_eq!(resolve_group("1234").unwrap(), 1234);
        assert!(matches!(
            resolve_group("no-such-group-telextiles-xyz"),
            Err(BindError::UnknownGroup(_))
        ));
    }
}
