"""Online IK adaptation in the closed loop: the learned IK corrects itself on a robot whose
kinematics differ from the model it was trained on.

Each control period: x_d -> IK network -> q_d -> smc_obs -> simulator -> q -> x = FK_real(q);
every `update_every` periods the learner adapts the network's output weights on the recent
pairs (x, q). Environments are batched: one per (perturbation size, adapt on/off). The
perturbation is kinematic (link lengths, joint offsets in FK_real); the dynamics stay nominal.
The joint references' velocity and acceleration come from the network's design rows along the
desired path, differentiated in time on the control grid, times the current weights.

The robot is the one the network was trained for, set up as the closed loop sets up every robot
(`control_robot`: its URDF's plant and nominal model, or the closed forms
`rbfn.robots.registry.closed_form` has for exactly that URDF). Its kinematics, the real robot's
included, are the closed forms' where they exist (for position targets), else the URDF chain's
through `rbfn.robots.perturbed`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import torch
from pytorch_kinematics import transforms as tf

from ..config import ControlConfig, GainsConfig, OnlineConfig, PathName, RobotConfig, Target, Trajectory
from ..layer import RBFNetwork
from ..lms import make_learner
from ..robots.arm_terms import ArmTerms
from ..robots.dynamics import load_arm
from ..robots.perturbed import PerturbedChain
from ..robots.registry import ClosedForm, closed_form
from ..robots.robot import robot_from_record, rotation_error_deg, unit_quaternions
from .aot import ahead_of_time, aot_chunk, chunk_key, map_tensors
from .controllers import Controller, make_controller
from .loop import integration_limit
from .models import model_scales
from .robot_setup import control_robot
from .simulator import Loop, Periods, Plant, Scenario, SimulationDiverged, make_chunk, run_chunks, stage_disturbances
from .trajectory import Reference, paper_trajectory, sinusoid_trajectory

log = logging.getLogger(__name__)

__all__ = [
    "RealRobot",
    "OnlineRobot",
    "desired_path",
    "online_robot",
    "record_closed_form",
    "OnlineRun",
    "run_online",
    "perturbation_sizes",
    "path_name",
    "check_online",
    "box_path",
]


@dataclass
class RealRobot:
    """Kinematics of a real robot in closed form: link lengths scaled by (1 + link_error), joint
    offsets added. Batched: link_error (B, L) (L = closed.links), offset (B, n)."""

    closed: ClosedForm
    link_error: torch.Tensor
    offset: torch.Tensor

    def fk(self, q: torch.Tensor) -> torch.Tensor:
        """Measured positions (..., B, 3) of joints q (..., B, n)."""
        return self.closed.fk(q + self.offset, self.link_error.unbind(-1))  # (B,) lengths per link


def record_closed_form(record: dict) -> ClosedForm | None:
    """The closed forms of a checkpoint's robot entry (`rbfn.robots.registry.closed_form`), for
    position targets (closed-form kinematics give positions); None: its URDF serves it."""
    if str(record.get("target", "position")) != Target.position:
        return None
    return closed_form(record.get("urdf", ""), record.get("end_link", ""), record.get("locked"))


def path_name(cfg: OnlineConfig, record: dict) -> str:
    """online.path, or its default for the robot: its closed forms' path, else sinusoid."""
    if cfg.path is not None:
        return str(cfg.path)
    closed = record_closed_form(record)
    return str(PathName.sinusoid) if closed is None else closed.path


def _padded(values: list[float], n: int, **kw) -> torch.Tensor:
    out = torch.zeros(n, **kw)
    out[: len(values)] = torch.tensor(values, **kw)
    return out


def perturbation_sizes(
    cfg: OnlineConfig, sizes: list[float], n_links: int | None = None, n_joints: int | None = None, **kw
) -> tuple[torch.Tensor, torch.Tensor]:
    """Link errors (S, n_links) and joint offsets (S, n_joints) of each sweep row (default sizes:
    the configured lists' lengths, missing entries 0): the configured perturbation scaled so that
    its link-1 error equals the row's size."""
    s = torch.tensor(sizes, **kw)
    ref = cfg.link_error[0]
    scale = s / ref if ref else torch.zeros_like(s)
    link = _padded(list(cfg.link_error), n_links or len(cfg.link_error), **kw)[None] * scale[:, None]
    offset = _padded(list(cfg.offset_error), n_joints or len(cfg.offset_error), **kw)[None] * scale[:, None]
    return link, offset


def desired_path(name: str, t: torch.Tensor, fk: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """Desired end-effector positions (T, 3) in m at times t (T,) s of a path in the SCARA's
    workspace (paper, circle, figure8), `fk` the closed-form kinematics (joints (B, 3) -> (B, 3) m)."""
    if name == PathName.paper:
        return fk(paper_trajectory(t)[0])
    centre = fk(torch.tensor([[1.0, 1.15, 1.0]], dtype=t.dtype))[0]
    w = 2 * math.pi / 5.0  # one loop per 5 s
    if name == PathName.circle:
        off = torch.stack([0.15 * torch.cos(w * t), 0.15 * torch.sin(w * t), 0.1 * torch.sin(w * t)], -1)
    elif name == PathName.figure8:
        off = torch.stack([0.2 * torch.sin(w * t), 0.1 * torch.sin(2 * w * t), 0.1 * torch.cos(w * t)], -1)
    else:
        raise ValueError(f"unknown path {name!r}; choose one of {[str(p) for p in PathName]}")
    return centre + off


def box_path(low: torch.Tensor, high: torch.Tensor, amplitude: float, t: torch.Tensor) -> torch.Tensor:
    """Joints (T, n) of the `sinusoid` path: the box centre plus amplitude * half range *
    (sin w1 t + sin w2 t) per joint (the closed loop's frequency pairs), inside the box for
    amplitude <= 0.5."""
    return sinusoid_trajectory(t, (low + high) / 2, amplitude * (high - low) / 2)[0]


@dataclass
class OnlineRobot:
    """What the online loop needs of the robot a network was trained for, with its S perturbation
    rows; `measure` serves 2S environments, [adapted rows, frozen rows]."""

    plant: Plant
    controller: Controller  # smc_obs on the robot's nominal model
    x_d: torch.Tensor  # (T, d) desired targets along the path
    q_nominal: torch.Tensor  # (T, n_free) the nominal model's exact IK along the path
    measure: Callable  # chain joints (..., 2S, n) -> (rotations (..., 2S, 3, 3) | None,
    # positions (..., 2S, 3))
    free: list[int]  # the chain indices of the network's joints
    held: torch.Tensor  # (n,) chain joint values (the locked joints' are used)
    target: str  # position | pose
    link_error: torch.Tensor  # (S, L) each row's link errors
    offset_error: torch.Tensor  # (S, n) each row's joint offsets
    q_real: torch.Tensor | None = None  # (T, n_free) the real robot's exact IK of the configured row (closed forms)
    redundant: int | None = None  # the chain index of the joint the network takes beside the pose (robot.redundancy)

    @property
    def n(self) -> int:
        return self.held.shape[0]

    def full(self, q: torch.Tensor, held: torch.Tensor | None = None) -> torch.Tensor:
        """Chain joints (..., n) from the network's joints (..., n_free), the locked ones at `held`
        (n,) (default: their values; zeros for velocities); q itself where every joint is free."""
        if len(self.free) == self.n:
            return q
        out = (self.held if held is None else held).to(q).expand(*q.shape[:-1], -1).clone()
        out[..., self.free] = q
        return out

    def targets(self, rot: torch.Tensor | None, pos: torch.Tensor, q: torch.Tensor | None = None) -> torch.Tensor:
        """The network's inputs (..., d) of measured poses, and with a `redundant` joint its value
        from the measured chain joints q (..., n)."""
        if self.target != Target.pose:
            return pos
        assert rot is not None  # poses have rotations
        x = torch.cat([pos, unit_quaternions(rot)], -1)
        if self.redundant is None:
            return x
        assert q is not None  # the measured joints carry the redundant joint's value
        return torch.cat([x, q[..., self.redundant : self.redundant + 1]], -1)

    def errors(self, rot: torch.Tensor | None, pos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(position error (T, B) in mm, rotation error (T, B) in degrees or None) of measured poses
        (T, B, ...) against the desired path."""
        e_pos = (pos - self.x_d[:, None, :3]).norm(dim=-1) * 1000.0
        if self.target != Target.pose:
            return e_pos, None
        assert rot is not None  # poses have rotations
        r_d = tf.quaternion_to_matrix(self.x_d[:, 3:7])[:, None].expand_as(rot)
        return e_pos, rotation_error_deg(rot.reshape(-1, 3, 3), r_d.reshape(-1, 3, 3)).view(e_pos.shape)


def check_online(cfg: OnlineConfig, record: dict) -> tuple[int, int]:
    """(links, joints) of the checkpoint entry's robot, after checking that online.path,
    online.link_error and online.offset_error suit it (ValueError naming the key)."""
    path = path_name(cfg, record)
    closed = record_closed_form(record)
    if closed is not None:
        n_links, n_joints, name = closed.links, len(closed.joint_names), closed.label
    else:
        if path != PathName.sinusoid:
            raise ValueError(
                f"online.path={path!r} is a path of the SCARA's workspace; the checkpoint's robot "
                f"({record.get('name') or record['end_link']}) follows online.path=sinusoid"
            )
        arm = load_arm(record["urdf"], end_link=record["end_link"])
        n_links = n_joints = arm.n
        name = f"the chain to {arm.end_link!r} (joints {arm.joint_names})"
    if len(cfg.link_error) > n_links:
        raise ValueError(
            f"online.link_error={list(cfg.link_error)} has {len(cfg.link_error)} entries; {name} has {n_links} links"
        )
    if len(cfg.offset_error) > n_joints:
        raise ValueError(
            f"online.offset_error={list(cfg.offset_error)} has {len(cfg.offset_error)} entries; "
            f"{name} has {n_joints} joints"
        )
    return n_links, n_joints


def online_robot(
    record: dict, cfg: OnlineConfig, gains: GainsConfig, sizes: list[float], t: torch.Tensor, **kw
) -> OnlineRobot:
    """The online scenario of a checkpoint's robot entry on the time grid t (T,) s, for the
    perturbation rows `sizes` (ValueError naming the bad key): the robot set up by `control_robot`
    from the entry's URDF text (closed forms where the registry has them), its kinematics, the
    real robot's included, closed-form or the URDF chain's."""
    check_online(cfg, record)
    robot = RobotConfig(
        name=record.get("name") or "urdf",
        end_link=record["end_link"],
        target=record.get("target", "position"),
        joint_low=list(record["joint_low"]),
        joint_high=list(record["joint_high"]),
        locked=dict(record.get("locked", {})),
    )
    # the entry's dynamics; friction, disturbance scaled per joint
    setup = control_robot(robot, ControlConfig(trajectory=Trajectory.sinusoid), urdf_text=record["urdf"])
    listed = setup.feedback_scale(gains, integration_limit(cfg.dt))  # capped where the step cannot follow
    scale = None if listed is None else torch.tensor(listed, **kw)
    ctrl = make_controller(
        "smc_obs", gains, cfg.dt, model=setup.nominal_model(0.0, model_scales(gains)), joint_scale=scale
    )
    trained = robot_from_record(record, kw.get("device", "cpu"))  # its chain, free joints, targets
    closed, n = record_closed_form(record), setup.n
    if closed is None:
        arm = cast(ArmTerms, setup.dynamics).arm  # no closed forms: the URDF recursion
        link, offset = perturbation_sizes(cfg, sizes, n, n, **kw)
        q_path = box_path(trained.low.to(**kw), trained.high.to(**kw), cfg.amplitude, t)  # (T, n_free)
        held = trained.full_joints(q_path[:1])[0]
        real = PerturbedChain(arm, torch.cat([link, link]), torch.cat([offset, offset]))
        return OnlineRobot(
            setup.plant,
            ctrl,
            trained.inputs(q_path).to(**kw),
            q_path,
            real.pose,
            trained.free,
            held,
            str(robot.target),
            link,
            offset,
            redundant=None if trained.redundant is None else trained.free[trained.redundant],
        )
    link, offset = perturbation_sizes(cfg, sizes, closed.links, n, **kw)
    path = path_name(cfg, record)
    if path == PathName.sinusoid:
        x_d = closed.fk(box_path(trained.low.to(**kw), trained.high.to(**kw), cfg.amplitude, t))
    else:
        x_d = desired_path(path, t, closed.fk).to(**kw)
    real_robot = RealRobot(closed, torch.cat([link, link]), torch.cat([offset, offset]))
    le, oe = perturbation_sizes(cfg, [cfg.link_error[0]], closed.links, n, **kw)
    q_real = closed.ik(x_d, [float(e) for e in le[0]]) - oe[0]
    return OnlineRobot(
        setup.plant,
        ctrl,
        x_d,
        closed.ik(x_d),
        lambda q: (None, real_robot.fk(q)),
        trained.free,
        torch.zeros(n, **kw),
        str(Target.position),
        link,
        offset,
        q_real,
    )


@dataclass
class OnlineRun:
    """What `run_online` returns for S perturbation rows, on the control grid of T instants with U
    weight updates; positions in mm, rotations in degrees, joints in rad (m for a prismatic one)."""

    t: torch.Tensor  # (T,) s
    err_adapt: torch.Tensor  # (T, S) task-space position error of the adapted network
    err_frozen: torch.Tensor  # (T, S) of the same network without adaptation
    err_analytic: torch.Tensor  # (T, S) of the nominal model's exact IK
    rot_adapt: torch.Tensor | None  # (T, S) rotation errors, for pose targets (else None)
    rot_frozen: torch.Tensor | None
    rot_analytic: torch.Tensor | None
    q_adapt: torch.Tensor  # (T, S, n_free) the adapted rows' joints
    x_d: torch.Tensor  # (T, d) desired targets along the path
    q_real: torch.Tensor | None  # (T, n_free) the real robot's exact IK of the configured row, or None
    dw: torch.Tensor  # (U, S) norms of the weight change W - W0
    t_update: torch.Tensor  # (U,) s, the update times
    weights: torch.Tensor  # (S, P, n_free) the adapted rows' final output weights
    link_error: torch.Tensor  # (S, L) each row's link errors
    offset_error: torch.Tensor  # (S, n) each row's joint offsets (rad or m)
    rejected: int  # pairs the learner rejected (non-finite)


def run_online(
    net: RBFNetwork, record: dict, cfg: OnlineConfig, gains: GainsConfig, sizes: list[float], device: str = "cpu"
) -> OnlineRun:
    """Run adapted and frozen networks for every perturbation size in `sizes` (link-1 errors; see
    `perturbation_sizes`) and the nominal model's exact IK, on the robot of the checkpoint entry
    `record`; see OnlineRun for what comes back.
    """
    kw: dict[str, Any] = {"dtype": torch.float64, "device": device}
    aot = ahead_of_time(cfg.aot, device)
    sc = Scenario(cfg.duration, cfg.dt, "rk4", 0.0, cfg.duration, 0.0)
    sc.validate()
    n = sc.steps
    t = sc.times(**kw)
    rob = online_robot(record, cfg, gains, sizes, t, **kw)
    net = net.to(**kw)
    n_s, nj = len(sizes), rob.n
    b = 2 * n_s  # environments: [adapted (S), frozen (S)]
    path = _design_path(net, rob.x_d, cfg.dt)  # (3, T, P)
    w0 = net.output_weights().to(**kw)
    learner = make_learner(cfg.learner, w0.expand(b, *w0.shape), cfg.alpha0, cfg.decay, cfg.forgetting)
    frozen = torch.cat(
        [torch.zeros(n_s, dtype=torch.bool, device=device), torch.ones(n_s, dtype=torch.bool, device=device)]
    )
    plant, ctrl, every = rob.plant, rob.controller, cfg.update_every
    vel = torch.zeros(nj, **kw)  # locked joints: held, at rest
    q = rob.full(torch.einsum("p,bpj->bj", path[0, 0], learner.w))
    qd = rob.full(torch.einsum("p,bpj->bj", path[1, 0], learner.w), vel)
    loop = Loop(q, qd, ctrl.init_state(q, qd))
    dist = stage_disturbances(plant, n, cfg.dt, **kw)
    load = plant.load(torch.zeros(every, b, **kw))  # no payload
    alpha = torch.zeros(every, **kw)
    dw: list[torch.Tensor] = []

    def rows(sl: slice) -> Periods:
        """The periods `sl`'s inputs, the reference from the networks' current weights."""
        m = sl.stop - sl.start
        stacked = (path[:, None, sl] @ learner.w).transpose(1, 2)  # (3, m, B, n_free): q_d, qd_d, qdd_d
        ref = Reference(rob.full(stacked[0]), rob.full(stacked[1], vel), rob.full(stacked[2], vel))
        return Periods(ref=ref, h=None, alpha=alpha[:m], dist=dist[sl], load=map_tensors(lambda c: c[:m], load))

    def learn(sl: slice, out: Any) -> None:
        """The adapted networks learn the segment's pairs (x, q); the frozen ones learn nothing."""
        rq = out.q
        rot, pos = rob.measure(rq)
        x = rob.targets(rot, pos, rq)  # (m, B, d)
        a = net.design(x).transpose(0, 1)  # (B, m, P)
        y = rq[..., rob.free].transpose(0, 1)
        keep = learner.w.clone()
        learner.update(a, y, sl.stop * cfg.dt)
        learner.w = torch.where(frozen[:, None, None], keep, learner.w)
        dw.append((learner.w - w0).flatten(1).norm(dim=-1)[:n_s])

    run = make_chunk(plant, ctrl, cfg.dt, "rk4", every)
    if aot and n >= every:  # compiled ahead of time, cached on disk
        example = (loop, rows(slice(0, every)))
        run = aot_chunk(run, chunk_key(plant, ctrl, cfg.dt, "rk4", every, example), example, b, log.info)
    try:
        _, rec = run_chunks(
            run,
            lambda m: make_chunk(plant, ctrl, cfg.dt, "rk4", m),
            loop,
            rows,
            n=n,
            chunk=every,
            record=True,
            every=0,  # every chunk, before its pairs are learnt
            when=lambda k: (k, k * cfg.dt),
            after=learn,
        )
    except SimulationDiverged as e:
        which = "frozen" if e.environment >= n_s else "adapted"
        size = 100 * sizes[e.environment % n_s]
        raise SimulationDiverged(
            f"online run diverged, {which} network, link-1 error {size:g} %: {e}", e.environment
        ) from e
    assert rec is not None  # record=True
    qs = rec[0]
    return _online_result(rob, qs, t, torch.stack(dw), learner, n_s, cfg)


def _design_path(net: RBFNetwork, x_d: torch.Tensor, dt: float) -> torch.Tensor:
    """The network's design rows along the desired targets x_d (T, d) and their first and second
    time derivatives (central differences, step dt s): (3, T, P)."""
    a_path = net.design(x_d)  # (T, P)
    da = torch.gradient(a_path, spacing=dt, dim=0)[0]
    return torch.stack([a_path, da, torch.gradient(da, spacing=dt, dim=0)[0]])


def _online_result(
    rob: OnlineRobot, qs: torch.Tensor, t: torch.Tensor, dw: torch.Tensor, learner: Any, n_s: int, cfg: OnlineConfig
) -> OnlineRun:
    """`run_online`'s answer from the joints (T, 2 S, n) of the adapted and frozen rows, the weight
    changes dw (U, S) and the learner; the nominal model's exact IK measured on each real robot."""
    b, nj = qs.shape[1], qs.shape[2]
    kw: dict[str, Any] = {"dtype": qs.dtype, "device": qs.device}
    pos, rot = rob.errors(*rob.measure(qs))  # (T, B)
    # The nominal model's exact IK on each real robot (a kinematic perturbation: the same joints).
    q_an = rob.full(rob.q_nominal)[:, None, :].expand(-1, b, nj)
    pos_an, rot_an = rob.errors(*rob.measure(q_an))
    return OnlineRun(
        t=t,
        err_adapt=pos[:, :n_s],
        err_frozen=pos[:, n_s:],
        err_analytic=pos_an[:, :n_s],
        rot_adapt=None if rot is None else rot[:, :n_s],
        rot_frozen=None if rot is None else rot[:, n_s:],
        rot_analytic=None if rot_an is None else rot_an[:, :n_s],
        q_adapt=qs[:, :n_s, rob.free],
        x_d=rob.x_d,
        q_real=rob.q_real,
        dw=dw,
        t_update=torch.arange(1, len(dw) + 1, **kw) * cfg.update_every * cfg.dt,
        weights=learner.w[:n_s],
        link_error=rob.link_error,
        offset_error=rob.offset_error,
        rejected=learner.rejected,
    )
