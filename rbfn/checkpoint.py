"""Checkpoints: a plain dict that `torch.load(weights_only=True)` reads, written atomically.

Keys: format_version, kind, package_version, model_args, state_dict, robot (URDF text, end
link, joint names and sampled range), config (plain data), metrics. The zip archive's comment
holds the SHA-256 of the archive, so any changed byte is caught before unpickling; the file is
still a plain torch.save archive that `torch.load(path, weights_only=True)` reads. Reading
checks everything evaluation relies on (robot entry, shapes, finite weights) up front, so a bad
file fails with a message naming it instead of deep inside evaluation.

Why one module of over 500 lines: a checkpoint's writing, sealing and every check on reading
it sit together, so what a reader relies on is checked where it is written.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
import pickle
import re
import reprlib
import zipfile
from pathlib import Path
from typing import Any

import torch

from . import memory
from .files import atomic_write_bytes, file_kind
from .layer import MIN_WIDTH, RBFNetwork
from .robots.robot import robot_from_record
from .targets import TargetFeatures

__all__ = [
    "FORMAT_VERSION",
    "KIND",
    "CHARTS_KIND",
    "check_charts",
    "MIN_WIDTH",
    "ONNX_MODEL",
    "PT2_PROGRAM",
    "TORCH_ARCHIVE",
    "file_format",
    "load_model",
    "load_sealed",
    "local_file",
    "model_from_checkpoint",
    "network_record",
    "read_checkpoint",
    "refuse_url",
    "save_checkpoint",
    "save_sealed",
]

FORMAT_VERSION = 1
KIND = "rbfn-ik"
CHARTS_KIND = "rbfn-ik-charts"  # a charted network's checkpoint (robot.workspace=full, rbfn.charts)
TRAIN_STATE_KIND = "rbfn-train-state"  # rbfn.resume's last.pt, sealed the same way
_REQUIRED = ("format_version", "kind", "model_args", "state_dict", "robot")
_ROBOT_KEYS = ("urdf", "end_link", "joint_low", "joint_high")
_MODEL_ARGS = ("num_centers", "in_features", "out_features", "tail")
# Trained-region buffers of RBFNetwork: this infinity means "unbounded" (no set_domain yet).
_UNBOUNDED = {
    "in_low": -math.inf,
    "out_low": -math.inf,
    "in_high": math.inf,
    "out_high": math.inf,
    "cover_radius": math.inf,
}
_ADVICE = "Re-run training or restore the file from a copy."
MAX_SEALED_BYTES = 2 << 30  # read whole before unpickling: a larger file is refused before it is read
MAX_PICKLE_BYTES = 64 << 20  # a sealed file's data.pkl: the URDF text (at most 16 MiB), config, metrics


_SEAL = b"aco-rbfn-sha256:"
_SEAL_LEN = len(_SEAL) + 64
_EOCD = b"PK\x05\x06"  # zip end-of-central-directory record: 22 bytes + comment


def seal(data: bytes) -> bytes:
    """Put the SHA-256 of a zip archive `data` (no comment) into its end-of-directory comment."""
    if len(data) < 22 or data[-22:-18] != _EOCD or data[-2:] != b"\x00\x00":
        raise ValueError("expected a zip archive without a comment")
    comment = _SEAL + hashlib.sha256(data).hexdigest().encode()
    return data[:-2] + len(comment).to_bytes(2, "little") + comment


def _zip_comment(data: bytes) -> bytes | None:
    """The comment of zip archive `data`; None when no end record closes the data (truncated)."""
    start = max(0, len(data) - 22 - 0xFFFF)
    i = data.rfind(_EOCD, start)
    while i >= 0:
        if i + 22 <= len(data) and int.from_bytes(data[i + 20 : i + 22], "little") == len(data) - i - 22:
            return data[i + 22 :]
        i = data.rfind(_EOCD, start, i)
    return None


def unseal(data: bytes, path: Path, what: str = "checkpoint", advice: str = _ADVICE) -> bytes:
    """The archive as written before sealing; ValueError if any byte of `data` changed.

    Tells apart a damaged file (no zip end record, damaged seal, checksum mismatch) from a
    valid zip archive that never had the seal (written by another program).
    """
    comment = _zip_comment(data)
    if comment is None:
        why = "it is empty" if not data else "it does not end with a zip archive's end record"
        raise ValueError(f"{path} is not a readable {what} (truncated or corrupted?): {why}. {advice}")
    if not comment.startswith(_SEAL) or len(comment) != _SEAL_LEN:
        # One changed byte in the seal's prefix still leaves a comment of the seal's length.
        if len(comment) == _SEAL_LEN and sum(a != b for a, b in zip(comment, _SEAL)) <= 2:
            raise ValueError(f"{path} is corrupted: its checksum seal is damaged. {advice}")
        raise ValueError(
            f"{path} is not an aco-rbfn {what}: it has no aco-rbfn seal (a zip archive "
            f"written by another program, or by torch.save directly). {advice}"
        )
    original = data[: -_SEAL_LEN - 2] + b"\x00\x00"
    if hashlib.sha256(original).hexdigest().encode() != comment[len(_SEAL) :]:
        raise ValueError(f"{path} is corrupted: its bytes do not match its SHA-256 checksum. {advice}")
    return original


def save_checkpoint(
    path: str | Path, model: RBFNetwork, robot: dict[str, Any], config: dict[str, Any], metrics: dict[str, Any]
) -> None:
    """Write the checkpoint dict for `model` to `path` atomically."""
    from . import __version__

    ckpt = {
        "format_version": FORMAT_VERSION,
        "kind": KIND,
        "package_version": __version__,
        **network_record(model),
        "robot": robot,
        "config": config,
        "metrics": metrics,
    }
    save_sealed(path, ckpt)


def network_record(model: RBFNetwork) -> dict[str, Any]:
    """{"model_args", "state_dict"}: what rebuilds `model` (`model_from_checkpoint`), plain data."""
    return {
        "model_args": {
            "num_centers": model.num_centers,
            "in_features": model.centers.shape[1],
            "target": model.target,
            "out_features": model.head.out_features,
            "tail": model.tail is not None,
            "redundancy": bool(model.inputs is not None and model.inputs.redundancy),
        },
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }


def save_sealed(path: str | Path, obj: Any) -> None:
    """torch.save `obj` (plain data and tensors) to `path`, sealed and atomically."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    sealed = seal(buf.getvalue())
    atomic_write_bytes(Path(path), lambda f: f.write(sealed))


def _refused_global(message: str) -> str | None:
    """The global that weights-only unpickling refused, from torch's message, if it names one."""
    m = re.search(r"GLOBAL (\S+) (?:was not an allowed global|whose module)", message)
    return m.group(1) if m else None


_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://")
# Where a file of an export is given to a checkpoint's reader: what to give instead.
_EXPORT_ADVICE = (
    "exports run without aco-rbfn (docs/deployment.md); rbfn.load_model, rbfn.load_solver, evaluate.py "
    "and python -m rbfn.export read the checkpoint.pt they were exported from"
)
ONNX_MODEL = "an ONNX model (an export such as ik.onnx)"
PT2_PROGRAM = "a torch.export program (an export such as ik.pt2)"
TORCH_ARCHIVE = "a torch.save archive (a checkpoint such as checkpoint.pt)"


def refuse_url(path: object, name: str) -> None:
    """ValueError when `path`, as given (`name` names it in the message), is a URL: aco-rbfn reads
    and writes files on disk only (as a path, a URL's "//" would fold into a local name)."""
    if isinstance(path, str) and _URL.match(path):
        raise ValueError(
            f"{name} is a URL; aco-rbfn reads and writes local files only, never downloading or uploading: "
            "give a local path (download the file first)"
        )


def file_format(data: bytes) -> str | None:
    """Which of the files aco-rbfn writes `data` looks like, for messages: ONNX_MODEL, PT2_PROGRAM
    (a zip archive naming its format "pt2"), TORCH_ARCHIVE (a zip archive with a data.pkl record);
    None for anything else. A file can look like one and still be damaged: this only names it."""
    if data[:4] == b"PK\x03\x04":
        try:
            with zipfile.ZipFile(io.BytesIO(data)) as z:
                names = {n.rpartition("/")[2]: n for n in z.namelist()}
                if "archive_format" in names and z.read(names["archive_format"]).strip() == b"pt2":
                    return PT2_PROGRAM
        except Exception:  # noqa: BLE001 - a damaged archive raises various errors; its reader reports it
            return None
        return TORCH_ARCHIVE if "data.pkl" in names else None
    try:
        import onnx

        model = onnx.ModelProto()
        model.ParseFromString(data)
    except Exception:  # noqa: BLE001 - not protobuf (DecodeError), or no onnx installed
        return None
    return ONNX_MODEL if model.ir_version > 0 and model.HasField("graph") else None


def local_file(path: str | os.PathLike[str], what: str = "checkpoint") -> Path:
    """`path` as a Path, checked to name a regular file (or a link to one) before anything opens it:
    TypeError for a value that is no path, ValueError for a URL (never fetched), an empty path, a
    directory, FIFO, device, socket or dangling link, each named; FileNotFoundError where nothing is."""
    if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes):
        raise TypeError(
            f"{what} path {reprlib.repr(path)} is of type {type(path).__name__}; "
            "expected a file path (str or pathlib.Path)"
        )
    refuse_url(path, str(path))
    if not os.fspath(path):
        raise ValueError(f"an empty path names no {what}; give the {what} file's path")
    path = Path(path)
    kind = file_kind(path)
    if kind is None:
        unexpanded = " (~ is not expanded: give the full path)" if str(path).startswith("~") else ""
        raise FileNotFoundError(f"no {what} at {path}{unexpanded}")
    if kind:
        raise ValueError(f"{path} is {kind}, not a {what}: a {what} is a regular file")
    return path


def _record_problem(data: bytes, what: str) -> str | None:
    """What is wrong with the records of zip archive `data` before torch.load reads them, if
    anything: a compressed record (torch.load would inflate it, up to about 1000 times its size,
    before anything could check it; torch.save stores every record whole), or a pickle (data.pkl)
    larger than MAX_PICKLE_BYTES (unpickling can make some 70 bytes of objects of each of its bytes)."""
    try:
        infos = zipfile.ZipFile(io.BytesIO(data)).infolist()
    except Exception:  # noqa: BLE001 - a damaged directory: torch.load reports it
        return None
    for i in infos:
        if i.compress_type != zipfile.ZIP_STORED:
            return (
                f"its record {i.filename} is compressed ({i.compress_size} B inflating to {i.file_size} B); "
                f"aco-rbfn stores every record of a {what} uncompressed, as torch.save does"
            )
        if i.filename.rpartition("/")[2] == "data.pkl" and i.file_size > MAX_PICKLE_BYTES:
            return (
                f"its pickled part {i.filename} holds {i.file_size} B; a {what}'s (its config, metrics and URDF text, "
                f"the tensors apart) is at most MAX_PICKLE_BYTES = {MAX_PICKLE_BYTES} B"
            )
    return None


def _overdeclared(obj: Any) -> tuple[str, torch.Tensor] | None:
    """The first tensor in `obj` (nested dicts, lists, tuples) that declares more values than its
    data holds (an expanded, stride-0 view: small on disk, its full size once anything copies
    it), or that is not dense; with where it is (its keys, space-separated)."""
    todo: list[tuple[Any, str]] = [(obj, "")]
    while todo:
        item, where = todo.pop()
        if isinstance(item, torch.Tensor):
            if item.layout != torch.strided or item.numel() * item.element_size() > item.untyped_storage().nbytes():
                return where, item
        elif isinstance(item, dict):
            todo.extend((v, f"{where} {k}".strip()) for k, v in reversed(item.items()))
        elif isinstance(item, (list, tuple)):
            todo.extend((v, f"{where} {i}".strip()) for i, v in reversed(list(enumerate(item))))
    return None


def load_sealed(path: str | os.PathLike[str], what: str = "checkpoint", advice: str = _ADVICE) -> Any:
    """What `save_sealed` wrote at `path` (weights-only unpickling); clear errors when damaged.

    `what` names the file's role and `advice` says what to do about a bad file, in messages;
    callers set them because the remedy differs (retrain for a checkpoint, delete a state).
    Before anything is allocated for it, the file is checked to be a regular file of at most
    MAX_SEALED_BYTES, none of aco-rbfn's exports, sealed, with its records stored uncompressed;
    after unpickling (which makes tensors as views of the records' bytes), every tensor is
    checked to be dense and to hold every value its shape declares.
    """
    path = local_file(path, what)
    size = path.stat().st_size
    if size > MAX_SEALED_BYTES:
        raise ValueError(
            f"{path} holds {size / 2**30:.3g} GiB; a {what} aco-rbfn writes is at most "
            f"{MAX_SEALED_BYTES / 2**30:g} GiB (tens of MB at M = 2000), so this is not one. {advice}"
        )
    data = path.read_bytes()
    export = file_format(data)
    if export in (ONNX_MODEL, PT2_PROGRAM):
        raise ValueError(f"{path} is {export}, not a {what}: {_EXPORT_ADVICE}")
    data = unseal(data, path, what, advice)
    problem = _record_problem(data, what)
    if problem:
        raise ValueError(f"{path}: {problem}, so it did not write this file. {advice}")
    try:
        obj = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - truncated or corrupted archives raise various errors
        text = str(e)
        if isinstance(e, pickle.UnpicklingError) and ("Weights only" in text or "WeightsUnpickler" in text):
            name = _refused_global(text)
            refused = f" (refused global: {name})" if name else ""
            raise ValueError(
                f"{path} holds objects other than tensors and plain data{refused}, which "
                f"aco-rbfn refuses to unpickle for safety: unpickling them can run "
                f"arbitrary code. {advice}"
            ) from None
        unsafe = "weights_only" in text  # torch's advice to load unsafely: never passed on
        detail = "" if unsafe else f": {text.strip().rstrip('.')}"
        raise ValueError(f"{path} is not a readable {what} (truncated or corrupted?){detail}. {advice}") from (
            None if unsafe else e
        )
    bad = _overdeclared(obj)
    if bad is not None:
        where, t = bad
        if t.layout != torch.strided:
            raise ValueError(
                f"{path}: {where} is a {t.layout} tensor of shape {tuple(t.shape)}; aco-rbfn writes dense "
                f"tensors only, so it did not write this file. {advice}"
            )
        held = t.untyped_storage().nbytes() // t.element_size()
        raise ValueError(
            f"{path}: {where} declares shape {tuple(t.shape)} ({t.numel():,} values, "
            f"{t.numel() * t.element_size():,} bytes), but the file holds {held:,} "
            f"value{'s' * (held != 1)} for it (an expanded or overlapping tensor); aco-rbfn writes every value "
            f"of a tensor, so it did not write this file. {advice}"
        )
    return obj


def _model_problem(ckpt: dict[str, Any]) -> str | None:
    """What keeps the checkpoint's model_args and state_dict from making a working RBFNetwork."""
    a, sd = ckpt.get("model_args"), ckpt.get("state_dict")
    if not isinstance(a, dict) or any(k not in a for k in _MODEL_ARGS):
        missing = [k for k in _MODEL_ARGS if not isinstance(a, dict) or k not in a]
        return f"model_args lacks {missing}; a checkpoint's model_args has {list(_MODEL_ARGS)}"
    m, d, out, tail = (a[k] for k in _MODEL_ARGS)
    for k in _MODEL_ARGS[:3]:
        if isinstance(a[k], bool) or not isinstance(a[k], int) or a[k] < 1:
            return f"model_args {k}={a[k]!r}; expected a positive integer"
    if not isinstance(tail, bool):
        return f"model_args tail={tail!r}; expected True or False"
    if not isinstance(sd, dict):
        return f"state_dict is a {type(sd).__name__}; expected a dict of tensors"
    expected = {
        "offset": (d,),
        "scale": (d,),
        "centers": (m, d),
        "widths": (m,),
        "head.weight": (out, m),
        "head.bias": (out,),
        "in_low": (d,),
        "in_high": (d,),
        "out_low": (out,),
        "out_high": (out,),
        "cover_radius": (),
    }
    if tail:
        expected["tail.weight"] = (out, d)
    pose = a.get("target", "position") == "pose"
    if a.get("target", "position") not in ("position", "pose"):
        return f"model_args target={a['target']!r}; expected 'position' or 'pose'"
    redundancy = a.get("redundancy", False)
    if not isinstance(redundancy, bool) or (redundancy and not pose):
        return f"model_args redundancy={redundancy!r}; expected True (pose targets only) or False"
    if d != (9 if pose else 3) + redundancy:
        return (
            f"model_args in_features={d} with target={a.get('target', 'position')!r} and redundancy={redundancy}; "
            f"allowed: {(9 if pose else 3) + redundancy} features"
        )
    if pose:
        expected["inputs.rotation_scale"] = ()
    missing, unexpected = sorted(set(expected) - set(sd)), sorted(set(sd) - set(expected))
    if missing or unexpected:
        return f"state_dict does not match model_args {a}: missing keys {missing}, unexpected keys {unexpected}"
    for k, shape in expected.items():
        t = sd[k]
        if not isinstance(t, torch.Tensor) or not t.is_floating_point():
            kind = f"a {t.dtype} tensor" if isinstance(t, torch.Tensor) else f"a {type(t).__name__}"
            return f"state_dict {k} is {kind}; expected a floating-point tensor"
        if tuple(t.shape) != shape:
            return f"state_dict {k} has shape {tuple(t.shape)}, but model_args {a} give {shape}"
    try:  # the network copies every tensor (in float64) before anything else runs
        memory.check_fits(
            "model_args num_centers",
            m,
            sum(t.numel() for t in sd.values()) * memory.FLOAT64,
            what="the network's weights in float64",
            advice="load it on a machine with more free memory",
        )
    except ValueError as e:
        return str(e)
    for k, t in sd.items():
        bad = torch.isnan(t) | (torch.isinf(t) & (t != _UNBOUNDED.get(k, math.nan)))
        if bool(bad.any()):
            allowed = f" (only {_UNBOUNDED[k]}, meaning unbounded, is allowed there)" if k in _UNBOUNDED else ""
            return (
                f"non-finite weights in {k}: {int(torch.isnan(t).sum())} NaN and "
                f"{int(bad.sum()) - int(torch.isnan(t).sum())} inf of {t.numel()} values{allowed}; "
                "the fit diverged or the file was altered. Retrain"
            )
    if not bool((sd["widths"] >= MIN_WIDTH).all()):
        return (
            f"state_dict widths has minimum {sd['widths'].min().item():.3g}; allowed: widths of at least "
            f"MIN_WIDTH = {MIN_WIDTH:g} (scaled input units), below which a Gaussian is 0 but at its centre"
        )
    for k in ("scale", "inputs.rotation_scale"):
        if k in sd and not bool((sd[k] > 0).all()):
            return f"state_dict {k} has minimum {sd[k].min().item():.3g}; allowed: positive input scales"
    if not float(sd["cover_radius"]) >= 0:
        return f"state_dict cover_radius is {float(sd['cover_radius']):.3g}; allowed: a radius >= 0 (inf: unbounded)"
    return None


def check_charts(ckpt: dict[str, Any], path: str | Path) -> dict[str, Any]:
    """The charted checkpoint dict `ckpt` read from `path`, checked (format, each chart network's
    parts, the robot entry), or a ValueError naming the file and what is wrong
    (`read_checkpoint` reads the file and calls this for a charted one)."""
    if ckpt.get("format_version") != FORMAT_VERSION:
        got = ckpt.get("format_version")
        raise ValueError(f"{path} has checkpoint format {got!r}; this aco-rbfn reads {FORMAT_VERSION}")
    charts, nets = ckpt.get("charts"), ckpt.get("networks")
    keys = ("centres", "revolute", "low", "high")
    if not isinstance(charts, dict) or any(not isinstance(charts.get(k), torch.Tensor) for k in keys):
        raise ValueError(f"{path}: its charts entry needs the tensors {list(keys)}")
    if not isinstance(nets, list) or len(nets) != charts["centres"].shape[0]:
        raise ValueError(f"{path}: networks must be a list of one network per chart ({charts['centres'].shape[0]})")
    for i, rec in enumerate(nets):
        try:
            model_from_checkpoint(rec)
        except (ValueError, TypeError, AttributeError) as e:
            raise ValueError(f"{path}: chart {i}: {e}") from e
    for k in ("robot", "config", "metrics"):
        if k not in ckpt:
            raise ValueError(f"{path} is missing the checkpoint key {k!r}")
    try:
        robot_from_record(ckpt["robot"])
    except (ValueError, TypeError) as e:
        raise ValueError(f"{path}: {e}") from e
    return ckpt


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict at `path`, checked for format, kind, shapes and finite weights, and its robot
    entry field by field (`robot_from_record`: the URDF text parses, never read as a file name), so
    a bad file fails here with a ValueError naming it and the field."""
    ckpt = load_sealed(path)  # the path as given: a URL is refused, not folded into a file name
    path = Path(path)
    if not isinstance(ckpt, dict):
        raise ValueError(
            f"{path} holds a {type(ckpt).__name__}, not a checkpoint dict; it was not written "
            "by aco-rbfn's save_checkpoint"
        )
    if ckpt.get("kind") == TRAIN_STATE_KIND:
        raise ValueError(
            f"{path} is a training state (last.pt of an unfinished or finished run), not a "
            f"checkpoint; the trained network is in checkpoint.pt of the same run directory "
            f"({path.parent / 'checkpoint.pt'}), written when the run finishes"
        )
    if ckpt.get("kind") == CHARTS_KIND:  # robot.workspace=full's charted network
        return check_charts(ckpt, path)
    if "kind" in ckpt and ckpt["kind"] != KIND:
        raise ValueError(f"{path} holds a {ckpt['kind']!r} model, not an IK network ({KIND!r})")
    if "format_version" in ckpt and ckpt["format_version"] != FORMAT_VERSION:
        raise ValueError(
            f"{path} has checkpoint format {ckpt['format_version']}, this aco-rbfn reads "
            f"format {FORMAT_VERSION}; use the aco-rbfn version "
            f"{ckpt.get('package_version', '?')} that wrote it, or retrain"
        )
    missing = [k for k in _REQUIRED if k not in ckpt]
    if missing:
        raise ValueError(
            f"{path} is missing checkpoint keys {missing}; checkpoints written by train.py "
            f"have {list(_REQUIRED)}. Retrain to get a complete checkpoint"
        )
    robot = ckpt["robot"]
    missing = [k for k in _ROBOT_KEYS if not isinstance(robot, dict) or k not in robot]
    if missing:
        raise ValueError(
            f"{path}: its robot entry is missing keys {missing}; evaluation needs "
            f"{list(_ROBOT_KEYS)} to rebuild the robot. Retrain to get a complete checkpoint"
        )
    problem = _model_problem(ckpt)
    if problem:
        raise ValueError(f"{path}: {problem}")
    try:
        robot_from_record(robot)  # every field, and the URDF text parsed (never opened as a file)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e
    a = ckpt["model_args"]
    if a["out_features"] != len(robot["joint_low"]) or a.get("target", "position") != robot.get("target", "position"):
        raise ValueError(
            f"{path}: model_args out_features={a['out_features']}, target={a.get('target', 'position')!r} "
            f"do not fit the robot entry; allowed: one output per free joint "
            f"({len(robot['joint_low'])}) and its target {robot.get('target', 'position')!r}"
        )
    if a.get("redundancy", False) != bool(robot.get("redundancy", "")):
        raise ValueError(
            f"{path}: model_args redundancy={a.get('redundancy', False)} does not fit the robot entry's "
            f"redundancy={robot.get('redundancy', '')!r}; allowed: True exactly where the robot names a joint"
        )
    return ckpt


def model_from_checkpoint(ckpt: dict[str, Any]) -> RBFNetwork:
    """Rebuild the RBFNetwork of a checkpoint dict (or a `network_record`), in eval mode; ValueError
    if its parts disagree."""
    if ckpt.get("kind") == CHARTS_KIND:
        raise ValueError(
            "this checkpoint holds a charted network (robot.workspace=full): rbfn.load_solver(PATH) answers with it; "
            "rbfn.export exports it; one box network (load_model, online adaptation) comes from robot.workspace=box"
        )
    problem = _model_problem(ckpt)
    if problem:
        raise ValueError(f"cannot rebuild the network from this checkpoint: {problem}")
    sd, a = ckpt["state_dict"], ckpt["model_args"]
    inputs = (
        TargetFeatures(pose=True, dtype=sd["centers"].dtype, redundancy=a.get("redundancy", False))
        if a.get("target") == "pose"
        else None
    )
    model = RBFNetwork(sd["centers"], sd["widths"], a["out_features"], tail=a["tail"], inputs=inputs)
    model.load_state_dict(sd)
    return model.eval().requires_grad_(False)


_LOAD_DTYPES = (torch.float32, torch.float64)


def load_model(path: str | Path, dtype: torch.dtype = torch.float32) -> RBFNetwork:
    """The IK network saved at `path`, in eval mode, in `dtype`: torch.float32 (the default, for
    inference: fast, and within ~1e-5 (rad, m) of float64) or torch.float64 (the precision it was
    fitted in, e.g. to reproduce its metrics).

    Input: positions (B, 3) in m (any real dtype; computed in `dtype`). Output: joints (B, 3)
    (rad, rad, m). `model.in_workspace(x)` / `model.solve(x)` flag positions outside the trained
    workspace.
    """
    if not isinstance(dtype, torch.dtype) or dtype not in _LOAD_DTYPES:
        raise ValueError(f"load_model(dtype={dtype!r}): allowed are torch.float32 (the default) and torch.float64")
    return model_from_checkpoint(read_checkpoint(path)).to(dtype)
