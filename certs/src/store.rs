//! Files on disk: the data directory, atomic private writes, bounded reads,
//! and the error type for everything stored.
use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Name of the directory under the XDG data home.
pub const APP_DIR: &str = "telextiles";
/// Largest file this crate reads (identity or trust store).
pub const MAX_FILE_BYTES: u64 = 4 << 20;

/// An error reading or writing the identity or the trust store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// An operating-system error on a path.
    #[error("cannot {action} {}: {error}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        /// The OS error (part of the message, so not repeated as a source).
        error: io::Error,
    },
    /// The file exists but its content is unusable.
    #[error("{} is corrupt: {reason}. {hint}", path.display())]
    Corrupt {
        path: PathBuf,
        reason: String,
        hint: &'static str,
    },
    /// No data directory could be determined from the environment.
    #[error(
        "cannot find a data directory: neither XDG_DATA_HOME nor HOME is set (pass --data-dir)"
    )]
    NoDataDir,
    /// The identity does not exist yet (only from `Identity::load`).
    #[error("no device identity in {} yet (it is made on the first run of `telextilesd`)", dir.display())]
    NoIdentity { dir: PathBuf },
    /// Key generation or certificate creation failed.
    #[error("cannot create a device identity: {0}")]
    Generate(String),
}

impl StoreError {
    pub(crate) fn io(action: &'static str, path: &Path, source: io::Error) -> StoreError {
        StoreError::Io {
            action,
            path: path.to_path_buf(),
            error: source,
        }
    }
}

/// The default data directory: `$XDG_DATA_HOME/telextiles` when
/// `XDG_DATA_HOME` is set to an absolute path, else
/// `$HOME/.local/share/telextiles`. Reads the environment only; creates
/// nothing. (`telextilesd` itself passes its configured state directory,
/// `$XDG_STATE_HOME/telextiles` by default, to every function here.)
pub fn default_data_dir() -> Result<PathBuf, StoreError> {
    data_dir_from(
        std::env::var_os("XDG_DATA_HOME").map(PathBuf::from),
        std::env::var_os("HOME").map(PathBuf::from),
    )
}

/// [`default_data_dir`] with the environment passed in (for tests).
pub fn data_dir_from(
    xdg_data_home: Option<PathBuf>,
    home: Option<PathBuf>,
) -> Result<PathBuf, StoreError> {
    if let Some(x) = xdg_data_home.filter(|p| p.is_absolute()) {
        return Ok(x.join(APP_DIR));
    }
    match home.filter(|p| !p.as_os_str().is_empty()) {
        Some(h) => Ok(h.join(".local").join("share").join(APP_DIR)),
        None => Err(StoreError::NoDataDir),
    }
}

/// Creates `dir` (and parents) if missing; a newly created leaf gets 0700.
pub(crate) fn ensure_dir(dir: &Path) -> Result<(), StoreError> {
    if dir.is_dir() {
        return Ok(());
    }
    let mut b = fs::DirBuilder::new();
    b.recursive(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::DirBuilderExt;
        b.mode(0o700);
    }
    b.create(dir)
        .map_err(|e| StoreError::io("create directory", dir, e))
}

/// Name of the lock file in the data directory.
pub const LOCK_FILE: &str = ".lock";

/// An exclusive advisory lock (`flock`) on `<dir>/.lock`, held until
/// dropped. Serialises changes to the identity and trust store between
/// processes (the daemon pairing while `telextilesd unpair` runs). Do not
/// take it twice in one thread: a second lock on a new descriptor waits
/// for the first.
#[derive(Debug)]
pub struct DirLock {
    _file: File,
}

impl DirLock {
    /// Creates the directory if needed and waits for the lock.
    pub fn acquire(dir: &Path) -> Result<DirLock, StoreError> {
        ensure_dir(dir)?;
        let path = dir.join(LOCK_FILE);
        let mut opts = OpenOptions::new();
        opts.read(true).write(true).create(true).truncate(false);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            opts.mode(0o600);
        }
        let file = opts
            .open(&path)
            .map_err(|e| StoreError::io("open lock file", &path, e))?;
        #[cfg(unix)]
        rustix::fs::flock(&file, rustix::fs::FlockOperation::LockExclusive)
            .map_err(|e| StoreError::io("lock", &path, e.into()))?;
        Ok(DirLock { _file: file })
    }
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `data` to `path` so that readers and crashes see either the old
/// file or the complete new one: a temporary file in the same directory
/// (mode 0600), fsync, rename over `path`, fsync of the directory.
pub fn write_atomic(path: &Path, data: &[u8]) -> Result<(), StoreError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    ensure_dir(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "file".into());
    let tmp = dir.join(format!(
        ".{name}.tmp.{}.{}",
        std::process::id(),
        TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let mut opts = OpenOptions::new();
        opts.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            opts.mode(0o600);
        }
        let mut f = opts
            .open(&tmp)
            .map_err(|e| StoreError::io("create", &tmp, e))?;
        f.write_all(data)
            .map_err(|e| StoreError::io("write", &tmp, e))?;
        f.sync_all().map_err(|e| StoreError::io("sync", &tmp, e))?;
        drop(f);
        fs::rename(&tmp, path).map_err(|e| StoreError::io("replace", path, e))?;
        // Make the rename itself durable.
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Reads a whole file of at most [`MAX_FILE_BYTES`]; `Ok(None)` if it does
/// not exist.
pub(crate) fn read_bounded(path: &Path) -> Result<Option<Vec<u8>>, StoreError> {
    let f = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(StoreError::io("open", path, e)),
    };
    let mut buf = Vec::new();
    f.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut buf)
        .map_err(|e| StoreError::io("read", path, e))?;
    if buf.len() as u64 > MAX_FILE_BYTES {
        return Err(StoreError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("larger than {MAX_FILE_BYTES} bytes"),
            hint: "it is not a file this program wrote",
        });
    }
    Ok(Some(buf))
}

/// Makes sure `path` is readable and writable by its owner only.
pub(crate) fn restrict_permissions(path: &Path) -> Result<(), StoreError> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let meta = fs::metadata(path).map_err(|e| StoreError::io("inspect", path, e))?;
        if meta.permissions().mode() & 0o077 != 0 {
            fs::set_permissions(path, fs::Permissions::from_mode(0o600))
                .map_err(|e| StoreError::io("restrict permissions of", path, e))?;
        }
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}
