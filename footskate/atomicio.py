"""The project's one way to write a file or a folder: atomically, through an unpredictable temp name.

Every write in StableMo and footskate goes through this module (tests/test_bad_input_writes.py
greps the source tree for writes that bypass it). The rules it enforces:

* the temporary file (or folder) is created *exclusively* (`tempfile.mkstemp` / `mkdtemp`: O_EXCL,
  random name) in the target's own folder, so a planted file or symlink is never followed or
  overwritten, and the final `os.replace` is a same-filesystem rename (atomic on POSIX);
* on any failure the temporary is removed and the target is untouched;
* a folder target that is not empty is only replaced when the caller says it is its own kind
  (`replaceable`) and nothing in it is unaccounted for (a file list the build wrote, or the new
  folder's own names), so nothing we did not write is ever deleted;
* a folder is replaced by one atomic exchange (`replace_dir`: renameat2 RENAME_EXCHANGE), or
  where the system lacks it by two journaled renames that the next write undoes or completes;
  leftovers of a killed write are removed by the next write to the same target.

Why it lives in footskate: footskate is the lower layer (torch/numpy only, it never imports
stablemo) while stablemo imports footskate, so this is the one place both can use. It needs the
standard library only; `stablemo.io` re-exports it with StableMo's error type for the checks.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import platform
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import BinaryIO, Callable, Iterator, Optional

try:
    import fcntl
except ImportError:  # not POSIX: no locks; the parent-folder ordering is then best effort
    fcntl = None

__all__ = [
    "atomic_dir", "atomic_open", "atomic_path", "default_signals", "exchange", "output_dir_problem",
    "output_file_problem", "ownership_problem", "recover_dir", "replace_dir", "same_output",
    "terminate_as_interrupt", "write_bytes", "write_text",
]


def _umask() -> int:
    # os.umask can only be read by setting it; restore it at once
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _new_file_mode(mode: Optional[int]) -> int:
    """mkstemp makes the file private (0600); give it what a plain open() would, unless told."""
    return (0o666 & ~_umask()) if mode is None else mode


def _unlink_quietly(path: str | os.PathLike) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def _temp_file(path: Path, suffix: str) -> tuple[int, str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, *, suffix: str = ".tmp", mode: Optional[int] = None,
                durable: bool = False) -> Iterator[BinaryIO]:
    """Open a binary file that becomes `path` when the block ends without an exception.

    Writes go to `.<name>.<random><suffix>` in `path`'s folder (created if missing); on success
    the file gets permission bits `mode` (default: 0o666 minus the umask), is fsync'ed when
    `durable`, and is renamed over `path` (a symlink at `path` is replaced, never followed).
    """
    path = Path(path)
    fd, tmp = _temp_file(path, suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fchmod(f.fileno(), _new_file_mode(mode))
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: Optional[str] = None) -> Iterator[Path]:
    """For writers that need a file *name* (an external program such as ffmpeg): yield the name
    of an empty temp file created exclusively beside `path`; rename it over `path` on success.
    In-process writers use `atomic_open` (a file object) instead."""
    path = Path(path)
    fd, tmp = _temp_file(path, (path.suffix or ".tmp") if suffix is None else suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _new_file_mode(None))
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


def write_bytes(path: str | os.PathLike, data: bytes, **kwargs) -> Path:
    """Atomically write `data` to `path` (keyword arguments as for `atomic_open`)."""
    with atomic_open(path, **kwargs) as f:
        f.write(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8", **kwargs) -> Path:
    """Atomically write `text` to `path` (keyword arguments as for `atomic_open`)."""
    return write_bytes(path, text.encode(encoding), **kwargs)


def _is_empty_dir(path: Path) -> bool:
    with os.scandir(path) as entries:
        return next(entries, None) is None


# ------------------------------------------------------------------------------ folders
# A folder is built as `.<name>.<8 random chars>.partial` beside its target and swapped in whole.
# Three rules keep anything we did not write from being deleted, and the target always whole:
#
# * ownership: a non-empty folder is replaced only when the caller says it is its kind
#   (`replaceable`) *and* every entry in it is accounted for: listed, with its size, in the file
#   list (`manifest`) the build that made it wrote, or, without a manifest, an entry of the same
#   name and kind the new folder holds too (it is rewritten, not lost). One extra file: refused.
# * the swap (`replace_dir`): renameat2(RENAME_EXCHANGE) where the kernel and file system have it
#   (one atomic step: the target is the old folder, then the new one); elsewhere two renames
#   under a journal `.<name>.replacing` that the next write to the same target reads to put the
#   old folder back if a kill fell between them.
# * leftovers: a build holds a lock (flock) on its partial folder until it is swapped in; the next
#   write to the same target removes partial/old folders of that target's name nobody holds
#   (a SIGKILL's leftovers). Creating, sweeping and swapping hold a lock on the parent folder, so
#   a sweep never sees a live build between its creation and its lock.

AT_FDCWD = -100
RENAME_EXCHANGE = 2
# renameat2's system call number, for a glibc older than 2.28 (no wrapper); other machines fall back
_SYS_RENAMEAT2 = {"x86_64": 316, "aarch64": 276}
_RANDOM = r"[a-z0-9_]{8}"  # tempfile.mkdtemp's random part
_DIR = -1  # a folder, in a tree listing (files are listed by their size)
_OTHER = -2  # a symlink, socket, fifo, device: never written by us
MANIFEST_FORMAT = "stablemo-folder-files"
# Where flock is unsupported, a leftover folder is taken as abandoned only after this long.
UNLOCKABLE_AGE_S = 24 * 3600.0


def _rename(src: Path, dst: Path) -> None:
    os.rename(src, dst)  # one name for the steps of the fallback (tests interrupt it here)


def _libc_exchange(a: bytes, b: bytes) -> Optional[int]:
    """renameat2(AT_FDCWD, a, AT_FDCWD, b, RENAME_EXCHANGE) -> 0 or an errno; None: no way to call it."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None
    func = getattr(libc, "renameat2", None)
    if func is not None:
        func.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
        func.restype = ctypes.c_int
        rc = func(AT_FDCWD, a, AT_FDCWD, b, RENAME_EXCHANGE)
    else:
        number = _SYS_RENAMEAT2.get(platform.machine())
        if number is None:
            return None
        libc.syscall.restype = ctypes.c_long
        rc = libc.syscall(ctypes.c_long(number), ctypes.c_int(AT_FDCWD), ctypes.c_char_p(a),
                          ctypes.c_int(AT_FDCWD), ctypes.c_char_p(b), ctypes.c_uint(RENAME_EXCHANGE))
    return 0 if rc == 0 else ctypes.get_errno()


def exchange(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Swap two existing paths in one atomic step; False where this system cannot (not Linux, an
    old kernel, a file system without RENAME_EXCHANGE). Other failures raise OSError."""
    if not sys.platform.startswith("linux"):
        return False
    err = _libc_exchange(os.fsencode(a), os.fsencode(b))
    if err is None or err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    if err:
        raise OSError(err, os.strerror(err), str(b))
    return True


def _tree(folder: Path) -> dict[str, int]:
    """Every entry under `folder` (not following symlinks): relative path -> size of a regular
    file, _DIR for a folder, _OTHER for anything else."""
    out: dict[str, int] = {}

    def walk(d: str, prefix: str) -> None:
        with os.scandir(d) as entries:
            for e in entries:
                rel = prefix + e.name
                if e.is_dir(follow_symlinks=False):
                    out[rel] = _DIR
                    walk(e.path, rel + "/")
                elif e.is_file(follow_symlinks=False):
                    out[rel] = e.stat(follow_symlinks=False).st_size
                else:
                    out[rel] = _OTHER

    walk(os.fspath(folder), "")
    return out


def _write_manifest(folder: Path, name: str) -> None:
    """List every entry of the finished build (with sizes) in `folder/name`, its last file."""
    entries = _tree(folder)
    entries.pop(name, None)
    write_text(folder / name, json.dumps({"format": MANIFEST_FORMAT, "version": 1, "entries": entries},
                                         indent=0, sort_keys=True) + "\n")


def _read_manifest(path: Path) -> Optional[dict[str, int]]:
    if path.is_symlink() or not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    entries = data.get("entries") if isinstance(data, dict) and data.get("format") == MANIFEST_FORMAT else None
    if not isinstance(entries, dict) or not all(isinstance(v, int) for v in entries.values()):
        return None
    return entries


def _drop_derived(tree: dict[str, int], derived: tuple[str, ...]) -> None:
    """Remove from `tree` the top-level entries in `derived` (data the caller regenerates from the
    rest or adds beside it later, e.g. a read cache, a file a later step adds to a bundle): a plain
    file, or a folder that holds plain files and folders only."""
    for top in derived:
        if tree.get(top, _OTHER) >= 0:  # a plain file (listed by its size)
            del tree[top]
            continue
        inside = [rel for rel in tree if rel.startswith(top + "/")]
        if tree.get(top) == _DIR and all(tree[rel] != _OTHER for rel in inside):
            for rel in [top, *inside]:
                del tree[rel]


def _shallowest(paths: list[str]) -> list[str]:
    """The paths not under another of them (a foreign folder is named, not its contents)."""
    chosen = set(paths)
    return sorted(p for p in paths if not any(p.rsplit("/", i)[0] in chosen for i in range(1, p.count("/") + 1)))


def ownership_problem(folder: str | os.PathLike, *, manifest: Optional[str] = None,
                      expected: Optional[dict[str, int]] = None, derived: tuple[str, ...] = ()) -> Optional[str]:
    """Why the existing folder `folder` may not be deleted as one we wrote (one line), or None.

    With `manifest` (a file name): every entry must be listed in that file list, which the build
    that made the folder wrote, with the same kind and (files) the same size; the list missing or
    unreadable is a refusal. Without: every entry must be in `expected` (a `_tree` of the folder
    that replaces it) with the same kind. Entries may be missing; none may be extra or changed.
    """
    folder = Path(folder)
    tree = _tree(folder)
    if manifest is not None:
        listed = _read_manifest(folder / manifest)
        if listed is None:
            return (f"has no list of the files StableMo wrote there ({manifest}: not made by this command, "
                    "or by an older version)")
        tree.pop(manifest, None)
        _drop_derived(tree, derived)
        foreign = [rel for rel, kind in tree.items() if kind == _OTHER or listed.get(rel) != kind]
    else:
        _drop_derived(tree, derived)
        like = expected or {}
        foreign = [rel for rel, kind in tree.items()
                   if kind == _OTHER or rel not in like or (kind == _DIR) != (like[rel] == _DIR)]
    if not foreign:
        return None
    names = _shallowest(foreign)
    more = f" and {len(names) - 3} more" if len(names) > 3 else ""
    return f"holds files StableMo did not write there or that changed since ({', '.join(names[:3])}{more})"


@contextlib.contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """An exclusive flock on `folder` itself for a short critical section (create + lock a build,
    sweep, swap); a no-op where the folder cannot be opened or locks are unsupported."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        yield
        return
    try:
        if fcntl is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _try_lock(path: Path) -> tuple[Optional[int], bool]:
    """(fd, locked): an fd on folder `path` holding an exclusive flock (locked=True), or where
    locks are unsupported an unlocked fd (locked=False); (None, True) if another process holds it."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0))
    if fcntl is None:
        return fd, False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None, True
    except OSError:
        return fd, False
    return fd, True


def _leftover_pattern(target: Path) -> re.Pattern:
    return re.compile(rf"^\.{re.escape(target.name)}\.{_RANDOM}\.(partial|old)$")


def _journal(target: Path) -> Path:
    return target.parent / f".{target.name}.replacing"


def _remove_leftover(path: Path) -> bool:
    """Delete one leftover build/old folder of ours unless a live build holds its lock."""
    try:
        st = path.lstat()
    except OSError:
        return False
    if not path.is_dir() or path.is_symlink() or (hasattr(os, "getuid") and st.st_uid != os.getuid()):
        return False
    try:
        fd, locked = _try_lock(path)
    except OSError:
        return False
    if fd is None:
        return False  # a live build
    if not locked and time.time() - st.st_mtime < UNLOCKABLE_AGE_S:
        os.close(fd)  # no locks here: only an old leftover can be told from a live build
        return False
    try:
        shutil.rmtree(path, ignore_errors=True)
    finally:
        os.close(fd)
    return not os.path.lexists(path)


def _recover(target: Path, keep: Optional[Path] = None) -> list[Path]:
    """Finish what a killed write to `target` left (the caller holds the parent lock): a fallback
    swap cut between its renames gets the old folder back at `target`; leftover partial and old
    folders of `target`'s name that no live build holds are removed, except `keep` (a finished
    build about to be swapped in). Returns what was removed."""
    journal = _journal(target)
    if journal.is_file() and not journal.is_symlink():
        try:
            old_name = json.loads(journal.read_text(encoding="utf-8")).get("old", "")
        except (OSError, ValueError, AttributeError):
            old_name = ""
        old = target.parent / str(old_name)
        if (_leftover_pattern(target).match(old.name) and old.is_dir() and not old.is_symlink()
                and not os.path.lexists(target)):
            _rename(old, target)  # the new folder never arrived: the old one is back, whole
        _unlink_quietly(journal)
    pattern = _leftover_pattern(target)
    removed = []
    with os.scandir(target.parent) as entries:
        candidates = [Path(e.path) for e in entries if pattern.match(e.name) and e.name != getattr(keep, "name", None)]
    for path in candidates:
        if _remove_leftover(path):
            removed.append(path)
    return removed


def recover_dir(target: str | os.PathLike) -> list[Path]:
    """Clean up after killed folder writes to `target` (see `_recover`); what was removed.
    `atomic_dir` calls it before each build, so a later run always tidies an earlier one's kill."""
    target = Path(target)
    if not target.parent.is_dir():
        return []
    with _folder_lock(target.parent):
        return _recover(target)


def _replace_by_renames(new: Path, target: Path) -> None:
    """The fallback swap: target -> .old, new -> target, journaled so that a kill between the two
    renames is undone by the next `_recover` (which puts the old folder back)."""
    old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
    write_text(_journal(target), json.dumps({"old": old.name, "new": new.name}) + "\n", durable=True)
    _rename(target, old)  # replaces the empty folder mkdtemp made
    try:
        _rename(new, target)
    except BaseException:
        _rename(old, target)
        _unlink_quietly(_journal(target))
        raise
    _unlink_quietly(_journal(target))
    shutil.rmtree(old, ignore_errors=True)


def _swap_in(new: Path, target: Path, still_ours: Optional[Callable[[Path], Optional[str]]]) -> None:
    """Put folder `new` at existing folder `target` and delete the old one (parent lock held).
    still_ours(old) is asked again after an atomic exchange, about the old folder at its new
    place: anything that appeared in it since the check puts it back (FileExistsError)."""
    if not exchange(new, target):
        _replace_by_renames(new, target)
        return
    problem = still_ours(new) if still_ours else None  # `new` now names the old folder
    if problem:
        exchange(new, target)
        raise FileExistsError(errno.ENOTEMPTY, problem, str(target))
    shutil.rmtree(new, ignore_errors=True)


def replace_dir(new: str | os.PathLike, target: str | os.PathLike) -> None:
    """Replace folder `target` by folder `new` (a sibling: same file system); the old folder is
    deleted. At every instant `target` names the old folder or the new one (renameat2
    RENAME_EXCHANGE); without that system call, two journaled renames, undone by the next
    `recover_dir(target)` (every `atomic_dir` runs it) if a kill falls between them.
    A missing `target` is simply created. The caller decides that the old folder is its own."""
    new, target = Path(new), Path(target)
    with _folder_lock(target.parent):
        _recover(target, keep=new)
        if not os.path.lexists(target):
            os.rename(new, target)
            return
        _swap_in(new, target, None)


def _move_dir_into_place(tmp: Path, path: Path, replaceable: Optional[Callable[[Path], bool]],
                         manifest: Optional[str], derived: tuple[str, ...]) -> None:
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise FileExistsError(errno.EEXIST, "exists and is not a folder", str(path))
    if not path.exists() or _is_empty_dir(path):
        os.replace(tmp, path)  # rename(2) may replace an empty folder
        return
    if replaceable is None or not replaceable(path):
        raise FileExistsError(errno.ENOTEMPTY, "folder is not empty and is not ours to replace", str(path))
    expected = None if manifest else _tree(tmp)

    def still_ours(folder: Path) -> Optional[str]:
        return ownership_problem(folder, manifest=manifest, expected=expected, derived=derived)

    problem = still_ours(path)
    if problem:
        raise FileExistsError(errno.ENOTEMPTY, problem, str(path))
    _swap_in(tmp, path, still_ours)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, replaceable: Optional[Callable[[Path], bool]] = None,
               manifest: Optional[str] = None, derived: tuple[str, ...] = ()) -> Iterator[Path]:
    """Build a folder that becomes `path` when the block ends without an exception.

    Yields a fresh folder `.<name>.<random>.partial` made exclusively beside `path` (and locked
    until it is in place); write into it (with `atomic_open` etc.). First, leftovers of killed
    writes to `path` are tidied (`recover_dir`). With `manifest` (a file name), the list of every
    file written (and its size) is added as that file at the end. On success the folder is renamed
    to `path` when `path` is absent or an empty folder, or swapped in with `replace_dir` when
    `replaceable(path)` says the existing folder is the caller's kind *and* `ownership_problem`
    finds nothing in it the caller did not write (its `manifest`, or else only names the new folder
    has too; `derived`: top-level files or cache folders that may go with it). Anything else at `path`
    raises FileExistsError (its message says why) and is left untouched. On failure (an exception,
    SIGINT; SIGTERM inside `terminate_as_interrupt`) the temp folder is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _folder_lock(path.parent):
        _recover(path)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
        try:
            lock = _try_lock(tmp)[0]  # held until the block ends: a sweep leaves a live build alone
        except OSError:  # a system that cannot open folders: no lock (the sweep cannot lock it either)
            lock = None
    try:
        yield tmp
        if manifest:
            _write_manifest(tmp, manifest)
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it private (0700)
        with _folder_lock(path.parent):
            _move_dir_into_place(tmp, path, replaceable, manifest, derived)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM and SIGINT raise SystemExit(128 + signal) in the main thread, so
    every `atomic_dir`/`atomic_open` being written removes its temporary before the process ends
    (the default SIGTERM ends it at once, leaving them for the next run's sweep). Elsewhere
    (another thread) a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, _frame):
        raise SystemExit(128 + signum)

    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def default_signals() -> None:
    """For worker processes forked inside `terminate_as_interrupt`: the parent handles the
    interrupt (and terminates them), a worker just ends on SIGTERM and ignores SIGINT."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def same_output(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two output paths are one directory entry, i.e. the second atomic write would replace
    the first: the same name in the same folder (after symlinks and '..' in the folders). A final
    symlink or a hard link is replaced, never written through, so those stay two outputs."""
    a, b = Path(a), Path(b)  # not normalised: "link/.." is the link target's parent, as the kernel sees it
    return a.name == b.name and os.path.realpath(a.parent) == os.path.realpath(b.parent)


# ------------------------------------------------------------------------------ output checks
# Used by the commands *before* any compute: a bad --out must not cost a sampling run.


def _nearest_existing(folder: Path) -> Path:
    for candidate in (folder, *folder.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(".")


def _cannot_write_in(folder: Path) -> Optional[str]:
    """Why files cannot be created in `folder` (an existing path), or None."""
    if folder.is_symlink() and not folder.exists():
        return f"{folder} is a broken symbolic link"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if os.access(folder, os.W_OK | os.X_OK):
        return None
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    return f"{folder} is on a read-only file system" if read_only else f"no permission to write in {folder}"


def output_file_problem(path: str | os.PathLike) -> Optional[str]:
    """Why `path` cannot be written as a file (a one-line reason naming the path), or None.

    Creates nothing. Refused: an existing folder, a path under a regular file, a folder that is
    read-only or not writable (a missing folder is fine when its nearest existing ancestor is writable).
    """
    path = Path(path)
    if path.name in ("", ".", ".."):
        return f"{path}: not a file name"
    if path.is_dir():
        return f"{path}: is an existing folder; give a file name"
    problem = _cannot_write_in(_nearest_existing(path.parent))
    return f"{path}: {problem}" if problem else None


def output_dir_problem(path: str | os.PathLike) -> Optional[str]:
    """Why files cannot be written into folder `path` (one line naming the path), or None.

    Creates nothing. Refused: an existing non-folder, a path under a regular file, a read-only or
    unwritable folder (the nearest existing ancestor when `path` does not exist yet).
    """
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        return f"{path}: exists and is not a folder"
    problem = _cannot_write_in(_nearest_existing(path))
    return f"{path}: {problem}" if problem else None
