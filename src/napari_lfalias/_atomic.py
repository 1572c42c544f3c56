"""Atomic replacement of files and folders, and the clean-up of what killed writers left.

A writer writes to a temporary name beside its target,
``.<name>.tmp-<host>-<pid>-<random><suffix>``, and moves it into place when
it is complete. The host and process in the name tell whether the writer
is still alive, so the temporaries of killed writers can be removed while
other writers run: :func:`remove_stale` removes only those whose process
is gone from this host.

A folder (a zarr store) that replaces a folder is swapped in with one
``renameat2(RENAME_EXCHANGE)`` (Linux): there is no moment at which the
target is missing. Where the file system cannot exchange, the old folder
is first moved to a *backup* name (``.<name>.tmp-old-...``); a kill
between the two renames leaves the target missing and the backup beside
it, and the next clean-up puts the backup back instead of deleting it.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import hashlib
import os
import re
import shutil
import socket
import uuid
from pathlib import Path

__all__ = ["TEMP_MARK", "temporary_name", "is_temporary", "replace", "remove_stale", "remove_all", "discard"]

#: Part of every temporary name.
TEMP_MARK = ".tmp-"
_BACKUP = "old-"
#: ``.<target>.tmp-<host>-<pid>-<random><suffix>``
_OWNED = re.compile(r"^\.(?P<target>.+)\.tmp-(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-[0-9a-f]{12}")
_BACKUP_NAME = re.compile(r"^\.(?P<target>.+)\.tmp-old-[0-9a-f]{12}$")


def _host_tag():
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:6]


def temporary_name(path):
    """A fresh temporary name beside ``path``, with its suffix, naming this host and process."""
    path = Path(path)
    return path.with_name(f".{path.name}{TEMP_MARK}{_host_tag()}-{os.getpid()}-{uuid.uuid4().hex[:12]}{path.suffix}")


def is_temporary(path):
    """True if ``path`` is a temporary or backup name made here."""
    name = Path(path).name
    return name.startswith(".") and TEMP_MARK in name


def _writer_gone(name):
    """True only when the name says its writer was a process of this host that no longer runs."""
    match = _OWNED.match(name)
    if match is None or match["host"] != _host_tag():
        return False
    pid = int(match["pid"])
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # a live process of another user
        return False
    return False


def discard(path):
    """Remove a file or folder; missing is fine."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _settle_backup(backup):
    """Put a backup back where its target is missing (a kill between two renames); else drop it."""
    match = _BACKUP_NAME.match(backup.name)
    target = backup.with_name(match["target"])
    if not target.exists() and not target.is_symlink():
        with contextlib.suppress(FileNotFoundError, FileExistsError, OSError):
            os.rename(backup, target)
            return "restored"
    discard(backup)
    return "removed"


def _remove_if(folder, keep):
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for path in entries:
        if not is_temporary(path) or keep(path):
            continue
        if _BACKUP_NAME.match(path.name):
            if _settle_backup(path) == "removed":
                removed.append(path)
        else:
            discard(path)
            removed.append(path)
    return removed


def remove_stale(folder, target=None):
    """Remove the temporaries of writers that were killed; leave those of live writers.

    Parameters
    ----------
    folder : str or Path
    target : str, optional
        Only the temporaries of this output name.

    Returns
    -------
    list of Path
        What was removed. Backups whose target is missing are restored, not removed.
    """
    prefix = None if target is None else f".{target}{TEMP_MARK}"

    def keep(path):
        if prefix is not None and not path.name.startswith(prefix):
            return True
        return not (_BACKUP_NAME.match(path.name) or _writer_gone(path.name))

    return _remove_if(folder, keep)


def remove_all(folder):
    """Remove every temporary in ``folder`` (restoring backups); only when no writer runs there."""
    return _remove_if(folder, lambda path: False)


# -- replacing a folder without a moment where it is missing --------------------------------------

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _renameat2():
    try:
        function = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return function


_EXCHANGE = _renameat2()


def _exchange(a, b):
    """Swap two paths atomically; False where the system or file system cannot."""
    if _EXCHANGE is None:
        return False
    if _EXCHANGE(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def replace(tmp, path):
    """Move the complete ``tmp`` onto ``path``; the old ``path`` is gone afterwards.

    A file onto a file is one :func:`os.replace`. A folder, or anything onto
    a folder, is exchanged atomically where the file system allows; else
    the old one goes to a backup name first (see the module notes).
    """
    tmp, path = Path(tmp), Path(path)
    folders = tmp.is_dir() or (path.is_dir() and not path.is_symlink())
    if not folders or not (path.exists() or path.is_symlink()):
        os.replace(tmp, path)
        return
    if _exchange(tmp, path):
        discard(tmp)  # now the old one
        return
    backup = path.with_name(f".{path.name}{TEMP_MARK}{_BACKUP}{uuid.uuid4().hex[:12]}")
    os.rename(path, backup)
    os.rename(tmp, path)
    discard(backup)
