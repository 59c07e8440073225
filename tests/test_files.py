"""rbfn.files: several files written all or none even when a signal comes between them, a stop
signal never swallowed inside `signals_raised`, and what is at a path named in a refusal."""

import contextlib
import os
import signal
from pathlib import Path

import pytest

import rbfn.files
from rbfn.files import file_kind, signals_raised, unwritable, write_files


@pytest.fixture(autouse=True)
def _sigint_raises_keyboard_interrupt():
    """SIGINT as Python sets it, whatever handler an earlier test left (rbfn.studies.stop's)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupt_on_first_replace(monkeypatch):
    """os.replace that sends this process SIGINT (Ctrl-C) as it renames the first file."""
    replace = os.replace
    calls = []

    def interrupted(src, dst):
        calls.append(dst)
        if len(calls) == 1:
            signal.raise_signal(signal.SIGINT)
        replace(src, dst)

    monkeypatch.setattr(rbfn.files.os, "replace", interrupted)
    return calls


def test_a_signal_between_two_renames_is_handled_after_both(tmp_path, monkeypatch):
    (tmp_path / "a").write_bytes(b"old a")
    (tmp_path / "b").write_bytes(b"old b")
    calls = _interrupt_on_first_replace(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        write_files({tmp_path / "a": b"new a", tmp_path / "b": b"new b"})
    assert len(calls) == 2  # never one file new and the other old
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == {"a": b"new a", "b": b"new b"}


def test_a_signal_before_the_renames_renames_nothing(tmp_path, monkeypatch):
    (tmp_path / "a").write_bytes(b"old a")
    write = rbfn.files._complete_temp

    def complete_then_interrupted(path, data):
        tmp = write(path, data)
        if path.name == "b":  # the last file written: Ctrl-C just before the renames
            signal.raise_signal(signal.SIGINT)
        return tmp

    monkeypatch.setattr(rbfn.files, "_complete_temp", complete_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_files({tmp_path / "a": b"new a", tmp_path / "b": b"new b", tmp_path / "c": b"new c"})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == {"a": b"old a"}  # no temporary file either


def _swallowed():
    """What torch's exporter may do with Ctrl-C: catch the KeyboardInterrupt and go on."""
    with contextlib.suppress(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)


def _replaced():
    """... or get it back from C++ as another exception."""
    try:
        signal.raise_signal(signal.SIGINT)
    except KeyboardInterrupt as e:
        raise TypeError("incompatible function arguments") from e


@pytest.mark.parametrize("library", [_swallowed, _replaced])
def test_a_stop_signal_is_never_swallowed_inside_signals_raised(library):
    after = []
    with pytest.raises(KeyboardInterrupt), signals_raised() as noted:
        library()
        after.append("went on")
    assert noted == [signal.SIGINT] and after == (["went on"] if library is _swallowed else [])
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is back


def test_an_interrupt_python_ignores_is_raised_on_leaving_and_not_printed(monkeypatch):
    """Raised in a weakref callback (or __del__), KeyboardInterrupt is "Exception ignored": Python
    prints it (sys.unraisablehook) and goes on. Inside signals_raised it is neither printed nor lost."""
    import sys
    import weakref

    class Thing:
        pass

    printed = []
    monkeypatch.setattr(sys, "unraisablehook", printed.append)
    after = []
    with pytest.raises(KeyboardInterrupt), signals_raised():
        thing = Thing()
        ref = weakref.ref(thing, lambda _: signal.raise_signal(signal.SIGINT))
        del thing  # the callback runs, and gets Ctrl-C
        after.append(ref() is None)
    assert after == [True] and printed == []


def test_signals_raised_keeps_other_errors_and_changes_nothing_without_a_signal():
    with pytest.raises(ValueError, match="mine"), signals_raised() as noted:
        raise ValueError("mine")
    with signals_raised() as noted:
        pass
    assert noted == []


def test_unwritable_names_a_dangling_link_on_the_way(tmp_path):
    (tmp_path / "out").symlink_to(tmp_path / "gone")
    problem = unwritable([tmp_path / "out" / "ik.onnx"])
    assert problem == f"{tmp_path / 'out'} is not a directory: it is a dangling symbolic link (to {tmp_path / 'gone'})"
    os.mkfifo(tmp_path / "fifo")
    assert unwritable([tmp_path / "fifo" / "sub" / "ik.onnx"]) == (
        f"{tmp_path / 'fifo'} is not a directory: it is a FIFO (named pipe)"
    )
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    assert unwritable([tmp_path / "loop" / "ik.onnx"]).startswith(f"{tmp_path / 'loop'} is not a directory: it is ")


def test_file_kind(tmp_path):
    (tmp_path / "f").write_text("x")
    (tmp_path / "link").symlink_to(tmp_path / "f")
    assert file_kind(tmp_path / "f") == file_kind(tmp_path / "link") == ""
    assert file_kind(tmp_path / "nothing") is None
    assert file_kind(tmp_path) == "a directory" and file_kind(tmp_path / "f" / "x") is None
    assert file_kind(Path(os.devnull)) == "a character device"
