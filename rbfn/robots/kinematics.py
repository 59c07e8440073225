"""Forward kinematics of any serial URDF through pytorch-kinematics, exact in float64.

pytorch-kinematics' own URDF loader turns origins into float32 transforms (0.8 m becomes
0.800000011920929 m). `load_serial_chain` parses the URDF with pytorch-kinematics' URDF parser
and builds the chain root -> end link itself from `pk.Frame`, `pk.Link`, `pk.Joint` and
`pk.SerialChain`, every offset computed in float64 from the URDF's numbers, so float64 FK is
exact to the URDF text.

Conventions (URDF's): a joint's origin is xyz (m) then fixed-axis roll-pitch-yaw (rad),
R = Rz(yaw) Ry(pitch) Rx(roll); a missing <axis> is (1, 0, 0); `continuous` is a revolute joint
without limits. Supported joint types: revolute, continuous, prismatic, fixed.

A URDF is read from a file (a `pathlib.Path`: a regular file of at most MAX_URDF_BYTES,
decoded by its byte-order mark or XML declaration) or given as its text (a str, never taken
for a file name) or bytes (`urdf_text`). `urdf_tree` is the one place that parses URDF text, for
the kinematics here (`parse_urdf`), the dynamics of `rbfn.robots.dynamics` and MuJoCo's models in
`rbfn.robots.mjcf`: lxml without loading a DTD, external entities or anything from the network,
with libxml2's limits on entity expansion (a "billion laughs" document is refused); meshes and
other referenced files (`package://...`) are never opened.

Why one module of over 500 lines: it is the one place that reads URDF text (the safe
parser every robot module uses) and the float64 chain built from it.
"""

from __future__ import annotations

import codecs
import logging
import math
import os
import re
import reprlib
import stat
import threading
import weakref
from collections.abc import Sequence
from importlib.resources import files
from pathlib import Path
from typing import Any, NamedTuple

import pytorch_kinematics as pk
import torch
from lxml import etree
from pytorch_kinematics.urdf_parser_py.urdf import URDF
from pytorch_kinematics.urdf_parser_py.xml_reflection import core as xml_reflection
from pytorch_kinematics.urdf_parser_py.xml_reflection.core import Path as XmlPath

from ..config import ROBOT_PRESETS

__all__ = [
    "MAX_URDF_BYTES",
    "forward_kinematics",
    "forward_kinematics_pose",
    "jacobian_and_pose",
    "is_urdf_text",
    "joint_limits",
    "load_serial_chain",
    "parse_urdf",
    "read_urdf",
    "urdf_path",
    "urdf_text",
    "urdf_tree",
]

log = logging.getLogger(__name__)
_PARSER_NOTES = threading.Lock()  # the parser's error hook is a module global

MAX_URDF_BYTES = 16 * 2**20
"""Largest URDF read, in bytes (a file, bytes) or characters (text): 16 MiB, 80 times the largest
URDF example-robot-data ships (tiago_dual.urdf, 0.2 MB). Anything larger is refused before it is
read whole, so a device such as /dev/zero cannot exhaust memory."""

# Byte-order marks, longest first (UTF-32-LE's begins with UTF-16-LE's), and the codecs that drop them.
_BOMS = (
    (codecs.BOM_UTF32_LE, "utf-32"),
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF8, "utf-8-sig"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)
# The encoding named by an XML declaration (group 2).
_DECLARED = re.compile(r"""<\?xml[^>]*?\sencoding\s*=\s*(["'])([A-Za-z][\w.:-]*)\1""")

_BLANK = "\ufeff \t\r\n"  # what may precede the first "<" of URDF text: a byte-order mark, whitespace
# What a file that is not a regular one is, for messages.
_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)

_JOINT_TYPES = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic", "fixed": "fixed"}


def urdf_path(name: str) -> Path:
    """Path of a packaged robot's URDF, rbfn/robots/NAME/NAME.urdf, NAME one of
    `rbfn.config.ROBOT_PRESETS` ("scara", "ur5", "panda"; a name, never a path)."""
    if name not in ROBOT_PRESETS:
        raise ValueError(f"name={name!r} is not a URDF shipped with rbfn.robots; allowed: {sorted(ROBOT_PRESETS)}")
    return Path(str(files(f"rbfn.robots.{name}") / f"{name}.urdf"))


def _matrix(origin) -> list[list[float]]:
    """4x4 homogeneous transform of a URDF <origin> (None: identity), in Python floats."""
    x, y, z = (float(v) for v in origin.xyz) if origin is not None and origin.xyz is not None else (0.0, 0.0, 0.0)
    r, p, w = (float(v) for v in origin.rpy) if origin is not None and origin.rpy is not None else (0.0, 0.0, 0.0)
    cr, sr, cp, sp, cw, sw = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(w), math.sin(w)
    return [
        [cw * cp, cw * sp * sr - sw * cr, cw * sp * cr + sw * sr, x],
        [sw * cp, sw * sp * sr + cw * cr, sw * sp * cr - cw * sr, y],
        [-sp, cp * sr, cp * cr, z],
        [0.0, 0.0, 0.0, 1.0],
    ]


def _transform(origin, dtype: torch.dtype) -> pk.Transform3d:
    m = torch.tensor(_matrix(origin), dtype=torch.float64).to(dtype)
    return pk.Transform3d(matrix=m[None], dtype=dtype)


def _too_large(size: int, source: str) -> ValueError:
    return ValueError(
        f"{source}: the URDF has {size} bytes or characters or more; allowed: at most MAX_URDF_BYTES = {MAX_URDF_BYTES}"
    )


def _decode(data: bytes, source: str) -> str:
    """Text of a URDF document's bytes, decoded by its byte-order mark, else by its XML declaration's
    encoding, else as UTF-8. A declaration naming another encoding is rewritten to name UTF-8: the
    text is handed on (to lxml, MuJoCo, checkpoints) as UTF-8."""
    if len(data) > MAX_URDF_BYTES:
        raise _too_large(len(data), source)
    declared = _DECLARED.match(data[:1024].decode("latin-1"))
    encoding = next((codec for bom, codec in _BOMS if data.startswith(bom)), declared.group(2) if declared else "utf-8")
    try:
        text = data.decode(encoding)
    except (LookupError, UnicodeDecodeError) as e:
        raise ValueError(
            f"{source}: cannot decode the URDF as {encoding!r} ({e}); allowed: an encoding "
            f"Python knows, named by a byte-order mark or the XML declaration "
            f"(UTF-8 without either)"
        ) from None
    declared = _DECLARED.match(text)
    if declared and declared.group(2).upper() != "UTF-8":
        text = text[: declared.start(2)] + "UTF-8" + text[declared.end(2) :]
    return text


def read_urdf(path: str | os.PathLike) -> str:
    """Text of the URDF file at `path`, decoded as `_decode` says.

    Only a regular file of at most MAX_URDF_BYTES is read: a directory, FIFO or device is refused
    by what it is (ValueError) before any read (opening does not block); FileNotFoundError if
    there is nothing at `path`.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file; allowed: a regular file") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
            raise ValueError(f"{path} is {kind}, not a regular file; allowed: a regular file")
        with open(fd, "rb", closefd=False) as f:
            data = f.read(MAX_URDF_BYTES + 1)
    finally:
        os.close(fd)
    return _decode(data, str(path))


def is_urdf_text(urdf: str) -> bool:
    """Whether a str is (meant as) URDF text: its first character past a byte-order mark and
    whitespace is "<". Anything else is not, whatever file it might name."""
    return urdf.lstrip(_BLANK).startswith("<")


def urdf_text(urdf: str | bytes | os.PathLike, source: str | None = None) -> tuple[str, str]:
    """(text, source) of a URDF file (a `pathlib.Path` or other path object, read by `read_urdf`),
    the URDF's text (a str: never taken for a file name) or its bytes (decoded by their BOM or XML
    declaration). `source` names the URDF in messages (default: the file, "URDF text" or "URDF
    bytes")."""
    if isinstance(urdf, os.PathLike):
        return read_urdf(urdf), source or str(urdf)
    if isinstance(urdf, bytes):
        return _decode(urdf, source or "URDF bytes"), source or "URDF bytes"
    if isinstance(urdf, str):
        return urdf, source or "URDF text"
    raise TypeError(
        f"urdf={reprlib.repr(urdf)} is a {type(urdf).__name__}; allowed: a pathlib.Path, "
        "the URDF's text (str) or its bytes"
    )


def urdf_tree(text: str, source: str, inertials: bool = False) -> etree._Element:
    """The <robot> element of URDF `text`, pruned to what kinematics and dynamics use; ValueError
    naming `source` when it is no URDF document.

    Parsed as UTF-8 whatever the XML declaration says (a str has no encoding), without a leading
    byte-order mark or whitespace; comments and processing instructions are dropped, and so is all
    but the <joint> elements, the <link> elements' names and, with `inertials`, their <inertial>
    (geometry and its mesh files, materials, transmissions: whatever pytorch-kinematics' parser
    would trip over or MuJoCo would open). The parser is lxml's default made explicit: internal
    entities only, no DTD, no network, no huge trees.
    """
    if len(text) > MAX_URDF_BYTES:
        raise _too_large(len(text), source)
    text = text.lstrip(_BLANK)
    if not text.startswith("<"):
        from_file = os.path.isfile(str(source))  # the text was read from that file
        hint = "" if from_file else " (a string is never read as a file name: pass a pathlib.Path for a file)"
        raise ValueError(
            f"{source}: {reprlib.repr(text)} is not URDF text; allowed: XML whose root element is <robot>{hint}"
        )
    parser = etree.XMLParser(
        encoding="utf-8",
        resolve_entities="internal",
        load_dtd=False,
        no_network=True,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    try:
        root = etree.fromstring(text.encode("utf-8"), parser)
    except etree.XMLSyntaxError as e:
        raise ValueError(f"{source}: malformed URDF: {' '.join(str(e).split())}") from e
    if etree.QName(root).localname != "robot":
        raise ValueError(f"{source}: malformed URDF: the root element is <{root.tag}>; a URDF's is <robot>")
    for child in list(root):
        if child.tag == "link":
            for part in list(child):
                if not (inertials and part.tag == "inertial"):
                    child.remove(part)
        elif child.tag != "joint":
            root.remove(child)
    _check_numbers(root, source)
    return root


# Numeric attributes of the elements `urdf_tree` keeps; lengths (m) beyond MAX_LENGTH are refused.
_NUMBERS = (
    "xyz",
    "rpy",
    "lower",
    "upper",
    "effort",
    "velocity",
    "damping",
    "friction",
    "value",
    "ixx",
    "ixy",
    "ixz",
    "iyy",
    "iyz",
    "izz",
)
MAX_LENGTH = 1e3


def _check_numbers(root: etree._Element, source: str) -> None:
    """ValueError naming the element and attribute of a non-finite number or a length beyond
    MAX_LENGTH m (text that is no number is left to the parser's own message). Masses and inertias
    are physics, checked by the dynamics (`rbfn.robots.dynamics.Arm.problems`): the kinematics
    need none of them."""
    for el in root.iter():
        for key in _NUMBERS:
            text = el.get(key)
            if text is None:
                continue
            try:
                values = [float(v) for v in text.split()]
            except ValueError:
                continue
            owner = el
            while owner.tag not in ("joint", "link") and owner.getparent() is not None:
                owner = owner.getparent()
            where = f'<{el.tag} {key}="{text}"> of {owner.tag} {owner.get("name")!r}'
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"{source}: {where}: allowed are finite numbers")
            if el.tag == "origin" and key == "xyz" and max(map(abs, values), default=0.0) > MAX_LENGTH:
                raise ValueError(f"{source}: {where}: allowed are offsets within {MAX_LENGTH:g} m")


def parse_urdf(text: str, source: str, inertials: bool = False) -> URDF:
    """The URDF of `text` (joints, links and, with `inertials`, their inertials), pruned and parsed
    as `urdf_tree` says; ValueError naming `source` when it is no URDF."""
    root = urdf_tree(text, source, inertials)
    notes: list[str] = []
    try:
        # The parser writes a line to stderr for each attribute or tag it does not know (a real
        # URDF's <robot version="1.0">, a vendor's extension), on every parse: kept for the log's
        # debug level instead, once a parse.
        with _PARSER_NOTES:
            xml_reflection.on_error = notes.append
            try:
                robot = URDF.from_xml(root, XmlPath(URDF.XML_REFL.tag, tree=etree.ElementTree(root)))
            finally:
                xml_reflection.on_error = xml_reflection.on_error_stderr
    except Exception as e:  # the parser's ParseError, AssertionError, ...
        msg = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{source}: malformed URDF: {msg}") from e
    if notes:
        log.debug("%s: the URDF parser passed over %d item(s): %s", source, len(notes), "; ".join(notes))
    if robot is None or not robot.links:
        raise ValueError(f"{source}: malformed URDF: no <robot> with <link> elements")
    return robot


def _path_to(robot: URDF, source: str, end_link: str) -> list:
    """URDF joints from the single root link down to `end_link`, root first."""
    links = [link.name for link in robot.links]
    if end_link not in robot.link_map:
        raise ValueError(f"{source}: end_link {end_link!r} is not a link of the URDF; links: {sorted(links)}")
    dup = sorted({n for n in links if links.count(n) > 1})
    if dup:
        raise ValueError(f"{source}: links defined more than once: {dup}")
    parent_joint: dict[str, Any] = {}
    for j in robot.joints:
        for end in (j.parent, j.child):
            if end not in robot.link_map:
                raise ValueError(
                    f"{source}: joint {j.name!r} names link {end!r}, which is not defined; links: {sorted(links)}"
                )
        if j.child in parent_joint:
            raise ValueError(
                f"{source}: link {j.child!r} is the child of two joints "
                f"({parent_joint[j.child].name!r}, {j.name!r}); a URDF is a tree"
            )
        parent_joint[j.child] = j
    roots = [n for n in links if n not in parent_joint]
    if len(roots) != 1:
        what = (
            "no root link (the joints form a cycle)"
            if not roots
            else f"{len(roots)} root links {roots} (links not connected by joints)"
        )
        raise ValueError(f"{source}: the URDF must be one tree with one root link; it has {what}")
    path, link, seen = [], end_link, {end_link}
    while link != roots[0]:
        joint = parent_joint[link]
        link = joint.parent
        if link in seen:
            raise ValueError(
                f"{source}: joints form a cycle through link {link!r}; no path from root {roots[0]!r} to {end_link!r}"
            )
        seen.add(link)
        path.append(joint)
    return path[::-1]


def _joint(j, source: str, dtype: torch.dtype) -> pk.Joint:
    if j.type not in _JOINT_TYPES:
        raise ValueError(
            f"{source}: joint {j.name!r} ({j.parent} -> {j.child}) is of type "
            f"{j.type!r}; supported on the chain: {sorted(_JOINT_TYPES)}"
        )
    axis = [float(v) for v in (j.axis if j.axis is not None else (1.0, 0.0, 0.0))]
    if j.type != "fixed" and not any(axis):
        raise ValueError(f"{source}: joint {j.name!r} has a zero axis")
    limits = velocity = effort = None
    if j.limit is not None:
        if j.type in ("revolute", "prismatic"):
            limits = (float(j.limit.lower), float(j.limit.upper))
            if limits[0] > limits[1]:
                raise ValueError(f"{source}: joint {j.name!r} has lower limit {limits[0]} > upper limit {limits[1]}")
        if j.limit.velocity is not None:
            velocity = (-float(j.limit.velocity), float(j.limit.velocity))
        if j.limit.effort is not None:
            effort = (-float(j.limit.effort), float(j.limit.effort))
    return pk.Joint(
        j.name,
        offset=_transform(j.origin, dtype),
        joint_type=_JOINT_TYPES[j.type],
        axis=torch.tensor(axis, dtype=torch.float64),
        dtype=dtype,
        limits=limits,
        velocity_limits=velocity,
        effort_limits=effort,
    )


def load_serial_chain(
    urdf: str | bytes | os.PathLike,
    end_link: str,
    dtype: torch.dtype = torch.float64,
    device: str | torch.device = "cpu",
    source: str | None = None,
) -> pk.SerialChain:
    """Serial chain from the URDF's root link to `end_link`, frames named after the links.

    `urdf` and `source` are as `urdf_text` takes them: a file (a `pathlib.Path`), the URDF's text
    (a str: never taken for a file name) or its bytes; `source` names it in messages. Offsets are exact to
    the URDF's numbers in float64 (rounded once to `dtype`). Raises ValueError (naming `source`)
    for a malformed URDF, an unknown `end_link`, a URDF that is not one tree, or a floating/planar
    joint on the path.
    """
    text, source = urdf_text(urdf, source)
    robot = parse_urdf(text, source)
    path = _path_to(robot, source, end_link)
    root_name = path[0].parent if path else end_link
    root = pk.Frame(root_name, link=pk.Link(root_name), joint=pk.Joint(dtype=dtype))
    frame = root
    for j in path:
        child = pk.Frame(j.child, link=pk.Link(j.child), joint=_joint(j, source, dtype))
        frame.children = [child]
        frame = child
    chain = pk.SerialChain(pk.Chain(root, dtype=dtype), end_link, dtype=dtype)
    return chain.to(dtype=dtype, device=device)


class _Step(NamedTuple):
    """One frame of a serial chain in turned frames (each joint's frame turned so that its axis is
    z, as `axis_frame` turns it): the fixed transform from the parent's turned frame, rotation F
    (3, 3) and offset o (3,), as `move` = [F^T; o^T] (4, 3), then its joint about or along z: kind
    (0 fixed, 1 revolute, 2 prismatic) and its index among the chain's joints."""

    move: torch.Tensor
    kind: int
    joint: int


FK_BLOCK = 4096  # rows a block of `forward_kinematics_pose` and `jacobian_and_pose`
_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # chain -> {(dtype, device): steps}


def axis_frame(axis: torch.Tensor) -> torch.Tensor:
    """A rotation Q (3, 3), float64, whose z column is the unit vector along `axis` (3,): a turn
    about `axis` by q is Q Rz(q) Q^T, a slide along it Q (0, 0, q)."""
    z = axis.to(torch.float64) / axis.norm()
    trial = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    if abs(float(z[0])) > 0.9:
        trial = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    x = trial - trial.dot(z) * z
    x = x / x.norm()
    return torch.stack([x, torch.linalg.cross(z, x), z], 1)


def _steps(chain: pk.SerialChain, dtype: torch.dtype | None = None) -> list[_Step]:
    """The chain's frames root -> end link as `_Step`s in `dtype` (None: the chain's) and on its
    device (cached per chain, dtype and device): runs of fixed frames folded into the next, each joint's frame
    turned by Q = `axis_frame(axis)` (T = F Q Rz(q) Q^T F' ... : the fixed transform before a joint
    takes Q on its right, the one after it Q^T on its left), and a last fixed step that turns the
    end link's frame back."""
    key = (dtype or chain.dtype, chain.device)
    hit = _STEPS.setdefault(chain, {}).get(key)
    if hit is not None:
        return hit
    names = chain.get_joint_parameter_names()
    eye = torch.eye(4, dtype=torch.float64)

    def matrix(offset) -> torch.Tensor:
        return eye if offset is None else offset.get_matrix()[0].to(device="cpu", dtype=torch.float64)

    frames = []  # (fixed transform (4, 4), kind, joint index, axis) in the URDF's frames, float64
    for name in chain.get_frame_names(exclude_fixed=False):
        f = chain.find_frame(name)
        link, joint = matrix(f.link.offset), matrix(f.joint.offset)
        kind = ("fixed", "revolute", "prismatic").index(f.joint.joint_type)
        index = names.index(f.joint.name) if kind else -1
        frames.append((link @ joint, kind, index, f.joint.axis.to(device="cpu", dtype=torch.float64).reshape(3)))
    steps: list[_Step] = []
    pending = torch.eye(4, dtype=torch.float64)  # fixed transforms not yet folded, from the last turned frame
    for t, kind, index, axis in frames:
        pending = pending @ t
        if not kind:
            continue
        q = axis_frame(axis)
        steps.append(_Step(torch.cat([(pending[:3, :3] @ q).T, pending[None, :3, 3]]), kind, index))
        pending = torch.eye(4, dtype=torch.float64)
        pending[:3, :3] = q.T
    if not steps or not torch.equal(pending, torch.eye(4, dtype=torch.float64)):
        steps.append(_Step(torch.cat([pending[:3, :3].T, pending[None, :3, 3]]), 0, -1))
    kw: dict[str, Any] = {"dtype": key[0], "device": key[1]}
    steps = [st._replace(move=st.move.to(**kw)) for st in steps]
    _STEPS[chain][key] = steps
    return steps


def _chain_pass(chain: pk.SerialChain, th: torch.Tensor, jacobian: bool):
    """(end-link poses (B, 4, 4), and with `jacobian` the geometric Jacobian (B, 6, n_joints) in the
    root frame (linear velocity, then angular) or None) for joints th (B, n_joints)."""
    th = th.to(dtype=chain.dtype, device=chain.device)
    b = th.shape[0]
    if b > FK_BLOCK:  # blocks that stay in cache
        parts = [_chain_pass(chain, t, jacobian) for t in th.split(FK_BLOCK)]
        return torch.cat([p for p, _ in parts]), torch.cat([j for _, j in parts]) if jacobian else None
    rot, pos, jac = compose(_steps(chain), th, jacobian)
    row = th.new_zeros(b, 1, 4)
    row[:, 0, 3] = 1.0  # the homogeneous row [0, 0, 0, 1]
    return torch.cat([torch.cat([rot, pos[:, :, None]], 2), row], 1), jac


def compose(steps: Sequence[_Step], th: torch.Tensor, jacobian: bool):
    """(end-link rotations (B, 3, 3), positions (B, 3), and with `jacobian` the geometric Jacobian
    (B, 6, n_joints) or None) for joints th (B, n_joints), from a chain's `_Step`s: the frames
    composed in order, each a fixed transform, then its joint's turn about z or slide along z.

    Batch last: the rotation is held as its columns (3, 3, B) and the position as (3, B), so a fixed
    transform is one product (4, 3) @ (3, 3 B) with the batch as its long side, and a turn about z
    mixes two columns elementwise (on the UR5 at 4 096 rows, one thread: the pose and Jacobian
    1.2 ms, against 4.3 ms batch first with 3x3 products and Rodrigues' formula, as it was). Plain
    tensor operations, no in-place writes and no data-dependent branches, so torch.export and the
    ONNX exporter take it (`rbfn.graph_polish`)."""
    b, n = th.shape
    q = th.transpose(0, 1)  # (n, B)
    cos, sin = q.cos(), q.sin()
    cols = torch.eye(3, dtype=th.dtype, device=th.device)[:, :, None].expand(3, 3, b)  # column k (3, B) at [k]
    pos = th.new_zeros(3, b)
    axes: dict[int, tuple[int, torch.Tensor, torch.Tensor]] = {}  # joint -> (kind, axis (3, B), origin (3, B))
    for st in steps:
        moved = st.move @ cols.reshape(3, 3 * b)  # (4, 3 B): the columns times F, then R o
        pos = pos + moved[3].reshape(3, b)
        cols = moved[:3].reshape(3, 3, b)
        if st.kind == 0:
            continue
        z = cols[2]  # the joint's axis in the root frame
        if st.kind == 1:  # R Rz(q): columns (c x + s y, c y - s x, z)
            c, s = cos[st.joint], sin[st.joint]
            cols = torch.stack([c * cols[0] + s * cols[1], c * cols[1] - s * cols[0], z])
        else:
            pos = pos + q[st.joint] * z
        axes[st.joint] = (st.kind, z, pos)
    rot, pos_b = cols.permute(2, 1, 0), pos.transpose(0, 1)
    if not jacobian:
        return rot, pos_b, None
    zero = th.new_zeros(3, b)
    kinds, zs, origins = zip(*(axes.get(j, (0, zero, zero)) for j in range(n)))  # a joint without a frame: 0
    z = torch.stack(zs, 1)  # (3, n, B)
    if any(k == 1 for k in kinds):
        d = pos[:, None] - torch.stack(origins, 1)
        lin = torch.stack([z[1] * d[2] - z[2] * d[1], z[2] * d[0] - z[0] * d[2], z[0] * d[1] - z[1] * d[0]])
    else:
        lin = z
    if any(k != 1 for k in kinds):  # a prismatic joint moves the end link along its axis and turns nothing
        revolute = torch.tensor([float(k == 1) for k in kinds], dtype=th.dtype, device=th.device)[:, None]
        lin, ang = revolute * lin + (1.0 - revolute) * z, revolute * z
    else:
        ang = z
    return rot, pos_b, torch.cat([lin, ang]).permute(2, 0, 1)


def forward_kinematics_pose(chain: pk.SerialChain, th: torch.Tensor) -> torch.Tensor:
    """End-link poses (B, 4, 4) in the root link's frame (m) for `th` (B, n_joints) (rad or m).

    [:, :3, :3] is the rotation matrix, [:, :3, 3] the position. The chain's frames composed in
    order, each a fixed transform then its joint's turn or slide (`compose`): pytorch-kinematics'
    transforms to rounding (tested), many times faster on CPU (no 4x4 products per frame, the
    batch last; measured on the UR5: see docs/benchmarks_ik.md).
    """
    return _chain_pass(chain, th, jacobian=False)[0]


def jacobian_and_pose(chain: pk.SerialChain, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(the geometric Jacobian (B, 6, n_joints) in the root frame: the end link's linear velocity (m
    per rad, or per m) above its angular velocity; the end-link poses (B, 4, 4)) for `th` (B,
    n_joints): pytorch-kinematics' `SerialChain.jacobian` to rounding (tested), from the same pass
    as `forward_kinematics_pose`."""
    pose, jac = _chain_pass(chain, th, jacobian=True)
    assert jac is not None
    return jac, pose


def forward_kinematics(chain: pk.SerialChain, th: torch.Tensor) -> torch.Tensor:
    """End-effector positions (B, 3) in m for joint values `th` (B, n_joints) (rad or m)."""
    return forward_kinematics_pose(chain, th)[:, :3, 3]


def joint_limits(chain: pk.SerialChain) -> tuple[torch.Tensor, torch.Tensor]:
    """(low, high) joint limits from the URDF, each (n_joints,) float64, rad or m.

    Continuous joints (and revolute/prismatic joints without <limit>) have no limits and give
    (-inf, inf): any angle is valid, so every finite joint box passes a check against them;
    take a continuous joint's sampling range from config (one turn, [-pi, pi], covers it).
    """
    low, high = chain.get_joint_limits()
    return (torch.as_tensor(low, dtype=torch.float64), torch.as_tensor(high, dtype=torch.float64))
