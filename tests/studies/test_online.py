"""evaluate.py's online part on a URDF arm with pose targets: its metrics and table."""

from rbfn.config import GainsConfig, OnlineConfig
from rbfn.studies.online import evaluate_online, online_table


def test_pose_network_reports_rotation_errors(panda_ckpt, tmp_path):
    cfg = OnlineConfig(duration=3.0, dt=0.002, sizes=[0.0, 0.03])
    m = evaluate_online(panda_ckpt, cfg, GainsConfig(), out_dir=tmp_path)
    assert m["path"] == "sinusoid" and m["robot"] == "panda" and m["joint_err_rms_last_2s"] is None
    for k in ("first_2s", "last_2s", "no_adapt", "analytic_nominal"):
        assert m[f"task_rot_err_deg_rms_{k}"] >= 0 and f"task_rot_err_deg_rms_{k}" in m["sweep"][1]
    assert m["task_rot_err_deg_rms_last_2s"] < m["task_rot_err_deg_rms_no_adapt"]
    assert m["sweep"][1]["offset_error"] == [0.02] + [0.0] * 6  # one offset per chain joint
    assert " / " in online_table(m).splitlines()[-1]
    assert (tmp_path / "checkpoint_online.pt").is_file() and (tmp_path / "online_task_error.png").is_file()
