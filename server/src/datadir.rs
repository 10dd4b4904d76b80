//! The server's data directory: where the world database, the TLS
//! certificate and key, and the auth secret live.
//!
//! Layout (all created on first run):
//!
//! ```text
//! <data_dir>/            mode 0700
//!   world.sled/          the chunk store (opened by the store, not here)
//!   cert.der             self-signed certificate, DER; give it to clients
//!   key.der              its private key, PKCS#8 DER, mode 0600
//!   auth.secret          token-signing key, 64 hex chars, mode 0600
//! ```
//!
//! Once `world.sled` exists the identity files are never generated again: a
//! missing one is an error, since a new secret would invalidate every issued
//! token and a new certificate every client that pinned the old one.

use std::fmt;
use std::fs;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::auth::{Secret, SecretError, SecretFile};
use crate::tls::{CertPair, TlsError};

/// File name of the chunk store inside the data dir.
pub const WORLD_DB_NAME: &str = "world.sled";
/// File name of the DER certificate.
pub const CERT_NAME: &str = "cert.der";
/// File name of the PKCS#8 DER private key.
pub const KEY_NAME: &str = "key.der";
/// File name of the auth secret.
pub const SECRET_NAME: &str = "auth.secret";
/// Largest key, certificate or secret file read; real ones are under 1 KiB.
pub const MAX_PRIVATE_FILE_LEN: u64 = 64 * 1024;

/// An opened data directory with its loaded secret and certificate.
#[derive(Debug)]
pub struct DataDir {
    root: PathBuf,
    secret: Secret,
    cert: CertPair,
}

/// What [`DataDir::open_or_init`] created, so the server can log it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InitReport {
    /// The data dir itself, if it did not exist.
    pub created_dir: Option<PathBuf>,
    /// The certificate path, if a certificate was generated.
    pub created_cert: Option<PathBuf>,
    /// The auth secret path, if a secret was generated.
    pub created_secret: Option<PathBuf>,
}

impl InitReport {
    /// True if this run generated anything.
    pub fn created_anything(&self) -> bool {
        self.created_dir.is_some() || self.created_cert.is_some() || self.created_secret.is_some()
    }
}

impl fmt::Display for InitReport {
    /// E.g. `generated certificate at ./d/cert.der, auth secret at ./d/auth.secret`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if let Some(p) = &self.created_dir {
            parts.push(format!("data dir at {}", p.display()));
        }
        if let Some(p) = &self.created_cert {
            parts.push(format!("certificate at {}", p.display()));
        }
        if let Some(p) = &self.created_secret {
            parts.push(format!("auth secret at {}", p.display()));
        }
        if parts.is_empty() {
            f.write_str("reused existing data dir")
        } else {
            write!(f, "generated {}", parts.join(", "))
        }
    }
}

/// Why the data dir could not be opened or initialised.
#[derive(Debug, Error)]
pub enum DataDirError {
    #[error("data dir {0} exists and is not a directory")]
    NotADirectory(PathBuf),
    #[error("data dir {0} does not exist (start strata-server once to create it)")]
    Missing(PathBuf),
    #[error("cannot create data dir {path}: {source}")]
    Create { path: PathBuf, source: io::Error },
    #[error("{present} exists but {missing} does not; restore {missing} from a backup")]
    HalfCertificate { present: PathBuf, missing: PathBuf },
    #[error("{missing} is missing but {world} exists; a new auth secret would invalidate every token already issued, so none is generated. Restore {missing} from a backup, or see \"Tokens\" in deploy/OPERATIONS.md to replace it on purpose")]
    MissingSecret { missing: PathBuf, world: String },
    #[error("{cert} and {key} are missing but {world} exists; a new certificate would be rejected by every client that pinned the old one, so none is generated. Restore both from a backup, or see \"Certificates\" in deploy/OPERATIONS.md to replace them on purpose")]
    MissingCertificate {
        cert: PathBuf,
        key: PathBuf,
        world: String,
    },
    #[error(transparent)]
    Secret(#[from] SecretError),
    #[error(transparent)]
    Tls(#[from] TlsError),
}

impl DataDir {
    /// Opens `root`, creating it and any missing secret or certificate
    /// (with SANs localhost, 127.0.0.1, ::1 and `extra_names`) unless it
    /// already holds a world, where a missing one is an error. Existing
    /// files are reused untouched, so clients' pinned certificates and
    /// issued tokens stay valid across restarts. Everything is loaded or
    /// generated in memory before anything is written, so a failure (a
    /// corrupt key, a bad extra name) leaves the disk as it was.
    pub fn open_or_init(
        root: &Path,
        extra_names: &[String],
    ) -> Result<(DataDir, InitReport), DataDirError> {
        Self::open_or_init_beside(root, extra_names, None)
    }

    /// [`Self::open_or_init`] for a server whose world lives outside the
    /// data dir (PostgreSQL): `world_elsewhere` names it when it already
    /// holds a world, and a missing secret or certificate is then an error
    /// as beside `world.sled` (a node started before the cluster's files
    /// were copied to it would sign tickets no other node accepts).
    pub fn open_or_init_beside(
        root: &Path,
        extra_names: &[String],
        world_elsewhere: Option<&str>,
    ) -> Result<(DataDir, InitReport), DataDirError> {
        let dir_exists = match fs::metadata(root) {
            Ok(meta) if meta.is_dir() => true,
            Ok(_) => return Err(DataDirError::NotADirectory(root.to_owned())),
            Err(e) if e.kind() == io::ErrorKind::NotFound => false,
            Err(source) => {
                return Err(DataDirError::Create {
                    path: root.to_owned(),
                    source,
                })
            }
        };
        let secret_path = root.join(SECRET_NAME);
        let (cert_path, key_path) = (root.join(CERT_NAME), root.join(KEY_NAME));
        let world_path = root.join(WORLD_DB_NAME);
        let world = match world_elsewhere {
            Some(w) => Some(w.to_string()),
            None => (dir_exists && world_path.exists()).then(|| world_path.display().to_string()),
        };
        let has_world = world.is_some();

        let existing_secret = match dir_exists && secret_path.exists() {
            true => Some(Secret::load(&secret_path)?),
            false if has_world => {
                return Err(DataDirError::MissingSecret {
                    missing: secret_path,
                    world: world.unwrap_or_default(),
                })
            }
            false => None,
        };
        let existing_cert = match (dir_exists && cert_path.exists(), key_path.exists()) {
            (true, true) => Some(CertPair::load(&cert_path, &key_path)?),
            (false, false) if has_world => {
                return Err(DataDirError::MissingCertificate {
                    cert: cert_path,
                    key: key_path,
                    world: world.unwrap_or_default(),
                })
            }
            (false, false) => None,
            (true, false) => return Err(half(cert_path, key_path)),
            // A save cut short between the key and moving its staged
            // certificate into place: finish it (the pair must match).
            (false, true) if crate::tls::staged_cert(&cert_path).is_file() => {
                let staged = crate::tls::staged_cert(&cert_path);
                let pair = CertPair::load(&staged, &key_path)?;
                crate::durable::rename(&staged, &cert_path).map_err(|source| {
                    DataDirError::Create {
                        path: cert_path.clone(),
                        source,
                    }
                })?;
                Some(pair)
            }
            (false, true) => return Err(half(key_path, cert_path)),
        };
        let (secret, secret_is_new) = match existing_secret {
            Some(secret) => (secret, false),
            None => (Secret::generate()?, true),
        };
        let (cert, cert_is_new) = match existing_cert {
            Some(pair) => (pair, false),
            None => (CertPair::generate(extra_names)?, true),
        };

        let mut report = InitReport::default();
        if !dir_exists {
            create_private_dir(root).map_err(|source| DataDirError::Create {
                path: root.to_owned(),
                source,
            })?;
            report.created_dir = Some(root.to_owned());
        }
        if secret_is_new {
            secret.save(&secret_path)?;
            report.created_secret = Some(secret_path);
        }
        if cert_is_new {
            cert.save(&cert_path, &key_path)?;
            report.created_cert = Some(cert_path);
        }

        let dir = DataDir {
            root: root.to_owned(),
            secret,
            cert,
        };
        Ok((dir, report))
    }

    /// Opens an existing, complete data dir without creating anything (for
    /// tools that must not invent a new identity, e.g. when copying a cert).
    pub fn open_existing(root: &Path) -> Result<DataDir, DataDirError> {
        match fs::metadata(root) {
            Ok(meta) if meta.is_dir() => {}
            Ok(_) => return Err(DataDirError::NotADirectory(root.to_owned())),
            Err(_) => return Err(DataDirError::Missing(root.to_owned())),
        }
        let secret = Secret::load(&root.join(SECRET_NAME))?;
        let (cert_path, key_path) = (root.join(CERT_NAME), root.join(KEY_NAME));
        // A save cut short: the staged certificate is the pair's (a tool
        // only reads it; the server's next start moves it into place).
        let staged = crate::tls::staged_cert(&cert_path);
        let cert = if !cert_path.exists() && key_path.exists() && staged.is_file() {
            CertPair::load(&staged, &key_path)?
        } else {
            CertPair::load(&cert_path, &key_path)?
        };
        Ok(DataDir {
            root: root.to_owned(),
            secret,
            cert,
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }
    /// Where the chunk store keeps its database.
    pub fn world_db_path(&self) -> PathBuf {
        self.root.join(WORLD_DB_NAME)
    }
    pub fn cert_path(&self) -> PathBuf {
        self.root.join(CERT_NAME)
    }
    pub fn key_path(&self) -> PathBuf {
        self.root.join(KEY_NAME)
    }
    pub fn secret_path(&self) -> PathBuf {
        self.root.join(SECRET_NAME)
    }
    pub fn secret(&self) -> &Secret {
        &self.secret
    }
    pub fn cert(&self) -> &CertPair {
        &self.cert
    }
}

fn half(present: PathBuf, missing: PathBuf) -> DataDirError {
    DataDirError::HalfCertificate { present, missing }
}

fn create_private_dir(path: &Path) -> io::Result<()> {
    let mut builder = fs::DirBuilder::new();
    #[cfg(unix)]
    {
        use std::os::unix::fs::DirBuilderExt;
        builder.mode(0o700);
    }
    crate::durable::create_dir_all(&builder, path)
}

/// Writes `bytes` to `path` readable by the owner only (0600 on Unix).
pub(crate) fn write_private_file(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_file_atomic(path, bytes, 0o600)
}

/// Writes a file others may read (0644 on Unix), e.g. the certificate.
pub(crate) fn write_public_file(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_file_atomic(path, bytes, 0o644)
}

/// Writes atomically and durably: a temporary file in the same directory is
/// synced and renamed over `path`, and the directory synced, so a power cut
/// leaves either the old file or the whole new one, never a truncated key.
#[cfg_attr(not(unix), allow(unused_variables))]
fn write_file_atomic(path: &Path, bytes: &[u8], mode: u32) -> io::Result<()> {
    let mut tmp_name = path.file_name().unwrap_or_default().to_owned();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    let mut options = fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(mode);
    }
    let mut file = options.open(&tmp)?;
    // `mode` only applies when the file is created (and is masked by the
    // umask); a stale temp file from a crash may have other bits, so set
    // them explicitly.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        file.set_permissions(fs::Permissions::from_mode(mode))?;
    }
    file.write_all(bytes)?;
    crate::durable::persist_file(&file, &tmp, path)
}

/// Reads a private file (key, secret), warning if others can read it.
pub(crate) fn read_private_file(path: &Path) -> io::Result<Vec<u8>> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = fs::metadata(path)?.permissions().mode();
        if mode & 0o077 != 0 {
            tracing::warn!(
                path = %path.display(),
                mode = format!("{:o}", mode & 0o777),
                "private file is accessible by group or others; chmod 600 it"
            );
        }
    }
    read_capped_file(path)
}

/// Reads a key, certificate or secret file, refusing anything larger than
/// [`MAX_PRIVATE_FILE_LEN`] so a wrong path cannot exhaust memory.
pub(crate) fn read_capped_file(path: &Path) -> io::Result<Vec<u8>> {
    let file = fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(MAX_PRIVATE_FILE_LEN + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_PRIVATE_FILE_LEN {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("file is larger than {MAX_PRIVATE_FILE_LEN} bytes"),
        ));
    }
    Ok(bytes)
}
