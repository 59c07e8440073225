"""Exports reproduce the module: ONNX under onnxruntime and the torch.export program."""

import pytest
import torch

from rbfn.export import export_onnx, export_pt2
from rbfn.fit import design_matrix, ridge_fit
from rbfn.layer import assemble


@pytest.fixture(scope="module")
def net(small_data):
    x, q = small_data.train.x, small_data.train.q
    off = x.mean(0)
    c = (x[:15] - off).clone()
    w = torch.full((15,), 0.6, dtype=torch.float64)
    fit = ridge_fit(design_matrix(x - off, c, w), q, design_matrix(small_data.val.x - off, c, w), small_data.val.q)
    n = assemble(c, w, fit.weights, off, torch.ones(3, dtype=torch.float64), tail=True)
    n.set_domain(x, q)
    return n


@pytest.mark.parametrize("batch", [1, 7, 300])
def test_pt2_and_onnx_match_module(net, small_data, tmp_path, batch):
    x = small_data.test.x[:batch].float()
    with torch.no_grad():
        y_ref, in_ref = net.float().solve(x)
    net.double()
    prog = torch.export.load(str(export_pt2(net, tmp_path / "ik.pt2")))
    assert prog.graph_signature.user_inputs == ("positions",)  # the name position networks always had
    y, inside = prog.module()(x)
    assert torch.allclose(y, y_ref, atol=1e-5) and torch.equal(inside, in_ref)
    ort = pytest.importorskip("onnxruntime")
    sess = ort.InferenceSession(str(export_onnx(net, tmp_path / "ik.onnx")), providers=["CPUExecutionProvider"])
    assert [(i.name, i.shape) for i in sess.get_inputs()] == [("positions", ["batch", 3])]
    y_onnx, in_onnx = sess.run(None, {"positions": x.numpy()})
    assert abs(y_onnx - y_ref.numpy()).max() < 1e-5
    assert (in_onnx == in_ref.numpy()).all()


def _in_workspace_positions(n: int, seed: int = 5) -> torch.Tensor:
    """FK images (n, 3) float32 of joints drawn in the trained branch (data's joint box)."""
    from rbfn.robots import scara

    g = torch.Generator().manual_seed(seed)
    low = torch.tensor([0.0, 0.3, 0.5], dtype=torch.float64)
    high = torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    return scara.fk(low + torch.rand(n, 3, dtype=torch.float64, generator=g) * (high - low)).float()


def test_round_trip_10k_positions_batches_1_7_10000(net, tmp_path):
    """The round trip: ONNX (onnxruntime) and .pt2 reproduce the float32 module to 1e-5 on
    10k in-workspace positions, fed in batches of 1, 7 and 10000; prints the max differences."""
    ort = pytest.importorskip("onnxruntime")
    x = _in_workspace_positions(10_000)
    with torch.no_grad():
        y_ref, in_ref = net.float().solve(x)
    net.double()
    prog = torch.export.load(str(export_pt2(net, tmp_path / "ik.pt2"))).module()
    sess = ort.InferenceSession(str(export_onnx(net, tmp_path / "ik.onnx")), providers=["CPUExecutionProvider"])
    assert in_ref.float().mean() > 0.9  # the positions are in the trained workspace
    for batch in (1, 7, 10_000):
        parts = x.split(batch)
        with torch.no_grad():
            pt2 = [prog(p) for p in parts]
        onnx = [sess.run(None, {"positions": p.numpy()}) for p in parts]
        y_pt2, in_pt2 = torch.cat([p[0] for p in pt2]), torch.cat([p[1] for p in pt2])
        y_onnx = torch.cat([torch.from_numpy(o[0]) for o in onnx])
        in_onnx = torch.cat([torch.from_numpy(o[1]) for o in onnx])
        d_pt2, d_onnx = float((y_pt2 - y_ref).abs().max()), float((y_onnx - y_ref).abs().max())
        print(
            f"batch {batch}: max |pt2 - module| = {d_pt2:.3g}, max |onnx - module| = {d_onnx:.3g}, "
            f"workspace flags equal: {torch.equal(in_pt2, in_ref)} / {torch.equal(in_onnx, in_ref)}"
        )
        assert d_pt2 < 1e-5 and d_onnx < 1e-5
        assert torch.equal(in_pt2, in_ref) and torch.equal(in_onnx, in_ref)


def test_exports_agree_beside_a_narrow_gaussian_far_from_the_centroid(tmp_path):
    """The exported graphs take the exponents' product in float64 too (rbfn.layer): beside a
    Gaussian narrow beside its distance from the centres' centroid, where the product in float32
    put the exports 5e-3 from the float32 module, ONNX (onnxruntime) and .pt2 agree with it and
    with float64 within 2e-6 (measured 6e-7), and flag alike."""
    ort = pytest.importorskip("onnxruntime")
    from .test_layer import narrow_far_net

    net, x = narrow_far_net()
    with torch.no_grad():
        y64, in64 = net.solve(x)
        y32, in32 = net.for_export().solve(x)
        y_pt2, in_pt2 = torch.export.load(str(export_pt2(net, tmp_path / "ik.pt2"))).module()(x)
    sess = ort.InferenceSession(str(export_onnx(net, tmp_path / "ik.onnx")), providers=["CPUExecutionProvider"])
    y_onnx, in_onnx = (torch.from_numpy(a) for a in sess.run(None, {"positions": x.numpy()}))
    for y, inside in ((y_pt2, in_pt2), (y_onnx, in_onnx)):
        assert float((y - y32).abs().max()) < 2e-6 and float((y.double() - y64).abs().max()) < 2e-6
        assert torch.equal(inside, in32) and torch.equal(inside, in64)


def test_export_is_one_graph_whatever_the_eager_block_size(net, small_data, tmp_path):
    """The exported program does not split rows into blocks: one graph for any batch size."""
    import copy

    small = copy.deepcopy(net)
    small.block_rows = 8
    x = small_data.test.x[:50].float()
    with torch.no_grad():
        y_ref, in_ref = copy.deepcopy(small).float().solve(x)  # eager: 7 blocks
    prog = torch.export.load(str(export_pt2(small, tmp_path / "ik.pt2")))
    # One exp over the (B, M) exponents (the other exps act on (M,) constants: the cover shift's scale).
    assert sum(n.target == torch.ops.aten.exp.default and n.meta["val"].dim() == 2 for n in prog.graph.nodes) == 1
    y, inside = prog.module()(x)
    assert torch.allclose(y, y_ref, atol=1e-6) and torch.equal(inside, in_ref)


@pytest.mark.parametrize("batch", [1, 8, 9, 50])
def test_onnx_runs_rows_in_blocks_row_for_row_as_one_pass(net, small_data, tmp_path, batch):
    """The ONNX graph's Scan over blocks of at most 8 rows (padded to equal blocks) gives bitwise
    the answers of one block holding every row, for batches below, at and across the block size."""
    ort = pytest.importorskip("onnxruntime")
    import onnx

    path = export_onnx(net, tmp_path / "ik8.onnx", block_rows=8)
    (branch,) = [n for n in onnx.load(str(path)).graph.node if n.op_type == "If"]
    in_blocks = next(a.g for a in branch.attribute if a.name == "then_branch")  # B > 8
    assert [n.op_type for n in in_blocks.node].count("Scan") == 1
    blocked = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    whole = ort.InferenceSession(
        str(export_onnx(net, tmp_path / "ik.onnx", block_rows=64)), providers=["CPUExecutionProvider"]
    )
    x = small_data.test.x[:batch].float().numpy()
    (y8, in8), (y, inside) = blocked.run(None, {"positions": x}), whole.run(None, {"positions": x})
    assert y8.shape == (batch, 3) and in8.shape == (batch,) and in8.dtype == bool
    assert (y8 == y).all() and (in8 == inside).all()


@pytest.fixture(scope="module")
def pose_run(tmp_path_factory):
    """A tiny UR5 pose network trained with its exports: the run directory."""
    import train

    from .conftest import TINY_TRAIN, compose_config

    out = tmp_path_factory.mktemp("ur5")
    tiny = [o for o in TINY_TRAIN if not o.startswith("export=")]
    train.run(compose_config("train", "robot=ur5", *tiny), out)
    return out


def test_a_pose_network_is_solved_through_its_poses_input(pose_run):
    """Training's ik.onnx and ik.pt2 of a pose network take "poses" (B, 7), reproduce the float32
    module to 1e-5 and carry the same metadata: example targets the robot's joints reach."""
    ort = pytest.importorskip("onnxruntime")
    import json

    from rbfn.checkpoint import load_model, read_checkpoint
    from rbfn.data import make_split
    from rbfn.robots.robot import robot_from_record

    robot = robot_from_record(read_checkpoint(pose_run / "checkpoint.pt")["robot"])
    x = make_split(robot, 50, seed=5).x.float()
    from rbfn.export import CHECKSUM_KEY, deployed, load_pt2, read_onnx

    with torch.no_grad():  # the exports turn targets around the base (the UR5's first joint) as this module does
        y_ref, in_ref = deployed(load_model(pose_run / "checkpoint.pt"), robot)(x)
    assert in_ref.any() and y_ref.shape == (50, 6)

    sess = ort.InferenceSession(read_onnx(pose_run / "ik.onnx"), providers=["CPUExecutionProvider"])
    (inp,) = sess.get_inputs()
    assert (inp.name, inp.shape) == ("poses", ["batch", 7])
    y_onnx, in_onnx = sess.run(["joints", "in_workspace"], {"poses": x.numpy()})
    assert abs(y_onnx - y_ref.numpy()).max() < 1e-5 and (in_onnx == in_ref.numpy()).all()

    files = {"rbfn.json": ""}
    prog = load_pt2(pose_run / "ik.pt2", extra_files=files)
    assert prog.graph_signature.user_inputs == ("poses",)
    with torch.no_grad():
        y_pt2, in_pt2 = prog.module()(x)
    assert float((y_pt2 - y_ref).abs().max()) < 1e-5 and torch.equal(in_pt2, in_ref)

    meta = sess.get_modelmeta().custom_metadata_map
    assert len(meta.pop(CHECKSUM_KEY)) == 64 and json.loads(files["rbfn.json"]) == meta  # the same, but the checksum
    assert meta["target"] == "pose" and meta["input"].startswith("poses (B, 7)") and meta["robot"] == "ur5"
    assert json.loads(meta["joint_names"]) == robot.joint_names
    q = torch.tensor(json.loads(meta["example_joints"]), dtype=torch.float64)
    assert q.shape == (4, 6) and ((q > robot.low) & (q < robot.high)).all()
    assert torch.equal(torch.tensor(json.loads(meta["example_targets"]), dtype=torch.float64), robot.targets(q))


def _run_example(path, capsys) -> list[str]:
    """What examples/deploy_onnx.py prints for the model at `path`, line by line."""
    import runpy

    from .conftest import ROOT

    runpy.run_path(str(ROOT / "examples" / "deploy_onnx.py"))["main"](str(path))
    return capsys.readouterr().out.splitlines()


def test_the_deploy_example_runs_on_position_and_pose_networks(net, scara_robot, pose_run, tmp_path, capsys):
    """examples/deploy_onnx.py reads the input's name and width from the file and solves its
    example targets (in the workspace) and one 10 m away (flagged), for either kind of network."""
    pytest.importorskip("onnxruntime")
    lines = _run_example(export_onnx(net, tmp_path / "ik.onnx", robot=scara_robot), capsys)
    assert lines[0].startswith(f"{scara_robot.name}: input 'positions' ['batch', 3]")
    pose_lines = _run_example(pose_run / "ik.onnx", capsys)
    assert pose_lines[0].startswith("ur5: input 'poses' ['batch', 7], outputs the joints ['shoulder_pan_joint',")
    for out in (lines, pose_lines):  # both arms turn about the base: a 7th line, the first example turned 2 rad
        assert len(out) == 7 and all("in workspace True" in line for line in out[1:5])
        assert out[5].endswith("max joint error -- (10 m away)  in workspace False")
        change = float(out[6].split("changes by ")[1].split(" rad")[0])
        assert out[6].startswith("target 0 turned 2 rad about the base") and abs(change - 2.0) < 0.05
    with pytest.raises(SystemExit, match=r"holds no example targets: export it again with python -m rbfn\.export"):
        _run_example(export_onnx(net, tmp_path / "bare.onnx"), capsys)  # no robot given: no examples


def test_exports_turn_targets_around_the_base_as_the_module_does(net, scara_robot, tmp_path):
    """Given the robot (the SCARA's first joint turns about the base's vertical axis), ONNX and
    .pt2 turn targets anywhere around the base into the trained range in their graph: they agree
    with the torch module within 1e-5, flag alike, and say so in their metadata; exported without
    the robot or with base_yaw=False they are the network as trained."""
    ort = pytest.importorskip("onnxruntime")
    import math

    from rbfn.export import deployed

    g = torch.Generator().manual_seed(11)
    q = scara_robot.low + torch.rand(300, 3, dtype=torch.float64, generator=g) * (scara_robot.high - scara_robot.low)
    q[150:, 0] = (2 * torch.rand(150, dtype=torch.float64, generator=g) - 1) * math.pi  # the whole turn
    x = scara_robot.targets(q).float()
    net.double()
    with torch.no_grad():
        y_ref, in_ref = deployed(net, scara_robot)(x)
    sess = ort.InferenceSession(
        str(export_onnx(net, tmp_path / "ik.onnx", robot=scara_robot)), providers=["CPUExecutionProvider"]
    )
    y_onnx, in_onnx = sess.run(None, {"positions": x.numpy()})
    assert abs(y_onnx - y_ref.numpy()).max() < 1e-5 and (in_onnx == in_ref.numpy()).all()
    assert sess.get_modelmeta().custom_metadata_map["base_yaw"] == "true"
    prog = torch.export.load(str(export_pt2(net, tmp_path / "ik.pt2", robot=scara_robot))).module()
    y_pt2, in_pt2 = prog(x)
    assert float((y_pt2 - y_ref).abs().max()) < 1e-5 and torch.equal(in_pt2, in_ref)
    # The turned half is answered as well as the half inside the box, and the first joint lies in its limits.
    err, _ = scara_robot.errors(y_ref.double(), x.double())
    assert float(err[150:].median()) < 1.5 * float(err[:150].median())
    assert (y_ref[:, 0].abs() <= math.pi + 1e-6).all()
    plain = ort.InferenceSession(
        str(export_onnx(net, tmp_path / "plain.onnx", robot=scara_robot, base_yaw=False)),
        providers=["CPUExecutionProvider"],
    )
    with torch.no_grad():
        y_net, _ = net.float().solve(x)
    net.double()
    assert abs(plain.run(None, {"positions": x.numpy()})[0] - y_net.numpy()).max() < 1e-5
    assert plain.get_modelmeta().custom_metadata_map["base_yaw"] == "false"


# --- Integrity: a changed byte in an export stops its reader; a file of another kind says what it is ----


def _flipped(path, tmp_path, where: float):
    """A copy of `path` with one bit changed at fraction `where` of its length."""
    data = bytearray(path.read_bytes())
    i = min(int(where * len(data)), len(data) - 1)
    data[i] ^= 0x04
    copy = tmp_path / f"{where}{path.suffix}"
    copy.write_bytes(bytes(data))
    return copy


_WHERE = [0.0, 0.001, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 0.999, 1.0]


def test_a_changed_byte_in_an_export_stops_its_readers(pose_run, tmp_path, capsys):
    """ik.onnx holds its SHA-256 in its metadata, ik.pt2 in its zip comment: read_onnx, load_pt2 and
    examples/deploy_onnx.py (numpy and onnxruntime only) check it, so a changed byte anywhere is an
    error naming the file instead of other joints."""
    pytest.importorskip("onnxruntime")
    from rbfn.export import load_pt2, onnx_checksum, read_onnx

    onnx_file, pt2_file = pose_run / "ik.onnx", pose_run / "ik.pt2"
    stored, actual = onnx_checksum(read_onnx(onnx_file))
    assert stored == actual and len(stored) == 64
    load_pt2(pt2_file)
    for where in _WHERE:
        bad = _flipped(onnx_file, tmp_path, where)
        with pytest.raises(ValueError, match=rf"^{bad} (is corrupted|holds no sha256 checksum|is not an ONNX)"):
            read_onnx(bad)
        with pytest.raises(SystemExit, match=rf"^{bad} (is corrupted|holds no sha256 checksum)"):
            _run_example(bad, capsys)
        bad = _flipped(pt2_file, tmp_path, where)
        with pytest.raises(ValueError, match=rf"^{bad} (is corrupted|is not a readable torch.export program)"):
            load_pt2(bad)
    assert capsys.readouterr().out == ""  # the example printed no joints


def test_files_handed_to_the_wrong_reader_say_what_they_are(pose_run, tmp_path, capsys):
    """An export given to a checkpoint's readers, a checkpoint or .pt2 given to the ONNX readers, and
    a directory, FIFO, device or URL given to any: one line naming the file and what it is."""
    pytest.importorskip("onnxruntime")
    from rbfn import load_model, load_solver
    from rbfn.checkpoint import read_checkpoint
    from rbfn.export import load_pt2, read_onnx

    onnx_file, pt2_file, ckpt = pose_run / "ik.onnx", pose_run / "ik.pt2", pose_run / "checkpoint.pt"
    for load in (load_model, load_solver, read_checkpoint):
        with pytest.raises(
            ValueError,
            match=rf"^{onnx_file} is an ONNX model \(an export such as ik.onnx\), not a checkpoint: exports run without aco-rbfn",
        ):
            load(onnx_file)
        with pytest.raises(
            ValueError, match=rf"^{pt2_file} is a torch.export program \(an export such as ik.pt2\), not a checkpoint"
        ):
            load(pt2_file)
    with pytest.raises(
        ValueError, match=rf"^{ckpt} is a torch.save archive \(a checkpoint such as checkpoint.pt\), not an ONNX model"
    ):
        read_onnx(ckpt)
    with pytest.raises(ValueError, match=rf"^{pt2_file} is a torch.export program .*, not an ONNX model"):
        read_onnx(pt2_file)
    with pytest.raises(ValueError, match=rf"^{onnx_file} is an ONNX model .*, not a torch.export program"):
        load_pt2(onnx_file)
    with pytest.raises(ValueError, match=rf"^{ckpt} is a torch.save archive .*, not a torch.export program"):
        load_pt2(ckpt)
    for path in (ckpt, pt2_file):
        with pytest.raises(
            SystemExit,
            match=rf"^{path} is a zip archive \(an aco-rbfn checkpoint.pt or ik.pt2 program\), not an ONNX model",
        ):
            _run_example(path, capsys)
    import os

    os.mkfifo(tmp_path / "fifo")
    for path, kind in (
        (tmp_path, "a directory"),
        (tmp_path / "fifo", r"a FIFO \(named pipe\)"),
        (os.devnull, "a character device"),
    ):
        with pytest.raises(SystemExit, match=rf"^{path} is {kind}, not an ONNX model"):
            _run_example(path, capsys)
        for read in (read_onnx, load_pt2):
            with pytest.raises(ValueError, match=rf"^{path} is {kind}, not an? (ONNX model|torch.export program)"):
                read(path)
    url = "https://example.com/run/ik.onnx"
    with pytest.raises(SystemExit, match=rf"^{url} is a URL; this example reads a local file: download it first"):
        _run_example(url, capsys)
    for read in (read_onnx, load_pt2):
        with pytest.raises(ValueError, match=rf"^{url} is a URL; aco-rbfn reads and writes local files only"):
            read(url)
    assert capsys.readouterr().out == ""
