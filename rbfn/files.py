"""Files written whole: one file (`atomic_write_bytes`), several all or none (`write_files`),
whether a set of paths may be written (`unwritable`), and what is at a path (`file_kind`).

A file is written under a temporary name beside its target and renamed over it once complete, so a
reader never sees half a file and an interrupted write leaves the old file as it was. Where the
system allows (Linux's O_TMPFILE), the temporary file has no name while it is being written and gets
one (NAME.xxxxxxxx.tmp) only once complete, for the rename: a process killed in the middle of a
write, even by SIGKILL, leaves nothing behind. Elsewhere it is named so from the start. Either is
removed on any exception, a signal turned into one included (rbfn.studies.stop). `write_files`
holds the stop signals (SIGINT, SIGTERM, SIGHUP) back until it is done (`signals_raised`), so a
signal never leaves some files renamed and others not, nor a temporary file: one that came before
the renames stops them all, one that comes during them is handled once they are done.

Written files get the permissions a plain open() would give them: those of the file they replace,
else 0o666 minus the umask (mkstemp's 0o600 would hide outputs from the user's group).
"""

from __future__ import annotations

import os
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO, cast

__all__ = ["STOP_SIGNALS", "atomic_write_bytes", "file_kind", "signals_raised", "unwritable", "write_files"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _umask() -> int:
    """The process umask, read without changing it where the OS allows."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _complete_temp(path: Path, write: Callable[[BinaryIO], object]) -> Path:
    """write(file) into a temporary file beside `path`; its name once complete (flushed to disk,
    with the mode `path` has or a new file would get). Nothing is left behind on an error."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = path.stat().st_mode & 0o777
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    tmp = None
    try:
        fd = os.open(path.parent, os.O_TMPFILE | os.O_WRONLY, 0o600) if os.path.isdir("/proc/self/fd") else -1
    except (AttributeError, OSError):  # no O_TMPFILE on this system or file system
        fd = -1
    if fd < 0:
        fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    unnamed = tmp is None
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
            os.fchmod(f.fileno(), mode)
            while unnamed:  # complete: link it in under a fresh temporary name
                tmp = str(path.with_name(f"{path.name}.{os.urandom(4).hex()}.tmp"))
                try:
                    # linkat(AT_SYMLINK_FOLLOW), which a dir fd selects (the absolute path ignores it)
                    os.link(f"/proc/self/fd/{f.fileno()}", tmp, src_dir_fd=f.fileno())
                    unnamed = False
                except FileExistsError:
                    tmp = None
    except BaseException:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise
    return Path(cast(str, tmp))  # named by now


def atomic_write_bytes(path: str | Path, write: Callable[[BinaryIO], object]) -> None:
    """Call write(file) on a temporary file beside `path`, then rename it over `path`."""
    path = Path(path)
    tmp = _complete_temp(path, write)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_files(files: dict[Path, bytes], remove: Iterable[Path] = ()) -> None:
    """Write every file of `files` (path -> content) or none, and remove the files `remove` (an
    output of an earlier run that this one does not make: absent ones are skipped) with them: each
    is written to a temporary file beside it and, once all are complete, the files to remove are
    moved aside, each new one is renamed over its target, and those moved aside are deleted. On an
    error before the renames no target has changed (a file moved aside is put back); no temporary
    file is left in any case. A stop signal (SIGINT, SIGTERM, SIGHUP; main thread) waits for the
    file being written: one that came before the renames renames nothing, one that comes during
    them is handled after the last; either is handled (its KeyboardInterrupt or `Stopped` raised)
    once the temporary files are gone."""
    temps: list[Path] = []
    aside: list[tuple[Path, Path]] = []  # (target, its temporary name)
    done = False
    with signals_raised(defer=True) as noted:
        try:
            for path, data in files.items():
                if noted:
                    break
                temps.append(_complete_temp(Path(path), lambda f, data=data: f.write(data)))  # type: ignore[misc]
            if not noted:
                for path in map(Path, remove):
                    if os.path.lexists(path):
                        moved = path.with_name(f"{path.name}.{os.urandom(4).hex()}.tmp")
                        os.replace(path, moved)
                        aside.append((path, moved))
                for tmp, path in zip(temps, files):
                    os.replace(tmp, path)
                done = True
        finally:
            for tmp in temps:
                tmp.unlink(missing_ok=True)
            for path, moved in aside:
                if done:
                    moved.unlink(missing_ok=True)
                else:
                    os.replace(moved, path)


@contextmanager
def signals_raised(defer: bool = False) -> Iterator[list[int]]:
    """Inside, a stop signal (STOP_SIGNALS) always ends the block with the exception its handler
    raises (KeyboardInterrupt for SIGINT, rbfn.studies.stop's `Stopped`), even where a library
    swallowed it (it is raised again on leaving) or replaced it by another (torch's exporters: a
    KeyboardInterrupt raised in a callback from C++ can come back as a TypeError, and torch.onnx then
    tries its next way to capture the model); one raised where Python ignores exceptions (a weakref
    callback, __del__) is not printed as "Exception ignored", and is raised again on leaving too.
    Yields the signals that came, in order. With `defer`,
    the first signal is handled only on leaving (a signal whose default is to end the process ends
    it then), so that the work inside is never cut in two. Python runs signal handlers in the main
    thread only: elsewhere nothing changes. A signal set to be ignored stays ignored."""
    noted: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield noted
        return
    previous: dict[int, Any] = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    handled = [s for s, h in previous.items() if callable(h) or (defer and h == signal.SIG_DFL)]
    raised: list[BaseException] = []

    def handle(signum: int, frame) -> None:
        if not callable(previous[signum]):  # SIG_DFL, restored by now
            os.kill(os.getpid(), signum)
            return
        try:
            previous[signum](signum, frame)
        except BaseException as e:
            raised.append(e)
            raise

    def note(signum: int, frame) -> None:
        noted.append(signum)
        if not defer:
            handle(signum, frame)

    hook = sys.unraisablehook

    def unraisable(info) -> None:
        if not any(info.exc_value is e for e in raised):
            hook(info)

    for s in handled:
        signal.signal(s, note)
    sys.unraisablehook = unraisable
    error: BaseException | None = None
    try:
        yield noted
    except BaseException as e:  # noqa: BLE001 - raised again below, or replaced by the signal's own
        error = e
    sys.unraisablehook = hook
    for s in handled:
        signal.signal(s, previous[s])
    if defer and noted:
        handle(noted[0], None)
    if raised and error is not raised[0]:  # swallowed, or replaced by another exception
        raise raised[0] from error
    if error is not None:
        raise error


def discard(stream) -> None:
    """Send the rest of what is written to `stream` (stdout, say, whose reader went away: `| head -1`)
    to /dev/null, at the descriptor, so the interpreter's last flush finds nothing broken either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, stream.fileno())
    finally:
        os.close(devnull)


def file_kind(path: Path) -> str | None:
    """What is at `path`, links followed: "" for a regular file, None for nothing, else what it
    is ("a directory", "a FIFO (named pipe)", "a character device", "a dangling symbolic link
    (to ...)", ...), for messages."""
    try:
        mode = path.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return f"a dangling symbolic link (to {os.readlink(path)})" if path.is_symlink() else None
    except OSError as e:  # a loop of links, a name too long, a folder on the way not searchable
        return f"not readable ({e.strerror or e})"
    return mode_kind(mode)


def mode_kind(mode: int) -> str:
    """What a file of (st_)mode `mode` is, in words: "" for a regular file, else "a directory", "a
    FIFO (named pipe)", "a character device", ..., for messages."""
    kinds = (
        (stat.S_ISREG, ""),
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((kind for test, kind in kinds if test(mode)), "not a regular file")


def _write_protected(path: Path) -> bool:
    """No write bit in the mode (which says "keep this" even to root, who may write anything), or no
    write permission for this process."""
    return not path.stat().st_mode & 0o222 or not os.access(path, os.W_OK)


def unwritable(paths: Iterable[str | Path], force: bool = False) -> str:
    """Why the files `paths` cannot or must not be written ('' when they may): a folder on the way
    is a file or one this process cannot write into, a path is a directory, or (unless `force`) an
    existing file or its folder is write-protected."""
    for path in map(Path, paths):
        folder = path.parent
        while file_kind(folder) is None and folder != folder.parent:  # nothing there: made on writing
            folder = folder.parent
        kind = file_kind(folder)
        if kind != "a directory":
            return f"{folder} is not a directory: it is {kind or 'a file'}"
        protected = f"{folder} is a write-protected directory (mode {folder.stat().st_mode & 0o777:#o})"
        if not os.access(folder, os.W_OK | os.X_OK):
            return f"{protected}: this process cannot write into it"
        if not force and _write_protected(folder):
            return f"{protected}; not writing into it (--force does)"
        if path.is_dir():
            return f"{path} is a directory"
        if path.exists() and not force and _write_protected(path):
            return (
                f"{path} is write-protected (mode {path.stat().st_mode & 0o777:#o}); not replacing it "
                "(--force replaces it)"
            )
    return ""
