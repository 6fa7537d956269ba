//! Where the daemon and its clients meet: the iceoryx2 root folder, and who may use it.
//!
//! iceoryx2 0.10 gives every file, socket and shared-memory segment it creates an owner-only
//! mode (files 0600/0400, folders 0750, `/dev/shm` segments 0600, sockets 0600), fixed in its
//! code: umask, setgid folders and default ACLs do not widen them, and there is no per-service
//! permission setting. Processes of **one user** share a scene graph; a group cannot. So the
//! daemon and every planner that attaches to it run as the same user (the service user,
//! `op3dsg` by default, configurable at install), and each user has a root folder of its own:
//! a process of another user, root included, never creates files in it, so nothing depends on
//! who ran first.
//!
//! The root is chosen alike by the daemon, `op3dsg`, the Rust client and the Python package
//! ([`IpcRoot::resolve`]):
//!
//! 1. `$OP3DSG_IPC_ROOT` when set (the daemon's `ipc.root` profile key comes before it);
//! 2. else [`SERVICE_ROOT`] (`/run/op3dsg`, made by the systemd unit's `RuntimeDirectory=`)
//!    when it exists and belongs to this process's effective user;
//! 3. else `/tmp/op3dsg-<euid>` ([`per_user_root`]), which the daemon creates with mode 0700.
//!
//! A root must be a real folder owned by the effective user with no group or other permission
//! bits ([`IpcRoot::check`]); anything else is refused with a message that names the owner and
//! the fix, before iceoryx2 is asked to create a node (which would fail with an unexplained
//! `InternalError`, or leave files that block the rightful owner).

use std::fmt;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use iceoryx2::config::Config;
use iceoryx2::prelude::FileName;
use iceoryx2::prelude::Path as IoxPath;
use iceoryx2::prelude::SemanticString as _;

/// Environment variable naming the iceoryx2 root folder (daemon, `op3dsg`, clients).
pub const IPC_ROOT_ENV: &str = "OP3DSG_IPC_ROOT";
/// The root of the installed service: the unit's `RuntimeDirectory=op3dsg`, owned by the service
/// user, mode 0700.
pub const SERVICE_ROOT: &str = "/run/op3dsg";
/// Prefix of every file and shared-memory segment iceoryx2 creates for op3dsg
/// (`/dev/shm/op3dsg_*`), instead of iceoryx2's default `iox2_`.
pub const ICEORYX2_PREFIX: &str = "op3dsg_";
/// Longest root path: iceoryx2 puts its event sockets straight into the root, named with the
/// prefix, a 30-digit id and `.event`, and a socket path has at most 107 bytes.
pub const MAX_ROOT_LEN: usize = 64;

/// The per-user default root, `/tmp/op3dsg-<uid>`.
pub fn per_user_root(uid: u32) -> PathBuf {
    PathBuf::from(format!("/tmp/op3dsg-{uid}"))
}

/// The effective user id of this process.
pub fn effective_uid() -> u32 {
    nix::unistd::geteuid().as_raw()
}

/// `uid`'s login name, or the number when the user database has none.
pub fn user_name(uid: u32) -> String {
    match nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid)) {
        Ok(Some(user)) => format!("'{}' (uid {uid})", user.name),
        _ => format!("uid {uid}"),
    }
}

/// The iceoryx2 configuration of a process that creates services in the root
/// [`IpcRoot::resolve`] chooses (a stand-in daemon of a test, a benchmark's raw publisher): the
/// root is made when missing and checked.
pub fn creator_config() -> Result<Config, RootError> {
    let root = IpcRoot::resolve();
    root.prepare()?;
    root.config()
}

/// Why a root was chosen (for logs and messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RootSource {
    /// The daemon's profile (`ipc.root`).
    Profile,
    /// `$OP3DSG_IPC_ROOT`.
    Environment,
    /// [`SERVICE_ROOT`], owned by this user.
    Service,
    /// `/tmp/op3dsg-<euid>`.
    PerUser,
}

impl RootSource {
    /// Lower-case words, as in the logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Profile => "the profile's ipc.root",
            Self::Environment => IPC_ROOT_ENV,
            Self::Service => "the installed service's root",
            Self::PerUser => "the per-user default",
        }
    }
}

/// Why a root cannot be used by this process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AccessDenied {
    /// The root belongs to another user.
    OtherOwner {
        /// The owner's uid.
        owner: u32,
        /// This process's effective uid.
        me: u32,
    },
    /// The root grants group or other users access (mode shown in octal).
    OpenMode {
        /// The permission bits.
        mode: u32,
    },
    /// The path is not a folder (a file, or a symbolic link: refused, as anybody may plant one
    /// in `/tmp`).
    NotAFolder,
    /// The root or a folder above it cannot be read (`errno`).
    Unreadable {
        /// The OS error number.
        errno: i32,
    },
}

impl AccessDenied {
    /// The reason and the fix, for a message that already names `root`.
    pub fn explain(&self, root: &Path) -> String {
        let root = root.display();
        match *self {
            Self::OtherOwner { owner, me } => format!(
                "no permission: IPC root {root} belongs to {}, this process runs as {}; {}",
                user_name(owner),
                user_name(me),
                attach_fix(owner),
            ),
            Self::OpenMode { mode } => format!(
                "IPC root {root} has mode {mode:04o}: it must be a folder only its owner can use \
                 (chmod 0700 {root})"
            ),
            Self::NotAFolder => format!("IPC root {root} is not a folder (a file or a symbolic link): remove it"),
            Self::Unreadable { errno } => format!(
                "no permission: cannot look into IPC root {root} ({}); it belongs to another user \
                 (docs/robot.md, \"Who can attach\")",
                std::io::Error::from_raw_os_error(errno)
            ),
        }
    }
}

/// What to do when the daemon runs as `owner`: iceoryx2 lets only that user attach.
/// The per-user roots (`/tmp/op3dsg-<uid>`) of users other than this process's, by uid.
fn other_users_roots() -> Vec<(u32, PathBuf)> {
    let me = effective_uid();
    let Ok(entries) = std::fs::read_dir("/tmp") else { return Vec::new() };
    let mut found: Vec<(u32, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let uid: u32 = entry.file_name().to_str()?.strip_prefix("op3dsg-")?.parse().ok()?;
            let meta = std::fs::symlink_metadata(entry.path()).ok()?;
            (uid != me && meta.is_dir() && meta.uid() == uid).then(|| (uid, entry.path()))
        })
        .collect();
    found.sort();
    found
}

fn attach_fix(owner: u32) -> String {
    attach_fix_any(&[owner])
}

/// [`attach_fix`] when the daemon may be any of `owners`' (which one, this process cannot see).
fn attach_fix_any(owners: &[u32]) -> String {
    let sudo: Vec<String> = owners
        .iter()
        .map(|&owner| match nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(owner)) {
            Ok(Some(user)) => format!("sudo -u {} ...", user.name),
            _ => format!("sudo -u #{owner} ..."),
        })
        .collect();
    let who = if owners.len() == 1 { "that user" } else { "the user whose daemon it is" };
    format!(
        "iceoryx2 shares memory only between processes of one user, so run this as {who} ({}) or make \
         this user the service user (docs/robot.md, \"Who can attach\")",
        sudo.join(" or ")
    )
}

/// A root that cannot be used, or made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RootError {
    /// The root does not exist: no daemon of this user runs there.
    Missing(PathBuf),
    /// It exists but this process may not use it.
    Denied(PathBuf, AccessDenied),
    /// The path is no valid iceoryx2 root (not absolute, too long, not UTF-8).
    InvalidPath(PathBuf, String),
    /// Creating it failed.
    Create(PathBuf, String),
}

impl fmt::Display for RootError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Missing(root) => {
                write!(f, "IPC root {} does not exist (no op3dsgd of this user runs)", root.display())
            }
            Self::Denied(root, why) => f.write_str(&why.explain(root)),
            Self::InvalidPath(root, why) => write!(f, "IPC root {}: {why}", root.display()),
            Self::Create(root, why) => write!(f, "cannot create IPC root {}: {why}", root.display()),
        }
    }
}

impl std::error::Error for RootError {}

/// The iceoryx2 root folder of one daemon and its clients.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IpcRoot {
    path: PathBuf,
    source: RootSource,
}

impl IpcRoot {
    /// The root at `path`, chosen because of `source`.
    pub fn at(path: impl Into<PathBuf>, source: RootSource) -> Self {
        Self { path: path.into(), source }
    }

    /// The root the daemon, `op3dsg` and the clients agree on (see the module docs):
    /// `$OP3DSG_IPC_ROOT`, else [`SERVICE_ROOT`] when it belongs to this user, else
    /// `/tmp/op3dsg-<euid>`.
    pub fn resolve() -> Self {
        match std::env::var_os(IPC_ROOT_ENV).filter(|v| !v.is_empty()) {
            Some(path) => Self::at(path, RootSource::Environment),
            None => Self::default_for(effective_uid()),
        }
    }

    /// [`Self::resolve`] without the environment: the service root if `uid` owns it, else the
    /// per-user one.
    pub fn default_for(uid: u32) -> Self {
        match std::fs::symlink_metadata(SERVICE_ROOT) {
            Ok(meta) if meta.is_dir() && meta.uid() == uid => Self::at(SERVICE_ROOT, RootSource::Service),
            _ => Self::at(per_user_root(uid), RootSource::PerUser),
        }
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Why it was chosen.
    pub fn source(&self) -> RootSource {
        self.source
    }

    /// Checks that the root exists and this process may use it: a folder (not a link), owned by
    /// the effective user, without group or other permission bits.
    pub fn check(&self) -> Result<(), RootError> {
        self.check_path()?;
        let meta = match std::fs::symlink_metadata(&self.path) {
            Ok(meta) => meta,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(RootError::Missing(self.path.clone())),
            Err(e) => {
                let errno = e.raw_os_error().unwrap_or(0);
                return Err(RootError::Denied(self.path.clone(), AccessDenied::Unreadable { errno }));
            }
        };
        let me = effective_uid();
        let denied = if !meta.is_dir() {
            Some(AccessDenied::NotAFolder)
        } else if meta.uid() != me {
            Some(AccessDenied::OtherOwner { owner: meta.uid(), me })
        } else if meta.permissions().mode() & 0o077 != 0 {
            Some(AccessDenied::OpenMode { mode: meta.permissions().mode() & 0o7777 })
        } else {
            None
        };
        denied.map_or(Ok(()), |why| Err(RootError::Denied(self.path.clone(), why)))
    }

    /// The daemon's side of [`Self::check`]: creates a missing root (the last folder only, mode
    /// 0700; its parent must exist), then checks it.
    pub fn prepare(&self) -> Result<(), RootError> {
        self.check_path()?;
        match self.check() {
            Err(RootError::Missing(_)) => {
                let created = std::fs::DirBuilder::new().mode(0o700).create(&self.path);
                match created {
                    Ok(()) => {}
                    // Another process of this user made it at the same moment: check it below.
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
                    Err(e) => return Err(RootError::Create(self.path.clone(), e.to_string())),
                }
                // The mode asked for is masked by the umask; set it exactly.
                std::fs::set_permissions(&self.path, std::fs::Permissions::from_mode(0o700))
                    .map_err(|e| RootError::Create(self.path.clone(), e.to_string()))?;
                self.check()
            }
            other => other,
        }
    }

    /// The iceoryx2 configuration with this root and [`ICEORYX2_PREFIX`]; every node of the
    /// daemon and its clients is built with it.
    pub fn config(&self) -> Result<Config, RootError> {
        self.check_path()?;
        let invalid = |why: String| RootError::InvalidPath(self.path.clone(), why);
        let text = self.path.to_str().ok_or_else(|| invalid("not UTF-8".to_owned()))?;
        let path = IoxPath::new(text.as_bytes()).map_err(|e| invalid(format!("{e:?}")))?;
        let prefix = FileName::new(ICEORYX2_PREFIX.as_bytes()).map_err(|e| invalid(format!("prefix: {e:?}")))?;
        let mut config = Config::default();
        config.global.set_root_path(&path);
        config.global.prefix = prefix;
        Ok(config)
    }

    /// When this process found no daemon in its own root: a note about the installed service's
    /// root if another user owns it (the daemon this process was probably looking for), else
    /// `None`.
    ///
    /// Without such a service root, a note naming the per-user roots of other users
    /// (`/tmp/op3dsg-<uid>`, daemons started by hand): this process cannot look inside them (they
    /// are theirs alone), but one of them is where a daemon another user started serves.
    pub fn foreign_service_note(&self) -> Option<String> {
        if self.source == RootSource::Service || self.path == Path::new(SERVICE_ROOT) {
            return None;
        }
        if let Ok(meta) = std::fs::symlink_metadata(SERVICE_ROOT)
            && meta.uid() != effective_uid()
        {
            return Some(format!(
                "the installed service's root {SERVICE_ROOT} belongs to {}: {}",
                user_name(meta.uid()),
                attach_fix(meta.uid())
            ));
        }
        if self.source != RootSource::PerUser {
            return None;
        }
        let others = other_users_roots();
        if others.is_empty() {
            return None;
        }
        let listed: Vec<String> =
            others.iter().map(|(uid, path)| format!("{} of {}", path.display(), user_name(*uid))).collect();
        let owners: Vec<u32> = others.iter().map(|(uid, _)| *uid).collect();
        Some(format!(
            "other users' roots exist ({}), where daemons they started by hand serve: {}",
            listed.join(", "),
            attach_fix_any(&owners)
        ))
    }

    fn check_path(&self) -> Result<(), RootError> {
        let invalid = |why: &str| Err(RootError::InvalidPath(self.path.clone(), why.to_owned()));
        if !self.path.is_absolute() {
            return invalid("must be an absolute path");
        }
        if self.path.as_os_str().len() > MAX_ROOT_LEN {
            return invalid(&format!("longer than {MAX_ROOT_LEN} bytes (iceoryx2's socket paths must fit)"));
        }
        if self.path.to_str().is_none() {
            return invalid("not UTF-8");
        }
        Ok(())
    }
}

impl fmt::Display for IpcRoot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.path.display(), self.source.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_root_is_made_owner_only_and_then_accepted() {
        let dir = tempfile::tempdir().unwrap();
        let root = IpcRoot::at(dir.path().join("r"), RootSource::Environment);
        assert_eq!(root.check(), Err(RootError::Missing(dir.path().join("r"))));
        root.prepare().unwrap();
        let mode = std::fs::metadata(root.path()).unwrap().permissions().mode() & 0o7777;
        assert_eq!(mode, 0o700);
        root.check().unwrap();
        root.prepare().unwrap();
    }

    #[test]
    fn an_open_mode_or_a_link_is_refused_with_the_fix() {
        let dir = tempfile::tempdir().unwrap();
        let open = dir.path().join("open");
        std::fs::create_dir(&open).unwrap();
        std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o750)).unwrap();
        let err = IpcRoot::at(&open, RootSource::Environment).check().unwrap_err();
        assert_eq!(err, RootError::Denied(open.clone(), AccessDenied::OpenMode { mode: 0o750 }));
        assert!(err.to_string().contains("chmod 0700"), "{err}");

        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&open, &link).unwrap();
        let err = IpcRoot::at(&link, RootSource::Environment).prepare().unwrap_err();
        assert_eq!(err, RootError::Denied(link, AccessDenied::NotAFolder));
    }

    #[test]
    fn bad_paths_are_refused_before_anything_is_made() {
        let relative = IpcRoot::at("relative/root", RootSource::Profile);
        assert!(matches!(relative.prepare(), Err(RootError::InvalidPath(_, _))));
        let long = IpcRoot::at(format!("/tmp/{}", "x".repeat(MAX_ROOT_LEN)), RootSource::Profile);
        let err = long.config().unwrap_err();
        assert!(err.to_string().contains("longer than"), "{err}");
    }

    #[test]
    fn another_owner_is_named_with_the_fix() {
        let why = AccessDenied::OtherOwner { owner: 0, me: 4242 };
        let text = why.explain(Path::new("/run/op3dsg"));
        assert!(text.starts_with("no permission: IPC root /run/op3dsg belongs to 'root' (uid 0)"), "{text}");
        assert!(text.contains("uid 4242") && text.contains("sudo -u root"), "{text}");
    }

    #[test]
    fn the_config_carries_the_root_and_the_prefix() {
        let root = IpcRoot::at("/tmp/op3dsg-test-root", RootSource::Environment);
        let config = root.config().unwrap();
        assert_eq!(config.global.root_path().to_string(), "/tmp/op3dsg-test-root");
        assert_eq!(config.global.prefix.to_string(), ICEORYX2_PREFIX);
    }

    #[test]
    fn the_default_is_per_user_unless_the_service_root_is_ours() {
        let service_owner = std::fs::symlink_metadata(SERVICE_ROOT).ok().map(|m| m.uid());
        let other = service_owner.map_or(4242, |owner| owner + 1);
        assert_eq!(IpcRoot::default_for(other), IpcRoot::at(format!("/tmp/op3dsg-{other}"), RootSource::PerUser));
        if let Some(owner) = service_owner {
            assert_eq!(IpcRoot::default_for(owner), IpcRoot::at(SERVICE_ROOT, RootSource::Service));
        }
    }
}
