"""robot=urdf: every robot key a user's arm leaves out, derived from its URDF, in one place.

    python train.py robot=urdf robot.urdf=PATH robot.end_link=LINK [+robot.locked.JOINT=VALUE ...]

conf/robot/urdf.yaml sets `robot.derive` and leaves the keys below at their markers;
`derive_robot` fills each from the arm (root -> end_link, `rbfn.robots.dynamics.Arm`) and logs one
line per key, saying what it chose and why ("given" for a key the user gave, which always wins):

* name: the URDF's <robot name="...">.
* target: `pose` for 6 free joints (the chain less robot.locked), `position` for 3; other counts
  are refused (`rbfn.robots.robot.check_ik_is_function`, or too few joints), naming the way out.
* home: the middle of each free joint's limits (0 for a joint without limits, e.g. continuous),
  unless the box around it is ill-conditioned (a singularity runs through it: the 5 % quantile of
  the task Jacobian's smallest to largest singular value over the box below CONDITIONED); then the
  nearest of CANDIDATES seeded candidates around the middle whose box is twice as well
  conditioned (none: the best of them); `conditioned_home`.
* joint_low / joint_high: home +- robot.box_halfwidth (rad, or m for a prismatic joint), clipped to
  the limits; given a box without a home, home is the box centre.
* gravity: 9.81 m/s^2 (standard gravity).
* rated_payload: the largest point mass (kg, 2 significant digits, rounded down) at the end link
  whose static gravity torque at home stays within PAYLOAD_MARGIN of every joint's URDF effort
  limit (where a payload loads no joint at home, an arm pointing straight up: at home and
  BOX_SAMPLES seeded joint vectors in the box); the control part's payload cases are 0, half and
  all of it. 0 where the URDF's inertials are unusable for dynamics (`Arm.problems`: a warning
  says so; the IK trains, the closed loop refuses the arm).
* control_rate, encoder_counts: 500 Hz and 2^20 counts per revolution (per metre, prismatic) on
  every chain joint, typical values, for the realistic loop.

A home at a singular configuration (where the box around it holds more than one IK branch) is
warned of (`warn_if_singular`).

`derive_sizes` fills the training sizes conf/sizing/urdf.yaml leaves at its markers (by the target
kind), `derive_train` / `derive_evaluate` apply both to a whole config: rbfn.studies.training and
rbfn.studies.evaluation call them before any check. Robots without `robot.derive` (the presets)
pass through unchanged.

Why one module of over 500 lines: every key robot=urdf derives, each rule beside the ones it
depends on (home, box, payload), so the log reads in the order the keys are chosen.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from ..config import ROBOT_PRESETS, EvalConfig, RobotConfig, Target, TrainConfig, Trajectory
from .dynamics import Arm, load_arm, urdf_source
from .kinematics import urdf_tree
from .registry import closed_form
from .robot import Robot, check_ik_is_function, check_joint_values, load_robot

__all__ = [
    "CONTROL_RATE",
    "ENCODER_COUNTS",
    "GRAVITY",
    "PAYLOAD_MARGIN",
    "SIZES",
    "CONDITIONED",
    "box_conditioning",
    "conditioned_home",
    "Sizes",
    "derive_evaluate",
    "derive_robot",
    "derive_sizes",
    "derive_train",
    "load_urdf_arm",
    "rated_payload",
    "warn_if_singular",
]

log = logging.getLogger(__name__)

GRAVITY = 9.81  # m/s^2, standard gravity
PAYLOAD_MARGIN = 0.5  # the rated payload's gravity torque at home: at most this share of each effort limit
BOX_SAMPLES = 128  # seeded joint vectors in a box: its conditioning and its payload bound
CONDITIONED = 5e-3  # a box's 5 % quantile of sigma_min / sigma_max below this: a singularity runs through it
CANDIDATES = 256  # homes tried around the middle of the limits where its box is ill-conditioned
CONTROL_RATE = 500.0  # Hz: a typical controller cycle (the UR e-Series' 500 Hz)
ENCODER_COUNTS = 2**20  # per revolution (per metre, prismatic): a typical 20-bit joint encoder


@dataclass(frozen=True)
class Sizes:
    """Training sizes: centres, the first M of the growth (0: none), samples per split."""

    num_centers: int
    growth_start: int
    n_train: int
    n_val: int
    n_test: int


# By target kind: the UR5's sizes (conf/sizing/ur5.yaml) for pose arms (6 free joints at most),
# the SCARA's (conf/sizing/scara.yaml) for position arms (3 at most). tests/robots/test_derive.py
# checks they equal those files.
SIZES = {
    Target.pose: Sizes(num_centers=2000, growth_start=0, n_train=20000, n_val=5000, n_test=10000),
    Target.position: Sizes(num_centers=80, growth_start=10, n_train=2000, n_val=1000, n_test=5000),
}


def load_urdf_arm(cfg: RobotConfig) -> tuple[Arm, str]:
    """(the arm root -> cfg.end_link of the file cfg.urdf, the URDF's <robot name>); ValueError
    naming robot.urdf / robot.end_link when either is missing or wrong."""
    if not cfg.urdf:
        raise ValueError("robot.urdf='' is not allowed: robot=urdf needs the arm's URDF file, robot.urdf=PATH")
    path = Path(cfg.urdf)
    try:
        text, source = urdf_source(path)
        root = urdf_tree(text, source)
    except (FileNotFoundError, ValueError) as e:
        raise type(e)(f"robot.urdf={cfg.urdf!r}: {e}") from None
    if not cfg.end_link:
        raise ValueError(
            "robot.end_link='' is not allowed: robot=urdf needs the chain's last link, robot.end_link=LINK, "
            f"one of the links of {cfg.urdf}: {sorted(str(link.get('name')) for link in root.iter('link'))}"
        )
    try:
        arm = load_arm(path, end_link=cfg.end_link, gravity=GRAVITY if cfg.gravity is None else cfg.gravity)
    except ValueError as e:
        raise ValueError(f"robot.urdf={cfg.urdf!r} (robot.end_link={cfg.end_link!r}): {e}") from None
    arm.warn_notes(log, f"robot.urdf={cfg.urdf}")
    if arm.problems:  # the IK needs no dynamics: it trains; the closed loop refuses the arm
        log.warning(
            "robot.urdf=%s: the closed loop (evaluate.py's control part) cannot simulate this arm's dynamics "
            "and will refuse it; the IK needs none and trains: %s",
            cfg.urdf,
            arm.problems[0],
        )
    return arm, str(root.get("name") or path.stem)


def rated_payload(arm: Arm, home: torch.Tensor, margin: float = PAYLOAD_MARGIN) -> tuple[float, str]:
    """(the largest point mass in kg at the arm's end link whose static gravity torque at every
    joint vector of `home` ((n,), or (S, n): home and samples of its box) stays within `margin` of
    every joint's effort limit, 2 significant digits rounded down; the joint and vector that bound
    it, in words). G(q, m) = G0 + m G1 is affine in the mass m, so per joint and vector
    |G0_j + m G1_j| <= margin e_j holds up to m_j = (margin e_j - sign(G1_j) G0_j) / |G1_j|.
    ValueError where the URDF gives no effort limit on the joints gravity loads."""
    q = home.to(torch.float64).reshape(-1, arm.n)
    g0 = arm.gravity(q)  # (S, n) N m (N)
    g1 = arm.gravity(q, 1.0) - g0  # N m per kg
    bound = margin * arm.effort_limits()
    loaded = (g1.abs() > 1e-9) & torch.isfinite(bound)
    if not bool(loaded.any()):
        raise ValueError(
            "robot.rated_payload: no joint is both loaded by a payload in the box (gravity "
            f"{arm.gravity_vector.tolist()} m/s^2) and limited by a URDF effort (effort "
            f"{arm.effort_limits().tolist()}); give robot.rated_payload=KG"
        )
    per = torch.where(loaded, (bound - g1.sign() * g0) / g1.abs(), torch.full_like(g1, math.inf))
    i, j = divmod(int(per.argmin()), arm.n)
    m = max(float(per[i, j]), 0.0)
    if m > 0:
        step = 10.0 ** (math.floor(math.log10(m)) - 1)
        m = math.floor(m / step + 1e-9) * step
        m = float(f"{m:.2g}")
    unit = "N" if arm.prismatic[j] else "N m"
    where = "at home" if i == 0 else "in the box, at " + str([round(v, 3) for v in q[i].tolist()])
    why = (
        f"{arm.joint_names[j]} {where} holds {abs(float(g0[i, j])):.3g} {unit} "
        f"unloaded and {abs(float(g0[i, j] + m * g1[i, j])):.3g} with it, of its effort limit "
        f"{float(arm.effort_limits()[j]):.3g}; at most {margin:.0%} of every joint's limit"
        + (f", at home and {q.shape[0] - 1} joint vectors in the box" if q.shape[0] > 1 else "")
    )
    return m, why


def _home_or_box_payload(arm: Arm, full: torch.Tensor) -> tuple[float, str]:
    """`rated_payload` at home (full[0], chain joints) or, where no joint is loaded there (an arm
    pointing straight up), at home and the box's samples (full (S, n))."""
    try:
        return rated_payload(arm, full[0])
    except ValueError:
        return rated_payload(arm, full)


def derive_robot(cfg: RobotConfig, arm: Arm, urdf_name: str) -> RobotConfig:
    """`cfg` with every key left at its robot=urdf marker filled from `arm` (the chain root ->
    cfg.end_link) and `urdf_name` (the URDF's <robot name>), one log line per key; `cfg` itself
    unchanged when it does not ask to derive (`cfg.derive` false)."""
    if not cfg.derive:
        return cfg
    name = cfg.name or urdf_name
    _said("name", name, "given" if cfg.name else "the URDF's <robot name>")
    unknown = [j for j in cfg.locked if j not in arm.joint_names]
    if unknown:
        raise ValueError(
            f"robot.locked names {unknown}, which are not joints of the chain to {cfg.end_link!r}: {arm.joint_names}"
        )
    free = [i for i, j in enumerate(arm.joint_names) if j not in cfg.locked]
    joints = [arm.joint_names[i] for i in free]
    log.info("free joints = %s (the chain to %r less robot.locked %s)", joints, cfg.end_link, dict(cfg.locked))

    target = _target(cfg, joints)
    if cfg.redundancy and cfg.redundancy not in joints:
        raise ValueError(f"robot.redundancy={cfg.redundancy!r} is not allowed: allowed are the free joints {joints}")
    pick_redundancy = target == Target.pose and len(joints) == 7 and not cfg.redundancy
    if not pick_redundancy:
        check_ik_is_function(target, joints, cfg.locked, cfg.redundancy)  # 8+ free joints: the ways out

    lo_all, hi_all = arm.joint_limits()
    lo, hi = lo_all[free], hi_all[free]
    home, low, high = _home_and_box(cfg, joints, lo, hi)
    redundancy = cfg.redundancy
    if pick_redundancy:
        trial_robot = load_robot(replace(cfg, name=name, target=target, home=home, joint_low=low, joint_high=high))
        scores = box_conditioning(
            trial_robot, torch.tensor(home, dtype=torch.float64)[None].expand(7, -1), lo, hi,
            cfg.box_halfwidth, drop=torch.arange(7),
        )  # fmt: skip
        # a first joint that turns the whole arm about the vertical answers targets turned about the
        # base (rbfn.yaw): it stays an output
        base = trial_robot.base_yaw_sign() != 0
        redundancy = joints[int(scores[int(base) :].argmax()) + int(base)]
        _said(
            "redundancy",
            redundancy,
            "7 free joints for a 6-dof pose: the joint whose value, given, leaves the other six best conditioned "
            f"over the box (5 % quantile of sigma_min / sigma_max, per joint: {[float(f'{v:.2g}') for v in scores]})"
            + ("; the base joint, which turns the arm about the vertical, stays an output" if base else ""),
        )
    if not cfg.home and not (cfg.joint_low and cfg.joint_high):  # both by the middle rule
        trial = replace(cfg, name=name, target=target, home=home, joint_low=low, joint_high=high, redundancy=redundancy)
        home, why = conditioned_home(load_robot(trial), lo, hi, torch.tensor(home), cfg.box_halfwidth)
        low, high = _box(torch.tensor(home, dtype=torch.float64), lo, hi, cfg.box_halfwidth)
        _said("home", [round(v, 4) for v in home], why)
        _said(
            "joint_low, joint_high",
            f"{[round(v, 4) for v in low]}, {[round(v, 4) for v in high]}",
            f"home +- robot.box_halfwidth={cfg.box_halfwidth:g}, clipped to the URDF limits",
        )

    gravity = GRAVITY if cfg.gravity is None else cfg.gravity
    _said("gravity", gravity, "given" if cfg.gravity is not None else "standard gravity, m/s^2")

    payload = _rated_payload(cfg, arm, free, home, low, high)

    rate = CONTROL_RATE if cfg.control_rate is None else cfg.control_rate
    _said(
        "control_rate", f"{rate:g} Hz", "given" if cfg.control_rate is not None else "typical, for the realistic loop"
    )
    counts = list(cfg.encoder_counts) or [float(ENCODER_COUNTS)] * arm.n
    _said(
        "encoder_counts",
        f"{counts[0]:.0f} x {len(counts)}" if len(set(counts)) == 1 else counts,
        "given" if cfg.encoder_counts else "2^20 per revolution (per metre, prismatic) on every joint: typical",
    )
    return replace(
        cfg,
        name=name,
        target=target,
        redundancy=redundancy,
        home=home,
        joint_low=low,
        joint_high=high,
        gravity=gravity,
        rated_payload=payload,
        control_rate=rate,
        encoder_counts=counts,
    )


def _said(key: str, value: Any, why: str) -> None:
    """One derived key's log line: its value and why."""
    log.info("robot.%s = %s (%s)", key, value, why)


def _target(cfg: RobotConfig, joints: list[str]) -> Target:
    """robot.target: given, or by the count of free `joints` (3: position; 4 and more: pose)."""
    target = cfg.target
    if target is None:
        if len(joints) < 3:
            raise ValueError(
                f"robot.target=null: the chain to {cfg.end_link!r} has {len(joints)} free joint(s) {joints}, "
                "too few to span positions (3) or poses (6); choose a link further out with robot.end_link, "
                "or give robot.target=position"
            )
        # 4 or 5 free joints span no more than 3 of a position's dof without redundancy: their IK
        # answers the poses the arm reaches (a 5-D or 4-D set of the 6-D poses), one joint vector each
        target = Target.pose if len(joints) >= 4 else Target.position
        why = {3: "position (3 dof)", 6: "pose (6 dof)", 7: "pose (6 dof) and one joint as an input"}.get(
            len(joints), f"pose: the poses the arm reaches ({len(joints)} of their 6 dof)"
        )
        _said("target", str(target), f"{len(joints)} free joints: {why}")
    else:
        _said("target", str(target), "given")
    return target


def _rated_payload(
    cfg: RobotConfig, arm: Arm, free: list[int], home: list[float], low: list[float], high: list[float]
) -> float:
    """robot.rated_payload (kg): given, or the largest the arm holds at home and over the box
    (`_home_or_box_payload`); 0 where the URDF's inertials or effort limits are unusable."""
    payload = cfg.rated_payload
    if payload < 0 and arm.problems:  # no meaningful gravity torques to bound it by
        payload = 0.0
        _said("rated_payload", "0 kg", "not derived: the URDF's inertials are unusable for dynamics (above)")
    elif payload < 0:
        full = torch.zeros(arm.n, dtype=torch.float64)
        for j, v in cfg.locked.items():
            full[arm.joint_names.index(j)] = v
        full = full.repeat(BOX_SAMPLES + 1, 1)
        full[:, free] = torch.cat([torch.tensor([home], dtype=torch.float64), _samples(low, high)])
        try:
            payload, why = _home_or_box_payload(arm, full)
        except ValueError as e:  # no effort limits (effort="0"): the IK needs none, the control part a mass
            payload = 0.0
            _said("rated_payload", "0 kg", "not derived")
            log.warning("%s; the IK needs none and trains; evaluate.py's control cases then carry no payload", e)
        else:
            _said("rated_payload", f"{payload:g} kg", why)
            if payload == 0:
                log.warning("robot.rated_payload = 0 kg: the arm's own weight at home takes over half an effort limit")
    else:
        _said("rated_payload", f"{payload:g} kg", "given")

    return payload


def _home_and_box(
    cfg: RobotConfig, joints: list[str], lo: torch.Tensor, hi: torch.Tensor
) -> tuple[list[float], list[float], list[float]]:
    """(home, joint_low, joint_high) per free joint, in rad (m): given ones kept, the rest derived
    from the limits lo, hi (n,) (-inf, inf where none), logged."""
    n, w = len(joints), cfg.box_halfwidth
    if not (isinstance(w, (int, float)) and math.isfinite(w) and w > 0):
        raise ValueError(f"robot.box_halfwidth={w!r} is not allowed: must be > 0 (rad, or m for a prismatic joint)")
    for key, v in (("home", cfg.home), ("joint_low", cfg.joint_low), ("joint_high", cfg.joint_high)):
        if v and len(v) != n:
            raise ValueError(
                f"robot.{key}={list(v)} is not allowed: one value per free joint of the chain to "
                f"{cfg.end_link!r}, which has {n}: {joints}"
            )
    fixed = [j for j, a, b in zip(joints, lo.tolist(), hi.tolist()) if not a < b]
    if fixed:
        raise ValueError(f"joints {fixed} have no range in the URDF (lower >= upper): hold them with robot.locked")
    box = bool(cfg.joint_low) and bool(cfg.joint_high)
    if cfg.home:
        home, why = [float(v) for v in cfg.home], "given"
        check_joint_values({}, joints, lo, hi, {"robot.home": home})
    elif box:
        home = [(a + b) / 2 for a, b in zip(cfg.joint_low, cfg.joint_high)]
        why = "the given box's centre"
    else:  # logged by derive_robot, after conditioned_home
        return _middle(lo, hi).tolist(), *_box(_middle(lo, hi), lo, hi, w)
    log.info("robot.home = %s (%s)", [round(v, 4) for v in home], why)
    if box:
        low, high = [float(v) for v in cfg.joint_low], [float(v) for v in cfg.joint_high]
        log.info("robot.joint_low, joint_high = %s, %s (given)", low, high)
    else:
        low, high = _box(torch.tensor(home, dtype=torch.float64), lo, hi, w)
        log.info(
            "robot.joint_low, joint_high = %s, %s (home +- robot.box_halfwidth=%g, clipped to the URDF limits)",
            [round(v, 4) for v in low],
            [round(v, 4) for v in high],
            w,
        )
    return home, low, high


def _middle(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """The middle of each joint's limits (n,); 0 for a joint without (continuous)."""
    finite = torch.isfinite(lo) & torch.isfinite(hi)
    return torch.where(finite, (lo + hi) / 2, torch.zeros_like(lo))


def _box(home: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, w: float) -> tuple[list[float], list[float]]:
    """(joint_low, joint_high): home (n,) +- w, clipped to the limits lo, hi (n,)."""
    return torch.maximum(home - w, lo).tolist(), torch.minimum(home + w, hi).tolist()


def _samples(low: list[float], high: list[float], n: int = BOX_SAMPLES, seed: int = 0) -> torch.Tensor:
    """n joint vectors (n, k) drawn uniformly in the box (seeded: the same box, the same samples)."""
    lo, hi = torch.tensor(low, dtype=torch.float64), torch.tensor(high, dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    return lo + (hi - lo) * torch.rand(n, lo.numel(), generator=g, dtype=torch.float64)


def box_conditioning(
    robot: Robot, homes: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, w: float, drop: torch.Tensor | None = None
) -> torch.Tensor:
    """Per home (C, k): the 5 % quantile over BOX_SAMPLES seeded joint vectors of its box (home
    +- w, clipped to the limits lo, hi (k,)) of the task Jacobian's sigma_min / sigma_max (C,).
    Near 0 where a singularity runs through the box (and with it a second IK branch). `drop` (C,)
    (the robot's redundant joint where None): per home, the joint whose column leaves the Jacobian,
    a joint whose value the network is given."""
    u = 2 * _samples([0.0] * homes.shape[1], [1.0] * homes.shape[1]) - 1  # (S, k) in [-1, 1]
    q = torch.maximum(torch.minimum(homes[:, None, :] + w * u, hi), lo)  # (C, S, k)
    jac = robot.jacobian(q.reshape(-1, homes.shape[1])).reshape(*q.shape[:2], -1, homes.shape[1])
    if drop is None and robot.redundant is not None:
        drop = torch.full((homes.shape[0],), robot.redundant)
    if drop is not None:  # (C, S, r, k) -> (C, S, r, k - 1)
        keep = torch.arange(homes.shape[1])[None, :] != drop[:, None]  # (C, k)
        jac = jac.masked_select(keep[:, None, None, :]).reshape(*jac.shape[:3], homes.shape[1] - 1)
    s = torch.linalg.svdvals(jac)
    return (s[..., -1] / s[..., 0]).quantile(0.05, dim=1)


def conditioned_home(
    robot: Robot, lo: torch.Tensor, hi: torch.Tensor, middle: torch.Tensor, w: float, seed: int = 0
) -> tuple[list[float], str]:
    """(home (k,), why): `middle` where its box (+- w, clipped to the limits lo, hi (k,) of the
    free joints) is well conditioned (box_conditioning >= CONDITIONED); else, of CANDIDATES seeded
    candidates middle + r u (u uniform in [-1, 1]^k, r growing from 0 to pi, rad or m; kept inside
    the limits, a box's width from them where the range allows), the nearest to the middle whose
    box reaches twice CONDITIONED, or, where none does, the best conditioned."""
    middle = middle.to(torch.float64)
    rule = "the middle of each joint's URDF limits; 0 without limits"
    score = float(box_conditioning(robot, middle[None], lo, hi, w)[0])
    if score >= CONDITIONED:
        return middle.tolist(), rule
    g = torch.Generator().manual_seed(seed)
    u = 2 * torch.rand(CANDIDATES, middle.numel(), generator=g, dtype=torch.float64) - 1
    r = torch.linspace(0.0, math.pi, CANDIDATES + 1, dtype=torch.float64)[1:, None]
    inner_lo = torch.where(hi - lo > 2 * w, lo + w, lo)
    inner_hi = torch.where(hi - lo > 2 * w, hi - w, hi)
    cand = torch.maximum(torch.minimum(middle + r * u, inner_hi), inner_lo)  # (C, k)
    scores = box_conditioning(robot, cand, lo, hi, w)
    dist = (cand - middle).norm(dim=-1)
    good = scores >= 2 * CONDITIONED
    i = int(torch.where(good, dist, torch.full_like(dist, math.inf)).argmin()) if good.any() else int(scores.argmax())
    why = (
        f"the middle of the limits {[round(v, 4) for v in middle.tolist()]} has a singularity in its box "
        f"(sigma_min / sigma_max {score:.2g} at its 5 % quantile, under {CONDITIONED:g}); the nearest of "
        f"{CANDIDATES} candidates around it with a well-conditioned box ({float(scores[i]):.2g}), "
        f"{float(dist[i]):.2f} away"
    )
    return cand[i].tolist(), why


def derive_sizes(cfg: TrainConfig) -> TrainConfig:
    """`cfg` with the training sizes conf/sizing/urdf.yaml leaves at its markers (rbfn.num_centers,
    data.n_train/n_val/n_test 0; rbfn.growth.start -1) taken from SIZES by the (filled) robot's
    target kind, one log line each; unchanged without robot.derive."""
    if not cfg.robot.derive:
        return cfg
    assert cfg.robot.target is not None, "derive_robot first"
    sizes = SIZES[cfg.robot.target]
    why = f"{cfg.robot.target} targets: the {'UR5' if cfg.robot.target == Target.pose else 'SCARA'}'s size"

    def pick(key: str, value: int, marker: int, derived: int) -> int:
        out = derived if value == marker else value
        log.info("%s = %d (%s)", key, out, why if value == marker else "given")
        return out

    growth = replace(cfg.rbfn.growth, start=pick("rbfn.growth.start", cfg.rbfn.growth.start, -1, sizes.growth_start))
    rbfn = replace(
        cfg.rbfn, num_centers=pick("rbfn.num_centers", cfg.rbfn.num_centers, 0, sizes.num_centers), growth=growth
    )
    data = replace(
        cfg.data,
        n_train=pick("data.n_train", cfg.data.n_train, 0, sizes.n_train),
        n_val=pick("data.n_val", cfg.data.n_val, 0, sizes.n_val),
        n_test=pick("data.n_test", cfg.data.n_test, 0, sizes.n_test),
    )
    return replace(cfg, rbfn=rbfn, data=data)


def _filled(robot: RobotConfig) -> RobotConfig:
    """The robot with its robot=urdf keys derived (unchanged without robot.derive; a warning
    where another URDF takes a shipped preset's values)."""
    if not robot.derive:
        if robot.urdf and robot.name in ROBOT_PRESETS:
            log.warning(
                "robot.urdf=%s takes robot=%s's preset values (box, home, payload, gains, sizes); for "
                "your own arm use robot=urdf, which derives them from the URDF",
                robot.urdf,
                robot.name,
            )
        return robot
    arm, name = load_urdf_arm(robot)
    filled = derive_robot(robot, arm, name)
    warn_if_singular(filled)
    return filled


def warn_if_singular(cfg: RobotConfig, tol: float = 1e-3) -> float:
    """Log a warning where the task Jacobian (3 or 6 rows, m and rad per rad or m) at cfg.home
    has a smallest singular value below `tol` times its largest: a singular home (a stretched
    elbow, aligned wrist axes), where the box around it holds more than one IK branch and the
    network learns their average. Returns that ratio."""

    robot = load_robot(cfg)
    s = torch.linalg.svdvals(robot.jacobian(torch.tensor([cfg.home], dtype=torch.float64))[0])
    ratio = float(s[-1] / s[0])
    if ratio < tol:
        log.warning(
            "robot.home=%s is (near) a singular configuration of the arm (Jacobian singular values "
            "%s): the box around it may hold more than one IK branch; give robot.home, away from it",
            [round(v, 4) for v in cfg.home],
            [float(f"{v:.3g}") for v in s.tolist()],
        )
    return ratio


def derive_train(cfg: TrainConfig) -> TrainConfig:
    """train.py's config with the robot's and the sizes' robot=urdf keys derived (the presets:
    unchanged)."""
    return derive_sizes(replace(cfg, robot=_filled(cfg.robot)))


def derive_evaluate(cfg: EvalConfig) -> EvalConfig:
    """evaluate.py's config with the control robot's robot=urdf keys derived (the presets:
    unchanged). The loop's sensing follows the robot's as conf/loop/realistic.yaml interpolates it:
    loop.control_rate and loop.encoder_counts composed equal to the robot's markers take the
    derived values, unless the loop is the ideal one."""
    robot = _filled(cfg.robot)
    if robot is cfg.robot:
        return cfg
    loop = cfg.loop
    if not loop.ideal:
        rate = robot.control_rate if loop.control_rate == cfg.robot.control_rate else loop.control_rate
        counts = (
            robot.encoder_counts if list(loop.encoder_counts) == list(cfg.robot.encoder_counts) else loop.encoder_counts
        )
        loop = replace(loop, control_rate=rate, encoder_counts=list(counts))
    if cfg.control.enabled and cfg.control.trajectory is None:
        text = urdf_source(Path(robot.urdf))[0]
        known = closed_form(text, robot.end_link, robot.locked, robot.gravity)
        if known is None:
            log.info("control.trajectory = %s (no closed form: about robot.home)", Trajectory.sinusoid)
        else:
            log.info("control.trajectory = %s (the closed form's own)", known.trajectory)
    return replace(cfg, robot=robot, loop=loop)
