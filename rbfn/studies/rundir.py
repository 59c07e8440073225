"""A run directory's own bookkeeping: one run at a time, and files written whole.

`RunDir` holds an exclusive lock on the directory (flock on the directory itself, so no file is
added) for as long as a run uses it; a second process given the same directory stops with a
clear message instead of silently sharing or overwriting it. Locks are advisory and local:
processes on other hosts sharing the directory over NFS are not excluded.

A directory Hydra named after the clock (`${now:...}` in hydra.run.dir, as both entry points'
defaults are) belongs to one run: where another process holds it, or it holds any file already
(two runs started in the same second), the run takes NAME_1, NAME_2, ... instead, each made with
mkdir (which fails where another process made it first). A multirun's job directories are its
sweep's and are never moved (a requeued SLURM job resumes in its own). An entry point removes its
run directory again when it leaves it empty, and the empty parents made for it since the process
started (Hydra makes hydra.run.dir with its parents before the run begins), so a refused or failed
run leaves no empty directory behind, nor one holding only its bookkeeping (.hydra/, its log,
TensorBoard event files); a run that fails after writing results keeps them, and its error says
where (`hydra_run_dir`). It writes .hydra/ itself, after its checks (`hydra_run_files`).
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import io
import json
import logging
import math
import os
import re
import shutil
import struct
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, ClassVar, cast

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tensorboard.compat.proto.summary_pb2 import Summary

from ..files import atomic_write_bytes, file_kind

_STARTED = time.time()  # this process's start, near enough: the entry points import this module first
# Whether the user asked for tracebacks (HYDRA_FULL_ERROR=1), read before the entry point asks Hydra
# to raise its errors for it to report in one line (rbfn.studies.cli.run_main).
FULL_ERROR = os.environ.get("HYDRA_FULL_ERROR") == "1"

__all__ = [
    "MadeRunDir",
    "RunDir",
    "RunDirInUse",
    "hydra_run_dir",
    "relabel",
    "hydra_run_files",
    "birth_time",
    "made_since",
    "bookkeeping",
    "remove_new_empty_parents",
    "strict_json",
    "write_figure",
    "write_summary",
    "write_json",
    "write_text",
]


class RunDirInUse(RuntimeError):
    """The run directory belongs to another run: another process holds it, or (for a run that needs
    a directory of its own) it holds files already."""


def _lock(path: Path) -> int | None:
    """A descriptor holding the exclusive lock on directory `path`; None where another process holds
    it or it is gone (removed by its last holder between our open and our lock)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        st, held = os.stat(path), os.fstat(fd)
        if (st.st_dev, st.st_ino) == (held.st_dev, held.st_ino):
            return fd
    except (BlockingIOError, FileNotFoundError):
        pass
    os.close(fd)
    return None


def _is_empty(path: Path) -> bool:
    with os.scandir(path) as entries:
        return next(entries, None) is None


class RunDir:
    """Context manager: this process's exclusive lock on run directory `path` (created if missing).

    `fresh`: `path` was named after the clock; one that another process holds or that holds any file
    is passed over for PATH_1, PATH_2, ... (`.path` is then the directory used). Otherwise a
    directory another process holds is refused (RunDirInUse), and with `own` one holding any file
    too. `tidy`: the directory is removed on exit if it is empty and was made for this run (a directory
    the user made before is kept, with its mode). Re-entrant within a process: a
    directory this process holds already is entered without another lock or check.
    """

    _held: ClassVar[dict[str, RunDir]] = {}  # real path -> the RunDir holding its lock, in this process

    def __init__(self, path: str | Path, fresh: bool = False, own: bool = False, tidy: bool = False) -> None:
        self.path = self._named = Path(path)
        self._fresh, self._own, self._tidy = fresh, own, tidy
        self._fd: int | None = None

    def __enter__(self) -> RunDir:
        if os.path.realpath(self.path) in RunDir._held:
            return self  # the caller holds it (the entry point around its library call)
        for up in (self.path, *self.path.parents):
            if up.exists() and not up.is_dir():
                raise RunDirInUse(
                    f"hydra.run.dir={self.path}: {up} is a file, not a directory; give this run another hydra.run.dir"
                )
        self.path, self._fd = self._take_fresh() if self._fresh else self._take(self.path)
        RunDir._held[os.path.realpath(self.path)] = self
        return self

    def relabel(self, label: str) -> None:
        """A clock-named directory (`fresh`; NAME, or the NAME_1, ... it took) renamed NAME_label, so
        that TensorBoard, which names a run by its directory, tells the runs of different robots
        apart (NAME_label_1, ... where NAME_label is taken). The lock moves with it; a directory the user named is kept.
        Characters other than letters, digits, '.', '_' and '-' in `label` (a URDF's robot name may
        hold any) become '-'."""
        label = re.sub(r"[^A-Za-z0-9._-]", "-", label).strip(".")
        if not self._fresh or self._fd is None or not label:
            return
        # after the clock's name, not a numbered sibling's: NAME_label, then NAME_label_1, ...
        path = next(_claimed(self._named.with_name(f"{self._named.name}_{label}"), 0), None)
        if path is None:
            return
        os.rename(self.path, path)  # onto the empty directory just claimed, which it replaces
        RunDir._held[os.path.realpath(path)] = RunDir._held.pop(os.path.realpath(self.path))
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename).parent == self.path:
                handler.baseFilename = str(path / Path(handler.baseFilename).name)
        self.path = path

    def _take(self, path: Path) -> tuple[Path, int]:
        while True:
            path.mkdir(parents=True, exist_ok=True)
            fd = _lock(path)
            if fd is not None:
                break
            if path.is_dir():
                raise RunDirInUse(
                    f"run directory {path} is in use by another process; wait for it to "
                    "finish, or give this run another hydra.run.dir"
                )
        held = sorted(os.listdir(path)) if self._own else []
        if held:
            os.close(fd)
            raise RunDirInUse(
                f"hydra.run.dir={path} holds files already ({', '.join(held[:4])}"
                f"{', ...' if len(held) > 4 else ''}), which this run would write over; give it a "
                "new or empty hydra.run.dir"
            )
        return path, fd

    def _take_fresh(self) -> tuple[Path, int]:
        self.path.mkdir(parents=True, exist_ok=True)
        fd = _lock(self.path)
        if fd is not None and _is_empty(self.path):
            return self.path, fd
        if fd is not None:
            os.close(fd)
        for path in _claimed(self.path, 1):
            fd = _lock(path)
            if fd is not None:
                return path, fd
        raise RunDirInUse(
            f"run directory {self.path} and its numbered siblings are all taken; give this run another hydra.run.dir"
        )

    def __exit__(self, *exc) -> None:
        if self._fd is None:
            return
        if self._tidy:
            with suppress(OSError):  # removed by someone else meanwhile: nothing to tidy
                if _is_empty(self.path) and made_since(self.path, _STARTED):
                    self.path.rmdir()  # still under the lock: nobody else is starting in it
        del RunDir._held[os.path.realpath(self.path)]
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)
        self._fd = None


def _claimed(base: Path, first: int) -> Iterator[Path]:
    """`base` (from `first` = 0), then base_1, base_2, ... up to base_9999: each made here (mkdir),
    so no other process takes the same one."""
    for n in range(first, 10_000):
        path = base.with_name(f"{base.name}_{n}") if n else base
        try:
            path.mkdir()
        except FileExistsError:
            continue
        yield path


def relabel(out_dir: Path, label: str) -> Path:
    """The run directory `out_dir` this process holds, renamed NAME_label where Hydra named it after
    the clock (`RunDir.relabel`: train.py and evaluate.py label theirs with the robot, once it is
    known); returns the directory used from now on."""
    held = RunDir._held.get(os.path.realpath(out_dir))
    if held is None:
        return out_dir
    held.relabel(label)
    return held.path


@contextmanager
def hydra_run_dir(own: bool = False):
    """The run directory of the Hydra job running now, held (`RunDir`; `own` as there), and tidied:
    yields the directory used, which differs from Hydra's where the clock-named one was taken. The
    job's log file (conf: hydra.job_logging.handlers.file.delay=true, so not opened yet) follows it."""
    hc = HydraConfig.get()
    named = Path(hc.runtime.output_dir)
    fresh = hc.mode == RunMode.RUN and "${now:" in str(cast(dict, OmegaConf.to_container(hc.run))["dir"])
    try:
        with RunDir(named, fresh=fresh, own=own, tidy=True) as run_dir:
            if run_dir.path != named:
                for handler in logging.getLogger().handlers:
                    if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename).parent == named:
                        handler.close()
                        handler.baseFilename = str(run_dir.path / Path(handler.baseFilename).name)
            before = set(os.listdir(run_dir.path))
            try:
                yield run_dir.path
            except BaseException as e:
                _after_failure(e, run_dir.path, before)
                raise
    finally:
        remove_new_empty_parents(named)


def bookkeeping(name: str) -> bool:
    """Whether run-directory entry `name` is bookkeeping, not a result: .hydra/ (the composed config),
    the job's log, TensorBoard event files."""
    return name == ".hydra" or name.endswith(".log") or name.startswith("events.out.tfevents.")


def _after_failure(e: BaseException, path: Path, before: set[str]) -> None:
    """After a run failed in `path` (holding `before` when it started): a directory that was empty and
    got bookkeeping only is emptied (then tidied away); otherwise `e` gets a note naming what the
    run wrote, which is kept."""
    with suppress(OSError):
        wrote = sorted(set(os.listdir(path)) - before)
        if not before and all(bookkeeping(name) for name in wrote):
            for name in wrote:
                (shutil.rmtree if (path / name).is_dir() else os.remove)(path / name)
        elif wrote:
            resume = "; run the same command again to resume it" if "last.pt" in wrote else ""
            results = [name for name in wrote if not bookkeeping(name)]  # its log and config are kept too
            shown = ", ".join(results[:6]) + (", ..." if len(results) > 6 else "")
            note = f"{path} keeps what this run wrote before it stopped ({shown}){resume}"
            # What BaseException.add_note does from Python 3.11 (its traceback prints them), on 3.10 too.
            e.__notes__ = [*getattr(e, "__notes__", []), note]  # type: ignore[attr-defined]


def remove_new_empty_parents(path: Path, since: float | None = None) -> None:
    """Remove `path` and its parents, nearest first, while each is an empty directory created at or
    after `since` (default: this process's start), i.e. made for this run (`made_since`); never the
    working directory or one above it, nor one another process holds (`RunDir`). Each is checked
    and removed under its lock: a run started in the same second may have made the clock's name
    again after this one moved off it (`relabel`), and holds it until it moves off in turn."""
    since = _STARTED if since is None else since
    keep = {Path.cwd().resolve(), *Path.cwd().resolve().parents}
    for d in (path, *path.parents):
        d = d.absolute()
        try:
            if not d.exists():
                continue  # removed already (RunDir's tidy)
            if d.resolve() in keep or not d.is_dir():
                return
            fd = _lock(d)
            if fd is None:
                return  # another process holds it (or removed it just now)
            try:
                if not made_since(d, since) or not _is_empty(d):
                    return
                d.rmdir()  # under the lock: a process taking it after finds it gone (`_lock`)
            finally:
                os.close(fd)
        except OSError:
            return


def made_since(path: Path, since: float) -> bool:
    """Whether directory `path` was created at or after `since` (time.time() seconds): by its birth
    time where the file system records one, else by its last change (an empty directory a user made
    before the run, and left alone since, is never taken for one the run made)."""
    born = birth_time(path)
    return (born if born is not None else os.stat(path).st_mtime) >= since


class _StatxTimestamp(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_int64), ("tv_nsec", ctypes.c_uint32), ("_pad", ctypes.c_int32)]


class _Statx(ctypes.Structure):  # struct statx (linux/stat.h), up to stx_btime, then its spare room
    _fields_ = [
        ("stx_mask", ctypes.c_uint32),
        ("_head", ctypes.c_uint8 * 60),  # blksize, attributes, nlink, uid, gid, mode, ino, size, ...
        ("stx_atime", _StatxTimestamp),
        ("stx_btime", _StatxTimestamp),
        ("_rest", ctypes.c_uint8 * 160),
    ]


def birth_time(path: Path) -> float | None:
    """When `path` was created (Linux statx's btime), in time.time()'s seconds; None where the
    system or the file system does not record it. Unlike the modification time, adding an entry
    to a directory does not change it: a parent that existed before the run keeps its own."""
    statx = getattr(ctypes.CDLL(None, use_errno=True), "statx", None)
    if statx is None:
        return None
    buf = _Statx()
    at_fdcwd, statx_btime = -100, 0x800
    if statx(at_fdcwd, os.fsencode(path), 0, statx_btime, ctypes.byref(buf)) != 0:
        return None
    if not buf.stx_mask & statx_btime:
        return None
    return buf.stx_btime.tv_sec + buf.stx_btime.tv_nsec * 1e-9


class MadeRunDir(Callback):
    """Hydra callback (conf: hydra.callbacks.run_dir): makes the run's directory (a multirun's sweep
    directory) before Hydra would, so that one that cannot be made (a read-only file system, a path
    under a file, a dangling symbolic link or a loop of them, a name too long for the file system)
    ends the command with one line, `error: hydra.run.dir=...: <why>`, and exit status 1 instead of
    Hydra's traceback (with HYDRA_FULL_ERROR=1, the traceback)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        _make_or_exit(config, "run")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        _make_or_exit(config, "sweep")


def _make_or_exit(config: DictConfig, mode: str) -> None:
    key = f"hydra.{mode}.dir"
    try:
        value = str(config.hydra[mode].dir)
    except OmegaConfBaseException:
        return  # an interpolation that does not resolve: Hydra's own error, in one line (run_main)
    path = Path(value)
    try:
        path.mkdir(parents=True, exist_ok=True)
        return
    except OSError as e:
        if FULL_ERROR:
            return  # Hydra's own attempt raises it again, with the traceback
        why = _why_not_made(path, e)
    print(f"error: {key}={value}: cannot make the run directory: {why}; give another {key}", file=sys.stderr)
    sys.exit(1)  # Hydra turns a callback's exception into a warning and goes on


def _why_not_made(path: Path, e: OSError) -> str:
    """What stops directory `path` being made, in words, from the error `e` mkdir gave."""
    if e.errno == errno.ENAMETOOLONG:
        return f"a name in it is too long for the file system ({len(str(path))} characters)"
    for up in reversed((path, *path.parents)):
        try:
            os.stat(up)
        except OSError as err:
            if err.errno == errno.ELOOP:
                return f"{up} is a loop of symbolic links"
            if os.path.islink(up):
                return f"{up} is a symbolic link to {os.readlink(up)}, which does not exist"
            break
        if not up.is_dir():
            return f"{up} is {file_kind(up) or 'a file'}, not a directory"
    where = f" ({e.filename})" if e.filename else ""
    return f"{e.strerror or e}{where}"


def hydra_run_files(dcfg, out_dir: Path) -> dict[str, str]:
    """What Hydra would write to RUN_DIR/.hydra (conf sets hydra.output_subdir=null, so the run
    writes them itself, after its checks: a refused run leaves the directory untouched), with the
    directory actually used as hydra.runtime.output_dir."""
    hc = HydraConfig.get()
    hydra = cast(dict[str, Any], OmegaConf.to_container(hc))
    hydra["runtime"]["output_dir"] = str(out_dir)
    return {
        ".hydra/config.yaml": OmegaConf.to_yaml(dcfg),
        ".hydra/hydra.yaml": OmegaConf.to_yaml(OmegaConf.create({"hydra": hydra})),
        ".hydra/overrides.yaml": OmegaConf.to_yaml(OmegaConf.create(list(hc.overrides.task))),
    }


def strict_json(obj) -> dict | list | float | int | str | bool | None:
    """`obj` with every non-finite float (NaN, inf) replaced by null, so that any JSON parser reads
    it; for a dict, the replaced values are named under "undefined" (dotted key -> why)."""
    undefined: dict[str, str] = {}

    def clean(v, key: str):
        if isinstance(v, float) and not math.isfinite(v):
            undefined[key] = (
                f"{v} is not a number JSON can hold: the value is undefined here (a statistic of "
                "non-finite outputs or of a diverged run)"
            )
            return None
        if isinstance(v, dict):
            return {k: clean(x, f"{key}.{k}" if key else str(k)) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x, f"{key}[{i}]") for i, x in enumerate(v)]
        return v

    out = clean(obj, "")
    if undefined and isinstance(out, dict):
        out["undefined"] = {**out.get("undefined", {}), **undefined}
    return out


def write_json(path: Path, obj) -> None:
    """`obj` as indented, strict JSON at `path` (non-finite numbers as null, see `strict_json`),
    written atomically."""
    text = json.dumps(strict_json(obj), indent=2, allow_nan=False).encode()
    atomic_write_bytes(Path(path), lambda f: f.write(text))


def write_text(path: Path, text: str) -> None:
    """`text` at `path`, written atomically."""
    data = text.encode()
    atomic_write_bytes(Path(path), lambda f: f.write(data))


def write_summary(writer, tag: str, summary: dict | str) -> None:
    """A run's final numbers as one entry `tag` of TensorBoard's Text page, where a scalar each
    would be a chart of one point: a dict's numbers, strings and lists of numbers as a Markdown
    table of metric and value (nested dicts and other values left out), or a str (a table the log
    prints) as it is, in a fixed-width block."""
    if isinstance(summary, str):
        writer.add_text(tag, "```\n" + summary.strip("\n") + "\n```")
        return

    def shown(v: Any) -> str | None:
        if isinstance(v, float):
            return f"{v:.6g}"
        if isinstance(v, (bool, int, str)):
            return str(v)
        if isinstance(v, list) and all(isinstance(x, (int, float)) or x is None for x in v):
            return ", ".join("-" if x is None else f"{x:.4g}" for x in v)
        return None

    rows = [f"| {k} | {text} |" for k, v in summary.items() if (text := shown(v)) is not None]
    writer.add_text(tag, "\n".join(["| metric | value |", "|---|---|", *rows]))


def write_figure(fig, path: Path, dpi: int = 110, writer=None, tag: str = "") -> None:
    """A matplotlib figure as a PNG at `path`, written atomically, and the same PNG as
    TensorBoard's image `tag` when a `writer` is given: rendered and encoded once for both."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    data = buf.getvalue()
    atomic_write_bytes(Path(path), lambda f: f.write(data))
    if writer is not None:
        # The encoded PNG goes into the summary as it is (SummaryWriter.add_image would decode and
        # re-encode it: a quarter of a figure's cost), through the writer's public `file_writer`
        # (None once the writer is closed). Width and height from the PNG's IHDR chunk.
        if writer.file_writer is None:
            raise ValueError(f"write_figure: the SummaryWriter for {tag!r} is closed")
        width, height = struct.unpack(">II", data[16:24])
        image = Summary.Image(height=height, width=width, colorspace=4, encoded_image_string=data)  # RGBA
        writer.file_writer.add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]))
