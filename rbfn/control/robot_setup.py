"""What the closed loop needs of a robot: plant, nominal model, desired trajectory, joint scale,
payload cases and units, from `RobotConfig` and `ControlConfig`; every robot-dependent setting is
checked here, before any simulation, with errors naming the key.

Every robot takes one path: its URDF chain (`rbfn.robots.dynamics.load_arm`) root ->
robot.end_link is loaded and checked, then `rbfn.robots.registry.closed_form` is asked for faster
closed forms of exactly that chain (the packaged SCARA's, with the payload at its end link); the
plant and the nominal model use their dynamics backend, else the URDF recursion's
(`rbfn.robots.arm_terms.ArmTerms`). Every joint of the chain is controlled:
joints in robot.locked are held at their value (desired amplitude 0). The joint box
(robot.joint_low/high) and robot.home list the free joints.
"""

from __future__ import annotations

import logging
import reprlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import torch

from ..config import ControlConfig, GainsConfig, RobotConfig, Trajectory
from ..robots.arm_terms import ArmTerms
from ..robots.backend import Dynamics
from ..robots.dynamics import load_arm, urdf_source
from ..robots.registry import closed_form
from ..robots.robot import check_joint_values
from .controllers import InertiaSchedule, JointRates, observer_factor
from .loop import RealLoop, crossover_limit, integration_limit
from .models import PAPER, ModelScales, NominalModel, model_scales
from .plants import Plant
from .trajectory import paper_trajectory, sinusoid_trajectory

log = logging.getLogger(__name__)

__all__ = ["ControlRobot", "GainFactors", "control_robot", "payload_cases"]


class GainFactors(NamedTuple):
    """What the controllers of one comparison take per joint beside the gains
    (`ControlRobot.gain_factors`): the torque-gain factor as a list (None: 1 on every joint; what
    `control_info` records) and as a tensor (n,), and the integrators' rates (None: off)."""

    listed: list[float] | None
    scale: torch.Tensor | None
    rates: JointRates | None


@dataclass
class ControlRobot:
    """A robot ready for the closed loop; joints in chain order, n = len(joint_names)."""

    name: str
    joint_names: list[str]
    prismatic: list[bool]
    plant: Plant
    model: NominalModel  # the unloaded robot's, at the default `ModelScales`
    scale: list[float] | None  # torque-gain and scenario factor per joint; None: 1 on every joint
    trajectory_kind: str
    home: list[float]  # per joint, rad or m (sinusoid)
    amplitude: list[float]  # per joint, rad or m (sinusoid)
    payloads: list[float]  # kg, the payload cases
    effort: list[float] | None = None  # per joint, the URDF's effort limits, N m (N); inf where none
    closed: Any = None  # the robot's closed forms where the registry has them (rbfn.robots.registry)
    rated_payload: float = 0.0  # kg, the most the arm is meant to carry (robot.rated_payload)
    lower: list[float] | None = None  # per joint, the URDF's position limits, rad or m; -inf where none
    upper: list[float] | None = None  # per joint, rad or m; inf where none

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def dynamics(self) -> Dynamics:
        """The arm's equations of motion (the plant's backend)."""
        return self.plant.dynamics

    def nominal_model(self, payload: float = 0.0, scales: ModelScales = PAPER) -> NominalModel:
        """The controllers' nominal model carrying `payload` kg (`gains.nominal_payload`; 0: the
        unloaded robot's) with factors `scales` (`model_scales(gains)`); `model` where both are the
        defaults."""
        if not payload and scales == self.model.scales:
            return self.model
        return NominalModel(self.dynamics, scales, payload)

    def home_inertia(self, payload: float = 0.0, scales: ModelScales = PAPER) -> torch.Tensor:
        """The nominal model's inertia matrix M_hat (n, n) at home carrying `payload` kg, float64,
        kg m^2 (kg)."""
        home = torch.tensor([self.home], dtype=torch.float64)
        eye = torch.eye(self.n, dtype=torch.float64)
        return self.nominal_model(payload, scales).at(home.expand(self.n, -1), torch.zeros_like(eye)).m_times(eye)

    def gain_factors(self, gains: GainsConfig, loop: RealLoop | None, dt: float | None = None, **kw) -> GainFactors:
        """The controllers' per-joint factors in `loop` (None: the ideal loop, stepping dt s): the
        joint scale, capped for `gains.phase_margin` in a realistic loop and, in the ideal loop with
        dt given, for the integrator's stability (`integration_limit`; `feedback_scale`), and the
        rates that follow from it (`joint_rates`); tensors with dtype and device from kw."""
        if loop is not None:
            crossover = crossover_limit(loop, gains.phase_margin) if gains.phase_margin else None
        else:
            crossover = None if dt is None else integration_limit(dt)
        listed = self.feedback_scale(gains, crossover)
        scale = None if listed is None else torch.tensor(listed, **kw)
        return GainFactors(listed, scale, self.joint_rates(gains, scale=scale, **kw))

    def feedback_scale(self, gains: GainsConfig, crossover: float | None) -> list[float] | None:
        """The controllers' torque-gain factor per joint (n,), as `scale` (None for ones): the joint
        scale s_j, capped where `crossover` (rad/s, `rbfn.control.loop.crossover_limit`; None: no
        cap) is below the joint's feedback bandwidth K s_j / Me_jj, Me_jj = 1 / (M_hat^-1)_jj the
        joint's apparent inertia at home with the other joints free (on a coupled joint far below
        M_jj, which the scale follows):

            s_j min(1, crossover Me_jj / (K s_j)).

        `scale` itself where no joint is capped. The scenario's friction, disturbance and torque
        noise keep the joint scale."""
        if crossover is None:
            return self.scale
        apparent = 1.0 / torch.linalg.inv(self.home_inertia(gains.nominal_payload, model_scales(gains))).diagonal()
        scale = torch.ones(self.n, dtype=torch.float64) if self.scale is None else torch.tensor(self.scale)
        capped = torch.minimum(scale, crossover * apparent / gains.K)
        return self.scale if torch.equal(capped, scale) else capped.tolist()

    def joint_rates(self, gains: GainsConfig, scale: torch.Tensor | None = None, **kw) -> JointRates | None:
        """Per-joint factors of the observer gain and the adaptation rate (`gains.inertia_scaling`;
        None where it is off), from the nominal model's inertia diagonal at home, M0_jj unloaded (or
        carrying gains.nominal_payload) and Mr_jj carrying the rated payload, and the controllers'
        torque-gain factor s_j (`scale`, (n,); None: the joint scale):

            observer_j = min(1, K s_j / (K_o Mr_jj)),   gamma_j = M0_jj / Mr_jj.

        With the observer no faster than the feedback's bandwidth K s_j / Mr_jj at the heaviest
        the joint may be, the observer's lag band (where it holds the inertia at the model's while
        the joint is heavier) stays below the feedback's crossover, which a fixed-bandwidth observer
        on an arm carrying many times its model's inertia crosses and then oscillates against the
        delay; dividing Gamma by the inertia's growth keeps the adaptation's integral action below
        the crossover likewise. Dimensionless (n,), dtype and device from kw."""
        if not gains.inertia_scaling:
            return None
        scales = model_scales(gains)
        base = self.home_inertia(gains.nominal_payload, scales).diagonal()
        rated = self.home_inertia(max(self.rated_payload, gains.nominal_payload), scales).diagonal()
        if scale is None:
            scale = self.joint_scale(dtype=torch.float64)
        s = torch.ones(self.n, dtype=torch.float64) if scale is None else scale.double().cpu()
        return JointRates(observer_factor(gains, s, rated).to(**kw), (base / rated).clamp(max=1.0).to(**kw))

    def inertia_schedule(self, gains: GainsConfig) -> InertiaSchedule:
        """The nominal model's inertia diagonal at home against the payload it carries (float64),
        for the two-phase law's observer gain: M_jj(m) = M_jj(0) + m (M_jj(1) - M_jj(0)), affine in
        a point mass m; the estimate's bound 1.25 x the rated payload."""
        scales = model_scales(gains)
        base = self.home_inertia(0.0, scales).diagonal()
        return InertiaSchedule(base, self.home_inertia(1.0, scales).diagonal() - base, 1.25 * self.rated_payload)

    @property
    def units(self) -> list[tuple[str, str]]:
        """(position, torque) unit per joint."""
        return [("m", "N") if p else ("rad", "N m") for p in self.prismatic]

    def joint_scale(self, **kw) -> torch.Tensor | None:
        """The joint scale as an (n,) tensor (dtype, device from kw), None for ones."""
        return None if self.scale is None else torch.tensor(self.scale, **kw)

    def trajectory(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Desired joints, velocities and accelerations (T, n) at times t (T,) s."""
        if self.trajectory_kind == Trajectory.paper:
            return paper_trajectory(t)
        home, amplitude = (torch.tensor(v, dtype=t.dtype) for v in (self.home, self.amplitude))
        return sinusoid_trajectory(t, home, amplitude)


def payload_cases(cfg: ControlConfig, rated: float) -> list[float]:
    """The payload cases in kg: control.payloads, else 0, rated/2 and rated (once each)."""
    return list(cfg.payloads) or list(dict.fromkeys([0.0, rated / 2, float(rated)]))


def control_robot(robot: RobotConfig, cfg: ControlConfig, urdf_text: str | None = None) -> ControlRobot:
    """The closed loop's robot for `robot` and the scenario `cfg` (ValueError naming the bad key).
    `urdf_text`: the URDF's text (a checkpoint's robot entry: data, never a file name), used
    instead of the file robot.urdf or the preset robot.name."""
    payloads = payload_cases(cfg, robot.rated_payload)
    heavy = [p for p in payloads if p > robot.rated_payload]
    if heavy:
        log.warning(
            "control.payloads=%s: %s kg exceed robot.rated_payload=%g kg, what %s is meant to carry; "
            "its torques may reach the URDF's effort limits (the realistic loop clips them there)",
            list(payloads),
            heavy,
            robot.rated_payload,
            robot.name,
        )
    source = urdf_text if urdf_text is not None else Path(robot.urdf) if robot.urdf else robot.name
    arm = _load(robot, cfg, source, urdf_text)
    n, names, prismatic = arm.n, arm.joint_names, arm.prismatic
    known = closed_form(urdf_source(source)[0], robot.end_link, robot.locked, robot.gravity)
    closed = known if cfg.payload_link in ("", robot.end_link) else None  # they carry the payload at the end link
    scale = _scale(cfg, robot, None if closed is not None else arm, n)
    home, amplitude = _sinusoid(robot, cfg, names)
    trajectory = cfg.trajectory or (known.trajectory if known is not None else Trajectory.sinusoid)
    if trajectory == Trajectory.paper and n != 3:
        raise ValueError(
            f"control.trajectory={str(trajectory)!r} is the SCARA's 3-joint path; the chain to "
            f"{robot.end_link!r} has {n} joints: use control.trajectory=sinusoid (or null)"
        )
    per = (lambda v: v) if scale is None else (lambda v: [v * s for s in scale])
    kw: dict[str, Any] = dict(
        viscous=per(cfg.viscous),
        coulomb=per(cfg.coulomb),
        friction=str(cfg.friction),
        disturbance=per(cfg.disturbance),
        disturbance_freq=cfg.disturbance_freq,
    )
    dynamics = closed.dynamics() if closed is not None else ArmTerms(arm)
    plant = Plant(dynamics, **kw)
    model = NominalModel(dynamics)
    return ControlRobot(
        robot.name,
        names,
        prismatic,
        plant,
        model,
        scale,
        str(trajectory),
        home,
        amplitude,
        payloads,
        arm.effort_limits().tolist(),
        closed,
        robot.rated_payload,
        *(v.tolist() for v in arm.joint_limits()),
    )


def _load(robot: RobotConfig, cfg: ControlConfig, source: str | Path, urdf_text: str | None):
    """The URDF arm of `source`: the text, else robot.urdf (a file), else the preset robot.name;
    ValueError with the first of its `problems` where its dynamics cannot be simulated (its notes
    logged as warnings)."""
    try:
        arm = load_arm(source, end_link=robot.end_link, gravity=robot.gravity)
    except (FileNotFoundError, ValueError) as e:
        urdf = repr(robot.urdf) if urdf_text is None else reprlib.repr(urdf_text)  # a file name, or text
        raise type(e)(
            f"robot.urdf={urdf} (robot.name={robot.name!r}, robot.end_link={robot.end_link!r}): {e}"
        ) from None
    if arm.problems:  # (e.g. a link without mass at the end of the chain: M(q) has no inverse)
        urdf = repr(robot.urdf) if urdf_text is None else "(the checkpoint's URDF text)"
        raise ValueError(
            f"robot.urdf={urdf} (robot.name={robot.name!r}, robot.end_link={robot.end_link!r}): the closed "
            f"loop cannot simulate this arm's dynamics: {arm.problems[0]}"
        )
    arm.warn_notes(log, f"robot.urdf={robot.urdf or robot.name}")
    if cfg.payload_link:
        try:
            arm = load_arm(source, end_link=robot.end_link, gravity=robot.gravity, payload_link=cfg.payload_link)
        except ValueError as e:
            raise ValueError(f"control.payload_link={cfg.payload_link!r}: {e}") from None
    unknown = [j for j in robot.locked if j not in arm.joint_names]
    if unknown:
        raise ValueError(
            f"robot.locked names {unknown}, which are not joints of the chain to {robot.end_link!r}: {arm.joint_names}"
        )
    free = arm.n - len(robot.locked)
    if len(robot.joint_low) != free:
        raise ValueError(
            f"robot.joint_low/joint_high give {len(robot.joint_low)} joints; the chain to "
            f"{robot.end_link!r} has {free} free joints ({arm.n} in all, {len(robot.locked)} locked)"
        )
    given = {f"robot.{k}": list(getattr(robot, k)) for k in ("home", "joint_low", "joint_high")}
    check_joint_values(robot.locked, arm.joint_names, *arm.joint_limits(), given)
    return arm


def _sinusoid(robot: RobotConfig, cfg: ControlConfig, names: list[str]) -> tuple[list[float], list[float]]:
    """Per chain joint: home (robot.home or the box centre; locked joints their value) and
    amplitude control.amplitude * half the box range (0 for locked joints)."""
    free = [j for j in names if j not in robot.locked]
    lo, hi = robot.joint_low, robot.joint_high
    centre = list(robot.home) or [(a + b) / 2 for a, b in zip(lo, hi)]
    half = {j: (b - a) / 2 for j, a, b in zip(free, lo, hi)}
    by_name = dict(zip(free, centre))
    home = [float(robot.locked[j]) if j in robot.locked else by_name[j] for j in names]
    amplitude = [0.0 if j in robot.locked else cfg.amplitude * half[j] for j in names]
    return home, amplitude


def _scale(cfg: ControlConfig, robot: RobotConfig, arm, n: int) -> list[float] | None:
    """control.joint_scale, else M_jj(home) of the URDF arm, None (ones) for closed forms (arm None)."""
    if cfg.joint_scale:
        if len(cfg.joint_scale) != n:
            raise ValueError(
                f"control.joint_scale={list(cfg.joint_scale)} needs one factor per joint of {robot.name!r} ({n})"
            )
        return [float(v) for v in cfg.joint_scale]
    if arm is None:
        return None
    home, _ = _sinusoid(robot, cfg, arm.joint_names)
    q = torch.tensor([home], dtype=torch.float64)
    return arm.mass_matrix(q)[0].diagonal().tolist()
