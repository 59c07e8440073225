"""Forward kinematics of any serial URDF through pytorch-kinematics, exact in float64.

pytorch-kinematics' own URDF loader turns origins into float32 transforms (0.8 m becomes
0.800000011920929 m). `load_serial_chain` parses the URDF with pytorch-kinematics' URDF parser
and builds the chain root -> end link itself from `pk.Frame`, `pk.Link`, `pk.Joint` and
`pk.SerialChain`, every offset computed in float64 from the URDF's numbers, so float64 FK is
exact to the URDF text.

Conventions (URDF's): a joint's origin is xyz (m) then fixed-axis roll-pitch-yaw (rad),
R = Rz(yaw) Ry(pitch) Rx(roll); a missing <axis> is (1, 0, 0); `continuous` is a revolute joint
without limits. Supported joint types: revolute, continuous, prismatic, fixed.
"""
from __future__ import annotations

import math
from importlib.resources import files
from pathlib import Path

import pytorch_kinematics as pk
import torch
from pytorch_kinematics.urdf_parser_py.urdf import URDF

__all__ = ["load_serial_chain", "forward_kinematics", "forward_kinematics_pose", "joint_limits",
           "urdf_path"]

_JOINT_TYPES = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic",
                "fixed": "fixed"}


def urdf_path(name: str) -> Path:
    """Path of a URDF shipped with rbfn.robots: "scara", "ur5" or "panda"."""
    path = Path(str(files("rbfn.robots") / f"{name}.urdf"))
    if not path.is_file():
        shipped = sorted(p.stem for p in path.parent.glob("*.urdf"))
        raise ValueError(f"no URDF named {name!r} in rbfn.robots; shipped: {shipped}")
    return path


def _matrix(origin) -> list[list[float]]:
    """4x4 homogeneous transform of a URDF <origin> (None: identity), in Python floats."""
    x, y, z = (float(v) for v in origin.xyz) if origin is not None and origin.xyz is not None \
        else (0.0, 0.0, 0.0)
    r, p, w = (float(v) for v in origin.rpy) if origin is not None and origin.rpy is not None \
        else (0.0, 0.0, 0.0)
    cr, sr, cp, sp, cw, sw = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(w), math.sin(w)
    return [[cw * cp, cw * sp * sr - sw * cr, cw * sp * cr + sw * sr, x],
            [sw * cp, sw * sp * sr + cw * cr, sw * sp * cr - cw * sr, y],
            [-sp, cp * sr, cp * cr, z],
            [0.0, 0.0, 0.0, 1.0]]


def _transform(origin, dtype: torch.dtype) -> pk.Transform3d:
    m = torch.tensor(_matrix(origin), dtype=torch.float64).to(dtype)
    return pk.Transform3d(matrix=m[None], dtype=dtype)


def _parse(urdf: str | Path) -> tuple[URDF, str]:
    """Parsed URDF and a name for messages (the file, or "URDF text")."""
    if isinstance(urdf, Path) or not str(urdf).lstrip().startswith("<"):
        source = str(urdf)
        text = Path(urdf).read_text()
    else:
        source, text = "URDF text", str(urdf)
    try:
        robot = URDF.from_xml_string(text)
    except Exception as e:  # lxml's XMLSyntaxError, the parser's ParseError, AssertionError
        msg = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{source}: malformed URDF: {msg}") from e
    if robot is None or not robot.links:
        raise ValueError(f"{source}: malformed URDF: no <robot> with <link> elements")
    return robot, source


def _path_to(robot: URDF, source: str, end_link: str) -> list:
    """URDF joints from the single root link down to `end_link`, root first."""
    links = [link.name for link in robot.links]
    if end_link not in robot.link_map:
        raise ValueError(f"{source}: end_link {end_link!r} is not a link of the URDF; links: "
                         f"{sorted(links)}")
    dup = sorted({n for n in links if links.count(n) > 1})
    if dup:
        raise ValueError(f"{source}: links defined more than once: {dup}")
    parent_joint: dict[str, object] = {}
    for j in robot.joints:
        for end in (j.parent, j.child):
            if end not in robot.link_map:
                raise ValueError(f"{source}: joint {j.name!r} names link {end!r}, which is not "
                                 f"defined; links: {sorted(links)}")
        if j.child in parent_joint:
            raise ValueError(f"{source}: link {j.child!r} is the child of two joints "
                             f"({parent_joint[j.child].name!r}, {j.name!r}); a URDF is a tree")
        parent_joint[j.child] = j
    roots = [n for n in links if n not in parent_joint]
    if len(roots) != 1:
        what = "no root link (the joints form a cycle)" if not roots else \
            f"{len(roots)} root links {roots} (links not connected by joints)"
        raise ValueError(f"{source}: the URDF must be one tree with one root link; it has {what}")
    path, link, seen = [], end_link, {end_link}
    while link != roots[0]:
        joint = parent_joint[link]
        link = joint.parent
        if link in seen:
            raise ValueError(f"{source}: joints form a cycle through link {link!r}; "
                             f"no path from root {roots[0]!r} to {end_link!r}")
        seen.add(link)
        path.append(joint)
    return path[::-1]


def _joint(j, source: str, dtype: torch.dtype) -> pk.Joint:
    if j.type not in _JOINT_TYPES:
        raise ValueError(f"{source}: joint {j.name!r} ({j.parent} -> {j.child}) is of type "
                         f"{j.type!r}; supported on the chain: {sorted(_JOINT_TYPES)}")
    axis = [float(v) for v in (j.axis if j.axis is not None else (1.0, 0.0, 0.0))]
    if j.type != "fixed" and not any(axis):
        raise ValueError(f"{source}: joint {j.name!r} has a zero axis")
    limits = velocity = effort = None
    if j.limit is not None:
        if j.type in ("revolute", "prismatic"):
            limits = (float(j.limit.lower), float(j.limit.upper))
            if limits[0] > limits[1]:
                raise ValueError(f"{source}: joint {j.name!r} has lower limit {limits[0]} > "
                                 f"upper limit {limits[1]}")
        if j.limit.velocity is not None:
            velocity = (-float(j.limit.velocity), float(j.limit.velocity))
        if j.limit.effort is not None:
            effort = (-float(j.limit.effort), float(j.limit.effort))
    return pk.Joint(j.name, offset=_transform(j.origin, dtype), joint_type=_JOINT_TYPES[j.type],
                    axis=torch.tensor(axis, dtype=torch.float64), dtype=dtype, limits=limits,
                    velocity_limits=velocity, effort_limits=effort)


def load_serial_chain(urdf: str | Path, end_link: str, dtype: torch.dtype = torch.float64,
                      device: str | torch.device = "cpu") -> pk.SerialChain:
    """Serial chain from the URDF's root link to `end_link`, frames named after the links.

    `urdf` is a file path or URDF text. Offsets are exact to the URDF's numbers in float64
    (rounded once to `dtype`). Raises ValueError (naming the file) for a malformed URDF, an
    unknown `end_link`, a URDF that is not one tree, or a floating/planar joint on the path.
    """
    robot, source = _parse(urdf)
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


def forward_kinematics_pose(chain: pk.SerialChain, th: torch.Tensor) -> torch.Tensor:
    """End-link poses (B, 4, 4) in the root link's frame (m) for `th` (B, n_joints) (rad or m).

    [:, :3, :3] is the rotation matrix, [:, :3, 3] the position.
    """
    th = th.to(dtype=chain.dtype, device=chain.device)
    return chain.forward_kinematics(th, end_only=True).get_matrix()


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
