"""Where the daemon and its clients meet: the iceoryx2 root folder, and who may use it.

The same rule as the Rust crate's ``op3dsg_ipc_types::access``. iceoryx2 0.10 gives everything it
creates owner-only modes, fixed in its code, so only processes of the daemon's own user can attach
to it. The root folder is, in this order:

1. ``$OP3DSG_IPC_ROOT`` when set;
2. ``/run/op3dsg`` (the systemd unit's ``RuntimeDirectory=``) when it belongs to this user;
3. ``/tmp/op3dsg-<euid>``.

It must be a folder (not a link) owned by this process's effective user with no group or other
permission bits; anything else is refused with a message naming the owner and the fix.
"""

from __future__ import annotations

import errno
import os
import pwd
import stat
from typing import List, Optional, Tuple

#: Environment variable naming the iceoryx2 root folder.
IPC_ROOT_ENV = "OP3DSG_IPC_ROOT"
#: The installed service's root (the unit's ``RuntimeDirectory=op3dsg``).
SERVICE_ROOT = "/run/op3dsg"
#: Prefix of every file and shared-memory segment iceoryx2 creates for op3dsg.
ICEORYX2_PREFIX = "op3dsg_"
#: Longest root path (iceoryx2's socket paths in it must fit 107 bytes).
MAX_ROOT_LEN = 64


def per_user_root(uid: int) -> str:
    return f"/tmp/op3dsg-{uid}"


def user_name(uid: int) -> str:
    """``'name' (uid N)``, or ``uid N`` when the user database has none."""
    try:
        return f"'{pwd.getpwuid(uid).pw_name}' (uid {uid})"
    except KeyError:
        return f"uid {uid}"


def attach_fix(owner: int) -> str:
    return attach_fix_any([owner])


def attach_fix_any(owners: List[int]) -> str:
    """:func:`attach_fix` when the daemon may be any of ``owners``' (which one, this process
    cannot see)."""
    sudo = []
    for owner in owners:
        try:
            sudo.append(f"sudo -u {pwd.getpwuid(owner).pw_name} ...")
        except KeyError:
            sudo.append(f"sudo -u #{owner} ...")
    who = "that user" if len(owners) == 1 else "the user whose daemon it is"
    return (
        f"iceoryx2 shares memory only between processes of one user, so run this as {who} "
        f'({" or ".join(sudo)}) or make this user the service user (docs/robot.md, "Who can attach")'
    )


def resolve_root() -> Tuple[str, str]:
    """The root and why it was chosen (``environment``, ``service`` or ``per-user``)."""
    env = os.environ.get(IPC_ROOT_ENV, "")
    if env:
        return env, "environment"
    uid = os.geteuid()
    try:
        st = os.lstat(SERVICE_ROOT)
        if stat.S_ISDIR(st.st_mode) and st.st_uid == uid:
            return SERVICE_ROOT, "service"
    except OSError:
        pass
    return per_user_root(uid), "per-user"


class RootMissing(Exception):
    """The root does not exist: no daemon of this user runs there."""


class RootDenied(Exception):
    """The root belongs to another user, is open to others, is no folder, or is invalid."""


def check_root(root: str) -> None:
    """Raises :class:`RootMissing` or :class:`RootDenied` (with the reason and the fix)."""
    if not os.path.isabs(root):
        raise RootDenied(f"IPC root {root}: must be an absolute path")
    if len(root.encode()) > MAX_ROOT_LEN:
        raise RootDenied(f"IPC root {root}: longer than {MAX_ROOT_LEN} bytes (iceoryx2's socket paths must fit)")
    try:
        st = os.lstat(root)
    except FileNotFoundError:
        raise RootMissing(f"IPC root {root} does not exist (no op3dsgd of this user runs)") from None
    except OSError as e:
        raise RootDenied(
            f"no permission: cannot look into IPC root {root} ({os.strerror(e.errno or errno.EACCES)}); "
            'it belongs to another user (docs/robot.md, "Who can attach")'
        ) from None
    me = os.geteuid()
    if not stat.S_ISDIR(st.st_mode):
        raise RootDenied(f"IPC root {root} is not a folder (a file or a symbolic link): remove it")
    if st.st_uid != me:
        raise RootDenied(
            f"no permission: IPC root {root} belongs to {user_name(st.st_uid)}, this process runs as "
            f"{user_name(me)}; {attach_fix(st.st_uid)}"
        )
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o077:
        raise RootDenied(f"IPC root {root} has mode {mode:04o}: it must be a folder only its owner can use (chmod 0700 {root})")


def prepare_root(root: str) -> None:
    """Makes a missing root (mode 0700, the last folder only), then checks it."""
    try:
        check_root(root)
        return
    except RootMissing:
        pass
    try:
        os.mkdir(root, 0o700)
        os.chmod(root, 0o700)
    except FileExistsError:
        pass
    except OSError as e:
        raise RootDenied(f"cannot create IPC root {root}: {e.strerror}") from None
    check_root(root)


def other_users_roots() -> List[Tuple[int, str]]:
    """The per-user roots (``/tmp/op3dsg-<uid>``) of users other than this process's, by uid."""
    me = os.geteuid()
    found = []
    try:
        names = os.listdir("/tmp")
    except OSError:
        return []
    for name in names:
        if not name.startswith("op3dsg-"):
            continue
        try:
            uid = int(name[len("op3dsg-"):])
        except ValueError:
            continue
        path = os.path.join("/tmp", name)
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if uid != me and stat.S_ISDIR(st.st_mode) and st.st_uid == uid:
            found.append((uid, path))
    return sorted(found)


def foreign_service_note(root: str, source: str = "per-user") -> Optional[str]:
    """When no daemon was found in ``root`` (chosen for ``source``, as :func:`resolve_root` says):
    a note about the installed service's root if another user owns it (the daemon the caller was
    probably looking for); without one, for a per-user root, a note naming the per-user roots of
    other users (``/tmp/op3dsg-<uid>``, daemons started by hand), which this process cannot look
    into. The same rule as the Rust crate's ``IpcRoot::foreign_service_note``."""
    if source == "service" or root == SERVICE_ROOT:
        return None
    try:
        st = os.lstat(SERVICE_ROOT)
        if st.st_uid != os.geteuid():
            return f"the installed service's root {SERVICE_ROOT} belongs to {user_name(st.st_uid)}: {attach_fix(st.st_uid)}"
    except OSError:
        pass
    if source != "per-user":
        return None
    others = other_users_roots()
    if not others:
        return None
    listed = ", ".join(f"{path} of {user_name(uid)}" for uid, path in others)
    return (
        f"other users' roots exist ({listed}), where daemons they started by hand serve: "
        f"{attach_fix_any([uid for uid, _ in others])}"
    )


def config(root: str):
    """The iceoryx2 configuration with ``root`` and :data:`ICEORYX2_PREFIX`."""
    import iceoryx2 as iox2

    cfg = iox2.config.default()
    cfg.global_cfg.root_path = iox2.Path.new(root)
    cfg.global_cfg.prefix = iox2.FileName.new(ICEORYX2_PREFIX)
    return cfg
