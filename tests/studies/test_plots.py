"""The figures read well for any arm: titles name the robot drawn, 6- and 7-joint layouts do not
overlap, the payload band is named, and a pose network's IK figure is a readable curve."""

import io
import itertools

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from rbfn.config import EvalConfig, RobotConfig, Target
from rbfn.robots.kinematics import read_urdf, urdf_path
from rbfn.studies.evaluation import evaluated_robots
from rbfn.studies.plots import (
    BEYOND_LABEL,
    LIMIT_LABEL,
    PAYLOAD_LABEL,
    online_figure,
    pose_error_figure,
    robot_label,
    tracking_figure,
    workspace_error_map,
)

OTHERS = ("scara", "ur5", "panda", "None")


def _z1_text() -> str:
    """The UR5's URDF under another robot name: a 6-joint arm the project does not ship."""
    return read_urdf(urdf_path("ur5")).replace('<robot name="ur5"', '<robot name="z1"', 1)


def _tracking(n: int, seed: int = 0, cases: int = 3, **kw):
    """The tracking figure of n joints with long URDF names and `cases` payload cases, synthetic
    signals whose scales span 1e-6 to 1e4."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, 3000)
    q_des = 0.5 * np.sin(t[:, None] * np.arange(1, n + 1))
    q_des[:, 1] = 1.5708  # a joint held still: offset tick labels
    noise = 1e-4 * rng.standard_normal((t.size, cases, n)) * np.geomspace(1e-2, 1e3, n)
    q = q_des[:, None] + noise
    tau = rng.standard_normal((t.size, cases, n)) * np.geomspace(0.5, 2e4, n)
    names = [f"shoulder_pan_joint_{j + 1}" for j in range(n)]
    labels = [f"{m:g} kg" for m in range(cases)]
    return tracking_figure(t, q, q_des, tau, robot="z1", detail="smc", cases=labels, joint_names=names, **kw)


def _titles(fig) -> list[str]:
    out = [ax.get_title() for ax in fig.axes]
    return out + ([fig._suptitle.get_text()] if fig._suptitle is not None else [])


def _no_other_robot(fig, robot: str) -> str:
    text = " | ".join(_titles(fig))
    assert robot in text, text
    assert not any(o in text for o in OTHERS), text
    return text


def test_robot_label_is_the_robots_own_name_never_a_leftover_default(tmp_path):
    path = tmp_path / "z1.urdf"
    path.write_text(_z1_text())
    assert robot_label("scara", "scara") == "scara"  # a preset and its URDF
    assert robot_label("ur5", read_urdf(urdf_path("ur5"))) == "ur5"
    # robot.urdf given, robot.name left at its default: the URDF's own name, file or checkpoint text
    assert robot_label("scara", path) == "z1" and robot_label("scara", _z1_text()) == "z1"
    assert robot_label("", _z1_text()) == "z1"
    assert robot_label("my_z1", path) == "my_z1"  # a name the user chose
    cfg = EvalConfig(robot=RobotConfig(urdf=str(path), end_link="ee_link", joint_low=[-1.0] * 6, joint_high=[1.0] * 6))
    record = {"name": "scara", "urdf": _z1_text(), "end_link": "ee_link", "joint_low": [-1.0] * 6}
    robots, _ = evaluated_robots(cfg, {"robot": record})
    assert robots == dict.fromkeys(("ik", "online", "control"), "z1 (ee_link, 6 joints)")


def test_titles_name_the_robot_passed_in_and_no_none():
    rng = np.random.default_rng(1)
    x, err, inside = rng.uniform(-1, 1, (200, 3)), rng.uniform(0.01, 5, 200), rng.uniform(size=200) < 0.9
    q = rng.uniform(-1, 1, (200, 6))
    _no_other_robot(workspace_error_map(x, err, inside, robot="z1", num_centers=40), "z1")
    _no_other_robot(pose_error_figure(q, -np.ones(6), np.ones(6), err, inside, robot="z1", num_centers=40), "z1")
    _no_other_robot(_tracking(6), "z1")
    t = np.linspace(0, 3, 300)
    e = np.abs(np.sin(t)) + 0.1
    unnamed_path = online_figure(t, e, e, e, t[::10], t[::10], robot="z1", learner="rls", path=None)
    assert "path" not in _no_other_robot(unnamed_path, "z1")
    named = online_figure(t, e, e, e, t[::10], t[::10], robot="z1", learner="rls", path="sinusoid", link_error=0.05)
    assert "path sinusoid" in _no_other_robot(named, "z1")
    for bad in ("", "None", None):
        with pytest.raises(ValueError, match="names the robot"):
            workspace_error_map(x, err, inside, robot=bad, num_centers=40)


def _boxes(ax, renderer) -> list:
    """Window boxes of the axes' drawn texts: tick labels within its view, axis labels, offset texts."""
    out = []
    for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        lo, hi = min(lo, hi), max(lo, hi)
        tol = 1e-9 * (hi - lo)
        for tick in axis.get_major_ticks():
            if tick.label1.get_visible() and tick.label1.get_text() and lo - tol <= tick.get_loc() <= hi + tol:
                out.append(tick.label1.get_window_extent(renderer))
        for text in (axis.label, axis.get_offset_text()):
            if text.get_visible() and text.get_text():
                out.append(text.get_window_extent(renderer))
    return out


@pytest.mark.parametrize("n", [3, 6, 7])
def test_many_joint_tracking_figure_lays_out_without_overlap(n):
    fig = _tracking(n, window=(1.0, 3.0))
    assert len(fig.axes) == 3 * n
    canvas = FigureCanvasAgg(fig)  # the figures are backend-free; Agg measures the text
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = {ax: _boxes(ax, renderer) for ax in fig.axes}
    for a, b in itertools.permutations(fig.axes, 2):
        for box in boxes[a]:
            assert not box.overlaps(b.bbox), (a.get_ylabel(), "text in the panel of", b.get_ylabel())
            hit = [other for other in boxes[b] if box.overlaps(other)]
            assert not hit, (a.get_ylabel(), b.get_ylabel())
    suptitle = fig._suptitle.get_window_extent(renderer)
    assert not any(suptitle.overlaps(ax.bbox) for ax in fig.axes)


def test_the_tracking_figure_draws_every_case_and_names_the_joints():
    fig = _tracking(6, cases=3)
    names = [x.get_text() for x in fig.legends[0].get_texts()]
    assert names[:4] == ["desired", "0 kg", "1 kg", "2 kg"]
    assert all(len(ax.lines) >= 3 for ax in fig.axes)  # one line a case in every panel
    assert [fig.axes[3 * j].get_ylabel() for j in range(6)] == [f"shoulder_pan_joint_{j + 1} [rad]" for j in range(6)]
    assert fig.axes[2].get_ylabel() == "[N m]" and fig.axes[0].get_title() == "position"
    with pytest.raises(ValueError, match="one name per case"):
        tracking_figure(
            np.arange(3.0),
            np.zeros((3, 2, 1)),
            np.zeros((3, 1)),
            np.zeros((3, 2, 1)),
            robot="z1",
            detail="pd",
            cases=["a"],
        )


def _inside_the_figure(fig) -> None:
    """Every text drawn (titles, tick labels within view, axis labels, the colour bar's) lies
    within the figure."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    whole = fig.bbox
    for ax in fig.axes:
        boxes = _boxes(ax, renderer) + [ax.title.get_window_extent(renderer)] * bool(ax.get_title())
        for box in boxes:
            assert whole.x0 - 1 <= box.x0 and box.x1 <= whole.x1 + 1, (ax.get_ylabel(), box)
            assert whole.y0 - 1 <= box.y0 and box.y1 <= whole.y1 + 1, (ax.get_ylabel(), box)


@pytest.mark.parametrize("spread", [(3.0, 1.5), (1.0, 3.0)])
def test_the_workspace_map_clips_no_label(spread):
    """A workspace wider than tall (the SCARA's) or taller than wide keeps its axis labels in the figure."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (3000, 3)) * np.array([*spread, 0.0])
    _inside_the_figure(
        workspace_error_map(x, rng.uniform(0.01, 2, 3000), np.ones(3000, bool), robot="scara", num_centers=80)
    )


def test_the_payload_band_is_named_in_the_legend():
    legend = _tracking(6, window=(1.0, 3.0)).legends[0]
    assert any(t.get_text().startswith(PAYLOAD_LABEL) for t in legend.get_texts())
    legend = _tracking(6).legends[0]
    assert not any(PAYLOAD_LABEL in t.get_text() for t in legend.get_texts())


def test_joint_limits_are_drawn_near_the_curves_and_breaches_marked():
    n = 3
    t = np.linspace(0.0, 4.0, 3000)
    q_des = 0.5 * np.sin(t[:, None] * np.arange(1, n + 1))
    q = q_des.copy()
    q[1500, 0] = 0.7  # one sample past joint 1's upper limit: thinning must not hide it
    lower, upper = [-0.6, -np.inf, -50.0], [0.6, np.inf, 50.0]  # joint 3's limits far from its range
    fig = tracking_figure(t, q, q_des, q, robot="z1", detail="pd", limits=(lower, upper))
    lines = {r: [ln for ln in fig.axes[3 * r].lines if ln.get_label() == LIMIT_LABEL] for r in range(n)}
    assert sorted(ln.get_ydata()[0] for ln in lines[0]) == [-0.6, 0.6]
    assert lines[1] == [] and lines[2] == []  # none, and too far to draw without flattening the curves
    marks = [ln for ax in fig.axes for ln in ax.lines if ln.get_label() == BEYOND_LABEL]
    assert len(marks) == 1 and marks[0].get_xdata().size >= 1
    names = [x.get_text() for x in fig.legends[0].get_texts()]
    assert LIMIT_LABEL in names and BEYOND_LABEL in names
    clean = tracking_figure(t, q_des, q_des, q, robot="z1", detail="pd", limits=(lower, upper))
    assert BEYOND_LABEL not in [x.get_text() for x in clean.legends[0].get_texts()]


def test_pose_error_figure_draws_the_error_against_the_distance_from_the_box_centre():
    rng = np.random.default_rng(2)
    low, high = -np.ones(7), np.full(7, 3.0)
    q = rng.uniform(low, high, (3000, 7))
    d = np.abs(q - 1.0).max(axis=1) / 2.0
    err = 0.1 + 10 * d**8  # mm: worse toward the box's edge
    fig = pose_error_figure(q, low, high, err, d < 0.98, robot="z1", num_centers=2000)
    (ax,) = fig.axes
    assert ax.get_yscale() == "log" and ax.get_xlim() == (0.0, 1.0)
    median = next(line for line in ax.lines if line.get_label() == "median per bin")
    x, y = median.get_data()
    assert np.all((x > 0) & (x < 1)) and np.all(np.diff(y) > 0)  # the rise toward the edge shows
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=60)
    assert buf.getvalue()[:4] == b"\x89PNG"


def test_ik_figure_of_a_urdf_pose_arm_names_it_from_its_urdf(tmp_path):
    """robot.urdf given, robot.name left at "scara": the IK figure is the pose figure, titled "z1"."""
    from rbfn.robots.robot import load_robot
    from rbfn.studies.ik import _error_figure

    path = tmp_path / "z1.urdf"
    path.write_text(_z1_text())
    home = [0.0, -1.2, 1.5, -1.9, -1.57, 0.0]
    robot = load_robot(
        RobotConfig(
            urdf=str(path),
            end_link="ee_link",
            target=Target.pose,
            joint_low=[h - 0.5 for h in home],
            joint_high=[h + 0.5 for h in home],
        )
    )
    assert robot.name == "scara"  # the default, which no figure may show
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.low.numpy(), robot.high.numpy(), (300, 6))
    err, inside = rng.uniform(0.01, 5.0, 300), np.ones(300, bool)
    fig = _error_figure(robot, q, np.zeros((300, 7)), err, inside, num_centers=40)
    assert _no_other_robot(fig, "z1").startswith("z1: IK position error against the joint box")
