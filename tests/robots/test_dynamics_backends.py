"""Every form of the rigid-body dynamics against the specification, `rbfn.robots.dynamics.Arm`.

One table: backend x robot x payload. Each backend gives what it has of M, M y, C qd + G, G,
C y, C^T qd (C the Christoffel matrix, y any joint vector), M^-1 y, dM/dt qd - C qd - G and the
forward dynamics M^-1 (y - C qd - G) at the same 600 random states in float64; the reference is
`Arm` (M by CRBA, C qd + G by RNEA, G, the matrices C and dM/dt). Backends: `Arm` by its other
routes (one kinematics pass, C qd + G from the matrix C, G as RNEA at rest), the two backends of
`rbfn.robots.backend.Dynamics` (the URDF recursion `ArmTerms`, whose narrow and wide batches take
different code, and the written-out solve `spd_solve` its compiled step takes; the SCARA's closed
form `ScaraTerms`), the SCARA's closed-form matrices, Pinocchio and MuJoCo where installed.
Payloads: none, 2.5 kg, and one per state, at the end link's origin.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import pytest
import torch

from rbfn.robots.arm_terms import ArmTerms
from rbfn.robots.backend import Dynamics, spd_solve
from rbfn.robots.scara import ScaraTerms
from tests.robots import test_dynamics as dynamics_tests

BATCH = 600  # above arm_terms.WIDE: its wide code paths
NARROW = 7  # below it: the narrow ones
ROBOTS = ["scara", "ur5", "panda", "test_arm"]  # the test arm: everything the loader lumps
PAYLOADS = ["none", "2.5 kg", "per state"]


class State(NamedTuple):
    """Joints q (B, n) rad or m, rates qd (B, n), any joint vector y (B, n), payload kg (float or (B,))."""

    q: torch.Tensor
    qd: torch.Tensor
    y: torch.Tensor
    payload: float | torch.Tensor


def _mv(m: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return (m @ x.unsqueeze(-1)).squeeze(-1)


_arm = functools.cache(dynamics_tests._arm)


@functools.cache
def _case(robot: str, payload: str) -> tuple[State, dict[str, torch.Tensor]]:
    """The states of a (robot, payload) case and the specification's quantities there."""
    arm = _arm(robot)
    g = torch.Generator().manual_seed(ROBOTS.index(robot))
    low, high = (x.clamp(-torch.pi, torch.pi) for x in arm.joint_limits())
    q = low + (high - low) * torch.rand(BATCH, arm.n, generator=g, dtype=torch.float64)
    qd = torch.randn(BATCH, arm.n, generator=g, dtype=torch.float64)
    y = torch.randn(BATCH, arm.n, generator=g, dtype=torch.float64)
    p = {"none": 0.0, "2.5 kg": 2.5, "per state": 4 * torch.rand(BATCH, generator=g, dtype=torch.float64)}[payload]
    m, c = arm.mass_matrix(q, p), arm.coriolis(q, qd, p)
    ref = {
        "M": m,
        "M y": _mv(m, y),
        "C qd + G": arm.bias(q, qd, p),
        "G": arm.gravity(q, p),
        "C y": _mv(c, y),
        "C^T qd": _mv(c.transpose(1, 2), qd),
        "M^-1 y": torch.linalg.solve(m, y),
        "dM/dt qd - C qd - G": _mv(arm.mass_matrix_dot(q, qd, p), qd) - _mv(c, qd) - arm.gravity(q, p),
        "M^-1 (y - C qd - G)": torch.linalg.solve(m, y - arm.bias(q, qd, p)),
    }
    return State(q, qd, y, p), ref


# ----------------------------------------------------------------------------- backends
def _arm_routes(robot: str, s: State) -> dict[str, torch.Tensor]:
    """Arm's M from `dynamics`, C qd + G from the matrix C, G as RNEA at rest."""
    arm = _arm(robot)
    m, _ = arm.dynamics(s.q, s.qd, s.payload)  # M of the one-pass route
    c, g = arm.coriolis(s.q, s.qd, s.payload), arm.gravity(s.q, s.payload)
    zero = torch.zeros_like(s.q)
    return {"M": m, "C qd + G": _mv(c, s.qd) + g, "G": arm.inverse_dynamics(s.q, zero, zero, s.payload)}


def _terms(make: Callable[[str], Dynamics]) -> Callable[[str, State], dict[str, torch.Tensor]]:
    """A backend's every term (`rbfn.robots.backend.Terms`), the friction in its forward dynamics none."""

    def run(robot: str, s: State) -> dict[str, torch.Tensor]:
        cfg = make(robot).at(s.q, s.payload)
        mo = cfg.motion(s.qd)
        return {
            "M": cfg.mass_matrix(),
            "M y": cfg.mass_times(s.y),
            "C qd + G": cfg.bias(s.qd),
            "G": cfg.gravity().expand_as(s.q),  # (the SCARA's G is one (3,) vector for every q)
            "C y": cfg.coriolis_times(s.qd, s.y, mo),
            "C^T qd": cfg.coriolis_transpose_qd(s.qd, mo),
            "M^-1 y": cfg.solve(s.y),
            "dM/dt qd - C qd - G": cfg.momentum_rate(s.qd, mo),
            "M^-1 (y - C qd - G)": cfg.accel(s.qd, s.y, lambda r, qd: r),
        }

    return run


def _narrow(robot: str, s: State) -> dict[str, torch.Tensor]:
    """ArmTerms on NARROW states at a time."""
    parts = [
        _terms(lambda r: ArmTerms(_arm(r)))(
            robot, State(*(x[i : i + NARROW] if torch.is_tensor(x) and x.dim() else x for x in s))
        )
        for i in range(0, BATCH, NARROW)
    ]
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def _written_out(robot: str, s: State) -> dict[str, torch.Tensor]:
    """M^-1 y and the forward dynamics as ArmTerms computes them compiled: `spd_solve` on its M."""
    cfg = ArmTerms(_arm(robot)).at(s.q, s.payload)
    return {
        "M^-1 y": spd_solve(cfg.mass_matrix(), s.y),
        "M^-1 (y - C qd - G)": spd_solve(cfg.mass_matrix(), s.y - cfg.bias(s.qd)),
    }


def _closed_form(robot: str, s: State) -> dict[str, torch.Tensor]:
    """The SCARA's closed forms."""
    from rbfn.robots.scara.closed_form import coriolis, gravity, mass_matrix

    c, g, m = coriolis(s.q, s.qd, s.payload), gravity(s.q, s.payload), mass_matrix(s.q, s.payload)
    return {
        "M": m,
        "M y": _mv(m, s.y),
        "C qd + G": _mv(c, s.qd) + g,
        "G": g,
        "C y": _mv(c, s.y),
        "C^T qd": _mv(c.transpose(1, 2), s.qd),
    }


def _pinocchio(robot: str, s: State) -> dict[str, torch.Tensor]:
    """Pinocchio from the same URDF, joints off the chain locked at zero, the payload a point mass
    at the end link's frame added to its joint's body, the arm's gravity."""
    import numpy as np

    arm = _arm(robot)
    pin, model, _ = dynamics_tests._pinocchio(robot, arm, 0.0)
    model.gravity.linear = arm.gravity_vector.numpy()  # the SCARA's 9.8 m/s^2
    end = dynamics_tests._source(robot)[1]
    frame = model.frames[model.getFrameId(end)]
    body = model.inertias[frame.parentJoint].copy()
    data = model.createData()
    payload = torch.as_tensor(s.payload, dtype=torch.float64).expand(BATCH)
    out: dict[str, list] = {k: [] for k in ("M", "C qd + G", "G", "C")}
    neutral = pin.neutral(model)
    for qi, qdi, pi in zip(s.q.numpy(), s.qd.numpy(), payload.tolist()):
        model.inertias[frame.parentJoint] = body + pin.Inertia(pi, frame.placement.translation, np.zeros((3, 3)))
        qp = pin.integrate(model, neutral, qi)  # continuous joints: (cos, sin)
        m = pin.crba(model, data, qp)
        out["M"].append(np.triu(m) + np.triu(m, 1).T)
        out["C qd + G"].append(pin.rnea(model, data, qp, qdi, np.zeros(arm.n)).copy())
        out["G"].append(pin.computeGeneralizedGravity(model, data, qp).copy())
        out["C"].append(pin.computeCoriolisMatrix(model, data, qp, qdi).copy())
    t = {k: torch.from_numpy(np.stack(v)) for k, v in out.items()}
    c = t.pop("C")
    return {**t, "M y": _mv(t["M"], s.y), "C y": _mv(c, s.y), "C^T qd": _mv(c.transpose(1, 2), s.qd)}


def _mujoco(robot: str, s: State) -> dict[str, torch.Tensor]:
    """MuJoCo compiling the same URDF (`rbfn.robots.mjcf.arm_model`), one model per payload."""
    mujoco = pytest.importorskip("mujoco")
    import numpy as np

    from rbfn.robots.mjcf import arm_model

    if torch.is_tensor(s.payload):
        pytest.skip("a MuJoCo model carries one payload")
    arm = _arm(robot)
    model = arm_model(
        dynamics_tests._source(robot)[0],
        payload=s.payload,
        payload_link=arm.end_link,
        gravity=-float(arm.gravity_vector[2]),
    )
    data = mujoco.MjData(model)
    assert [model.joint(i).name for i in range(model.njnt)] == arm.joint_names
    out: dict[str, list] = {k: [] for k in ("M", "C qd + G", "G")}
    for qi, qdi in zip(s.q.numpy(), s.qd.numpy()):
        data.qpos[:] = qi
        for key, v in (("G", 0.0 * qdi), ("C qd + G", qdi)):
            data.qvel[:] = v
            mujoco.mj_forward(model, data)
            out[key].append(data.qfrc_bias.copy())
        m = np.zeros((arm.n, arm.n))
        mujoco.mj_fullM(model, data, m)
        out["M"].append(m)
    t = {k: torch.from_numpy(np.stack(v)) for k, v in out.items()}
    return {**t, "M y": _mv(t["M"], s.y)}


# backend -> (its quantities at a robot's states, the robots it models, the largest relative error)
BACKENDS: dict[str, tuple[Callable[[str, State], dict[str, torch.Tensor]], list[str], float]] = {
    "Arm, other routes": (_arm_routes, ROBOTS, 1e-12),
    "ArmTerms": (_terms(lambda r: ArmTerms(_arm(r))), ROBOTS, 1e-12),
    "ArmTerms, narrow": (_narrow, ROBOTS, 1e-12),
    "ArmTerms, compiled solve": (_written_out, ROBOTS, 1e-12),
    "ScaraTerms": (_terms(lambda r: ScaraTerms()), ["scara"], 1e-12),
    "SCARA closed-form matrices": (_closed_form, ["scara"], 1e-12),
    "Pinocchio": (_pinocchio, ROBOTS, 1e-11),
    # MuJoCo refuses the SCARA URDF's rods (no inertia about their axis) and the test arm's joints
    # off the chain; its own SCARA model is tests/robots/test_mjcf.py's.
    "MuJoCo": (_mujoco, ["ur5", "panda"], 1e-10),
}


@pytest.mark.parametrize("payload", PAYLOADS)
@pytest.mark.parametrize(("backend", "robot"), [(b, r) for b, (_, robots, _) in BACKENDS.items() for r in robots])
def test_backend_matches_the_specification(backend, robot, payload):
    run, _, tol = BACKENDS[backend]
    state, ref = _case(robot, payload)
    got = run(robot, state)
    assert got, backend
    errors = {}
    for key, x in got.items():
        assert x.dtype == torch.float64 and x.shape == ref[key].shape, (key, x.dtype, x.shape)
        d = (x - ref[key]).reshape(BATCH, -1).norm(dim=1)
        errors[key] = float((d / ref[key].reshape(BATCH, -1).norm(dim=1)).max())
    assert max(errors.values()) <= tol, errors


@pytest.mark.parametrize("robot", ["scara", "ur5"])
def test_a_scaled_backend_scales_each_term(robot):
    """`Dynamics.scaled(m, c, g)` (a nominal model): M by m, C by c, G by g, through every term;
    the SCARA's closed form folds the factors into its coefficients, the URDF recursion wraps it."""
    state, _ = _case(robot, "2.5 kg")
    base = ScaraTerms() if robot == "scara" else ArmTerms(_arm(robot))
    one, scaled = base.at(state.q, state.payload), base.scaled(0.9, 0.8, 0.85).at(state.q, state.payload)
    q, qd, y = state.q, state.qd, state.y
    mdot = _mv(_arm(robot).mass_matrix_dot(q, qd, state.payload), qd)
    want = {
        "M y": 0.9 * one.mass_times(y),
        "C y": 0.8 * one.coriolis_times(qd, y),
        "G": 0.85 * one.gravity(),
        "C^T qd": 0.8 * one.coriolis_transpose_qd(qd),
        "M^-1 y": one.solve(y) / 0.9,
        "dM/dt qd - C qd - G": 0.9 * mdot - 0.8 * one.coriolis_qd(qd) - 0.85 * one.gravity(),
    }
    got = {
        "M y": scaled.mass_times(y),
        "C y": scaled.coriolis_times(qd, y),
        "G": scaled.gravity(),
        "C^T qd": scaled.coriolis_transpose_qd(qd),
        "M^-1 y": scaled.solve(y),
        "dM/dt qd - C qd - G": scaled.momentum_rate(qd),
    }
    for key in want:
        assert torch.allclose(got[key].expand_as(q), want[key].expand_as(q), rtol=1e-12, atol=1e-12), key
