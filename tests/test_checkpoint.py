"""Checkpoints: weights-only loadable, written atomically, and every broken file says what is wrong."""

import os
import re
import reprlib
import signal
import subprocess
import sys
import time

import pytest
import torch

from rbfn.checkpoint import (
    FORMAT_VERSION,
    MIN_WIDTH,
    atomic_write_bytes,
    load_model,
    load_sealed,
    model_from_checkpoint,
    read_checkpoint,
    save_checkpoint,
    save_sealed,
    seal,
)
from rbfn.config import RobotConfig
from rbfn.layer import RBFNetwork
from rbfn.resume import StateFile, TrainState
from rbfn.robots.robot import load_robot
from tests.guarded import run_guarded

ROBOT = load_robot(RobotConfig()).record()  # the SCARA: 3 free joints, position targets


def _resave(raw, path):
    """Write an edited checkpoint dict with a valid seal, as another writer would."""
    import io

    buf = io.BytesIO()
    torch.save(raw, buf)
    path.write_bytes(seal(buf.getvalue()))


@pytest.fixture()
def ckpt(tmp_path):
    net = RBFNetwork(torch.randn(5, 3, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 3)
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, net, ROBOT, {"seed": 0}, {"x": 1.0})
    return path, net


def test_round_trip_weights_only(ckpt):
    path, net = ckpt
    raw = torch.load(path, weights_only=True)
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == "rbfn-ik"
    loaded = load_model(path, dtype=torch.float64)
    x = torch.randn(4, 3, dtype=torch.float64)
    assert torch.allclose(loaded(x), net(x).detach())


def test_load_model_dtype(ckpt):
    path, net = ckpt
    x = torch.randn(4, 3, dtype=torch.float64)
    model = load_model(path)  # float32 for inference by default
    assert model.centers.dtype == torch.float32 and model(x).dtype == torch.float32
    assert all(t.dtype == torch.float32 for t in model.state_dict().values())
    assert (model(x).double() - net(x).detach()).abs().max() < 1e-5
    assert load_model(path, dtype=torch.float64).centers.dtype == torch.float64
    for bad in (torch.float16, torch.int64, "float32", 64):
        with pytest.raises(
            ValueError,
            match=rf"load_model\(dtype={re.escape(repr(bad))}\): allowed are torch.float32 "
            r"\(the default\) and torch.float64",
        ):
            load_model(path, dtype=bad)


def test_truncated_file(ckpt):
    path, _ = ckpt
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"not a readable checkpoint .truncated or corrupted"):
        read_checkpoint(path)


def test_flipped_byte(ckpt):
    path, _ = ckpt
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0xFF
    path.write_bytes(bytes(data))
    # Wherever the byte is, reading fails clearly: the zip or pickle structure breaks, or a
    # payload byte changes and the checksum no longer matches.
    with pytest.raises(ValueError, match=r"not a readable checkpoint|is corrupted"):
        read_checkpoint(path)


@pytest.mark.parametrize("where", [0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 1.0])
def test_flipped_byte_anywhere(ckpt, where):
    path, _ = ckpt
    data = bytearray(path.read_bytes())
    data[min(int(len(data) * where), len(data) - 1)] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"not a readable checkpoint|is corrupted"):
        read_checkpoint(path)


def test_wrong_format_version(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["format_version"] = FORMAT_VERSION + 1
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"format {FORMAT_VERSION + 1}.*reads format {FORMAT_VERSION}"):
        read_checkpoint(path)


def test_missing_key(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["state_dict"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"missing checkpoint keys \['state_dict'\]"):
        read_checkpoint(path)


def test_other_model_kind(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["kind"] = "controller"
    _resave(raw, path)
    with pytest.raises(ValueError, match="holds a 'controller' model"):
        read_checkpoint(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint at"):
        read_checkpoint(tmp_path / "nope.pt")


def test_killed_writer_leaves_no_half_written_checkpoint(tmp_path):
    # A child process writes a large checkpoint over and over; kill it mid-write. The path holds
    # either nothing or a complete, loadable checkpoint, and no temporary file is left.
    script = f"""
import torch
from rbfn.checkpoint import save_checkpoint
from rbfn.layer import RBFNetwork
net = RBFNetwork(torch.randn(20000, 3, dtype=torch.float64), torch.ones(20000, dtype=torch.float64), 3)
while True:
    save_checkpoint({str(tmp_path / "checkpoint.pt")!r}, net, {ROBOT!r}, {{}}, {{}})
    print("wrote", flush=True)
"""
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "wrote"  # one complete file, the next write under way
    time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    path = tmp_path / "checkpoint.pt"
    assert load_model(path).num_centers == 20000
    leftovers = [p for p in os.listdir(tmp_path) if p != "checkpoint.pt"]
    # SIGKILL gives no chance to clean up: a temp file may remain, but never under the real name.
    assert all(p.endswith(".tmp") for p in leftovers)


def test_flipped_byte_in_the_seal_region_is_damage_not_a_foreign_file(ckpt):
    # Every byte of the zip end record and the seal: a changed one reads as damage, never as
    # "not an aco-rbfn checkpoint".
    path, _ = ckpt
    good = path.read_bytes()
    for back in range(1, 22 + 80 + 1):
        data = bytearray(good)
        data[-back] ^= 0x01
        path.write_bytes(bytes(data))
        with pytest.raises(ValueError, match=r"not a readable checkpoint .truncated or corrupted|is corrupted"):
            read_checkpoint(path)


def test_plain_torch_save_is_not_an_aco_rbfn_checkpoint(ckpt):
    path, _ = ckpt
    torch.save(torch.load(path, weights_only=True), path)  # valid zip archive, no seal
    with pytest.raises(ValueError, match="is not an aco-rbfn checkpoint: it has no aco-rbfn seal") as e:
        read_checkpoint(path)
    assert str(path) in str(e.value) and "torch.save" in str(e.value) and "truncated" not in str(e.value)


class _Opaque:
    """A class weights-only unpickling refuses."""


def test_sealed_file_with_objects_is_refused_without_suggesting_unsafe_load(tmp_path):
    path = tmp_path / "checkpoint.pt"
    save_sealed(path, {"kind": "rbfn-ik", "blob": _Opaque()})
    with pytest.raises(ValueError, match="holds objects other than tensors and plain data") as e:
        read_checkpoint(path)
    msg = str(e.value)
    assert str(path) in msg and "for safety" in msg and "_Opaque" in msg
    assert "weights_only" not in msg
    assert e.value.__cause__ is None and e.value.__suppress_context__  # torch's advice not chained either


def test_training_state_is_not_a_checkpoint(tmp_path):
    StateFile(tmp_path).save(TrainState(config={"seed": 0}))
    for read in (read_checkpoint, load_model):
        with pytest.raises(ValueError, match=r"last.pt is a training state .*not a checkpoint.*checkpoint.pt"):
            read(tmp_path / "last.pt")


@pytest.mark.parametrize(
    "key,value",
    [
        ("head.weight", float("nan")),
        ("centers", float("inf")),
        ("in_low", float("inf")),
        ("cover_radius", float("nan")),
    ],
)
def test_non_finite_weights_are_refused(ckpt, key, value):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["state_dict"][key].view(-1)[0] = value
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"{path.name}: non-finite weights in {key}"):
        load_model(path)


def test_unbounded_domain_loads(ckpt):
    # An RBFNetwork without set_domain has infinite bounds meaning "unbounded": still loadable.
    path, _ = ckpt
    assert torch.isinf(torch.load(path, weights_only=True)["state_dict"]["in_low"]).all()
    assert torch.isinf(load_model(path).in_low).all()


def test_missing_robot(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["robot"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"missing checkpoint keys \['robot'\]"):
        read_checkpoint(path)


def test_incomplete_robot(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["robot"]["joint_low"], raw["robot"]["urdf"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"robot entry is missing keys \['urdf', 'joint_low'\]"):
        read_checkpoint(path)


def test_corrupted_training_state_says_delete_it(tmp_path):
    states = StateFile(tmp_path)
    states.save(TrainState(config={"seed": 0}))
    data = states.path.read_bytes()
    states.path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"not a readable training state .truncated or corrupted") as e:
        StateFile(tmp_path).load({"seed": 0})
    assert f"Delete {states.path}" in str(e.value) and "Re-run training" not in str(e.value)


def test_load_sealed_advice(tmp_path):
    path = tmp_path / "x.pt"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=r"x.pt is not a readable thing .*: it is empty. Do this.$"):
        load_sealed(path, what="thing", advice="Do this.")


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_written_files_get_the_umask_mode(tmp_path, umask):
    old = os.umask(umask)
    try:
        atomic_write_bytes(tmp_path / "a.bin", lambda f: f.write(b"x"))
    finally:
        os.umask(old)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~umask


def test_rewritten_file_keeps_its_mode(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"x")
    path.chmod(0o640)
    atomic_write_bytes(path, lambda f: f.write(b"y"))
    assert path.stat().st_mode & 0o777 == 0o640 and path.read_bytes() == b"y"


@pytest.mark.parametrize(
    "args,match",
    [
        ({"num_centers": 6}, r"centers has shape \(5, 3\), but model_args .* give \(6, 3\)"),
        ({"tail": False}, r"unexpected keys \['tail.weight'\]"),
        ({"out_features": "3"}, r"out_features='3'; expected a positive integer"),
    ],
)
def test_model_args_disagree_with_state_dict(ckpt, args, match):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["model_args"].update(args)
    with pytest.raises(ValueError, match=match):
        model_from_checkpoint(raw)
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"{path.name}: .*" + match):
        read_checkpoint(path)


# --- A checkpoint is data: its robot entry is checked field by field, its URDF never a file name ----


def _crafted(path, model=None, **robot):
    """Write a sealed checkpoint of a SCARA network (3 -> 3) whose robot entry has `robot`'s fields."""
    net = model or RBFNetwork(torch.randn(5, 3, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 3)
    save_checkpoint(path, net, {**ROBOT, **robot}, {}, {})
    return path


@pytest.mark.parametrize("target", ["/etc/hostname", "/dev/zero", "fifo"])
def test_urdf_naming_a_file_is_refused_unread(tmp_path, target):
    # Reading the file named (/etc/hostname: its text; /dev/zero: endless; a FIFO: blocks forever)
    # would be reading something the checkpoint does not hold. Every loader refuses it unopened.
    if target == "fifo":
        target = str(tmp_path / "robot.urdf")
        os.mkfifo(target)
    path = _crafted(tmp_path / "crafted.pt", urdf=target)
    out = run_guarded(f"""
from rbfn.checkpoint import load_sealed, read_checkpoint
from rbfn.robots.robot import robot_from_record
from rbfn.solver import load_solver
P = {str(path)!r}
for load in (read_checkpoint, load_solver, lambda p: robot_from_record(load_sealed(p)["robot"])):
    try:
        load(P)
        print("loaded")
    except ValueError as e:
        print("ValueError:", e)
""")
    lines = out.strip().splitlines()
    assert len(lines) == 3 and "loaded" not in out, out
    refused = (
        rf"robot\.urdf: {re.escape(reprlib.repr(target))} is not URDF text; allowed: XML whose root element is <robot>"
    )
    assert all(re.search(refused, line) for line in lines), out
    assert all(line.startswith(f"ValueError: {path}: ") for line in lines[:2]), out


_BAD_FIELDS = [
    ("urdf", 42, r"robot\.urdf=42 is not allowed; allowed: the URDF's text \(a str of XML"),
    ("urdf", b"<robot/>", r"robot\.urdf=b'<robot/>' is not allowed; allowed: the URDF's text"),
    ("urdf", "<robot name='r'><link name='a'/>", r"robot\.urdf: malformed URDF: .*line 1"),
    (
        "urdf",
        "<rbt><link name='quill'/></rbt>",
        r"robot\.urdf: malformed URDF: the root element is <rbt>; a URDF's is <robot>",
    ),
    (
        "urdf",
        "<robot name='r'><link name='a'/></robot>" + " " * (16 << 20),
        r"robot\.urdf: the URDF has 16777256 bytes or characters or more; allowed: at most MAX_URDF_BYTES = 16777216",
    ),
    ("end_link", 3, r"robot\.end_link=3 is not allowed; allowed: the name of a link of the URDF"),
    ("end_link", "gripper", r"robot\.urdf: end_link 'gripper' is not a link of the URDF; links: \['base', 'link1'"),
    (
        "joint_low",
        [0.0, float("nan"), 0.5],
        (
            r"robot\.joint_low=\[0\.0, nan, 0\.5\] is not allowed; allowed: a list of "
            r"finite numbers \(rad or m\), one per free joint"
        ),
    ),
    ("joint_low", "0 0.3 0.5", r"robot\.joint_low='0 0\.3 0\.5' is not allowed; allowed: a list of finite numbers"),
    (
        "joint_high",
        [2.0, True, 1.5],
        r"robot\.joint_high=\[2\.0, True, 1\.5\] is not allowed; allowed: a list of finite",
    ),
    (
        "joint_high",
        [2.0, 2.0],
        (
            r"robot\.joint_high=\[2\.0, 2\.0\] is not allowed; allowed: as many entries as "
            r"robot\.joint_low \(3\)"
        ),
    ),
    (
        "joint_high",
        [2.0, 0.2, 1.5],
        (
            r"robot\.joint_high=\[2\.0, 0\.2, 1\.5\] is not allowed; allowed: each entry above "
            r"robot\.joint_low's \(\[0\.0, 0\.3, 0\.5\]\)"
        ),
    ),
    (
        "joint_names",
        ["joint1", 2, "joint3"],
        (
            r"robot\.joint_names=\['joint1', 2, 'joint3'\] is not allowed; allowed: a "
            r"list of joint names"
        ),
    ),
    (
        "joint_names",
        ["a", "b", "c"],
        (
            r"robot\.joint_names=\['a', 'b', 'c'\] is not allowed; allowed: the free joints "
            r"of the chain to 'quill', in chain order: \['joint1', 'joint2', 'joint3'\]"
        ),
    ),
    ("target", "orientation", r"robot\.target='orientation' is not allowed; allowed: one of \['position', 'pose'\]"),
    (
        "target",
        "pose",
        (
            r"model_args out_features=3, target='position' do not fit the robot entry; allowed: one output "
            r"per free joint \(3\) and its target 'pose'"
        ),
    ),
    (
        "locked",
        {"joint3": float("inf")},
        (
            r"robot\.locked=\{'joint3': inf\} is not allowed; allowed: a dict from joint "
            r"name \(str\) to a finite held value"
        ),
    ),
    ("locked", ["joint3"], r"robot\.locked=\['joint3'\] is not allowed; allowed: a dict"),
    ("locked", {"elbow": 0.0}, r"robot\.locked names \['elbow'\], which are not joints of the chain to 'quill'"),
    ("name", None, r"robot\.name=None is not allowed; allowed: a label \(str\)"),
]


@pytest.mark.parametrize("key,value,match", _BAD_FIELDS, ids=[f"{k}-{i}" for i, (k, _, _) in enumerate(_BAD_FIELDS)])
def test_bad_robot_field_is_named(tmp_path, key, value, match):
    path = _crafted(tmp_path / "crafted.pt", **{key: value})
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: .*{match}"):
        read_checkpoint(path)


@pytest.mark.parametrize(
    "low,high,match",
    [
        (
            [0.0, 0.3],
            [2.0, 2.0],
            (
                r"robot\.joint_low/joint_high give 2 joints \(\[0\.0, 0\.3\]\); allowed: one per free "
                r"joint of the chain to 'quill', which has 3"
            ),
        ),
        (
            [-9.0, 0.3, 0.5],
            [2.0, 2.0, 1.5],
            r"joint range of joint1 \[-9, 2\] leaves the URDF limits \[-3\.142, 3\.142\]",
        ),
    ],
)
def test_robot_box_must_fit_the_chain(tmp_path, low, high, match):
    path = _crafted(tmp_path / "crafted.pt", joint_low=low, joint_high=high)
    with pytest.raises(ValueError, match=f"{path.name}: robot entry: {match}"):
        read_checkpoint(path)


def test_robot_entry_with_only_the_required_keys_loads(tmp_path):
    path = tmp_path / "crafted.pt"
    _crafted(path)
    raw = torch.load(path, weights_only=True)
    raw["robot"] = {k: ROBOT[k] for k in ("urdf", "end_link", "joint_low", "joint_high")}
    save_sealed(path, raw)
    assert read_checkpoint(path)["robot"]["end_link"] == "quill"


@pytest.mark.parametrize(
    "key,value,match",
    [
        (
            "widths",
            1e-300,
            (
                r"widths has minimum 1e-300; allowed: widths of at least MIN_WIDTH = 1e-12 \(scaled input "
                r"units\), below which a Gaussian is 0 but at its centre"
            ),
        ),
        ("widths", -1.0, r"widths has minimum -1; allowed: widths of at least MIN_WIDTH"),
        ("scale", 0.0, r"scale has minimum 0; allowed: positive input scales"),
        ("cover_radius", -1.0, r"cover_radius is -1; allowed: a radius >= 0 \(inf: unbounded\)"),
    ],
)
def test_useless_model_buffers_are_refused(ckpt, key, value, match):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["state_dict"][key].view(-1)[0] = value
    save_sealed(path, raw)
    with pytest.raises(ValueError, match=f"{path.name}: state_dict {match}"):
        read_checkpoint(path)


def test_min_width_is_where_gaussians_vanish():
    # At MIN_WIDTH a Gaussian is already 0 in float64 a few 1e-11 from its centre; training's
    # smallest width (1e-9 times the scale 0.25) is far above it.
    from rbfn.layer import gaussian_features
    from rbfn.widths import SCALE_GRID

    z = torch.tensor([[0.0, 0.0, 0.0], [4e-11, 0.0, 0.0]], dtype=torch.float64)
    phi = gaussian_features(z, torch.zeros(1, 3, dtype=torch.float64), torch.full((1,), MIN_WIDTH, dtype=torch.float64))
    assert phi[:, 0].tolist() == [1.0, 0.0]
    assert 1e-9 * min(SCALE_GRID) > 100 * MIN_WIDTH


def test_network_outputs_must_match_the_robot(tmp_path):
    net = RBFNetwork(torch.randn(5, 3, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 2)
    path = _crafted(tmp_path / "crafted.pt", model=net)
    with pytest.raises(
        ValueError,
        match=r"model_args out_features=2, target='position' do not fit the robot entry; "
        r"allowed: one output per free joint \(3\)",
    ):
        read_checkpoint(path)


def test_a_file_too_large_to_be_a_checkpoint_is_refused_before_it_is_read(tmp_path):
    from rbfn.checkpoint import load_sealed

    big = tmp_path / "big.pt"
    with open(big, "wb") as f:  # sparse: no disk used
        f.truncate(3 << 30)
    with pytest.raises(ValueError, match=r"big.pt holds 3 GiB; a checkpoint aco-rbfn writes is at most 2 GiB"):
        load_sealed(big)


# --- Sizes a file declares are checked before anything is allocated for them -------------------------


def _expanded(path, rows: int = 2_000_000_000):
    """The sealed checkpoint at `path` rewritten (about 10 KB) with stride-0 views declaring `rows`
    centres: 48 GB once anything copies them. Its shapes and model_args agree; only the data betrays it."""
    raw = torch.load(path, weights_only=True)
    for k, shape in {"centers": (rows, 3), "widths": (rows,), "head.weight": (3, rows)}.items():
        raw["state_dict"][k] = torch.ones((1,) * len(shape), dtype=torch.float64).expand(*shape)
    raw["model_args"]["num_centers"] = rows
    _resave(raw, path)
    return path


def test_declared_sizes_beyond_the_file_are_refused_before_allocation(ckpt):
    # Each loader used to copy the 2e9 x 3 view (48 GB): an allocator error or the OOM killer.
    path = _expanded(ckpt[0])
    assert path.stat().st_size < 20_000
    out = run_guarded(f"""
import torch
from rbfn import load_model, load_solver
from rbfn.checkpoint import read_checkpoint
for load in (read_checkpoint, load_model, load_solver):
    try:
        load({str(path)!r})
        print("loaded")
    except ValueError as e:
        print("ValueError:", e)
""")
    lines = out.strip().splitlines()
    assert len(lines) == 3, out
    assert all(
        line.startswith(
            f"ValueError: {path}: state_dict centers declares shape (2000000000, 3) (6,000,000,000 values, "
            "48,000,000,000 bytes), but the file holds 1 value for it (an expanded or overlapping tensor)"
        )
        for line in lines
    ), out


def test_an_expanded_tensor_anywhere_in_a_sealed_file_is_refused(tmp_path):
    path = tmp_path / "state.pt"
    save_sealed(path, {"colony": {"archive": [torch.zeros(1).expand(10**9)]}})
    with pytest.raises(ValueError, match=r"colony archive 0 declares shape \(1000000000,\) .* holds 1 value for it"):
        load_sealed(path, what="training state")


def test_a_compressed_record_is_refused_before_it_inflates(ckpt):
    """torch.load inflates a deflated record (up to ~1000x) before anything could check it; torch.save
    stores every record, so a sealed file with a compressed one was crafted."""
    import io
    import zipfile

    from rbfn.checkpoint import unseal

    path = ckpt[0]
    archive = zipfile.ZipFile(io.BytesIO(unseal(path.read_bytes(), path)))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for name in archive.namelist():
            z.writestr(name, archive.read(name))
    path.write_bytes(seal(out.getvalue()))
    with pytest.raises(
        ValueError, match=rf"^{path}: its record archive/data.pkl is compressed \(\d+ B inflating to \d+ B\)"
    ):
        load_model(path)


def test_a_pickle_larger_than_a_checkpoints_is_refused_before_unpickling(ckpt, monkeypatch):
    """Unpickling makes up to some 70 bytes of objects of each byte (an empty list of one opcode):
    data.pkl, which holds no tensor, is bounded before it is unpickled."""
    import rbfn.checkpoint

    monkeypatch.setattr(rbfn.checkpoint, "MAX_PICKLE_BYTES", 1000)
    with pytest.raises(
        ValueError, match=rf"^{ckpt[0]}: its pickled part archive/data.pkl holds \d+ B; .* MAX_PICKLE_BYTES = 1000 B"
    ):
        load_model(ckpt[0])


def test_a_network_too_large_for_memory_is_refused_naming_its_size(ckpt, monkeypatch):
    import rbfn.memory

    monkeypatch.setattr(rbfn.memory, "available_bytes", lambda device="cpu": 100)
    with pytest.raises(
        ValueError,
        match=rf"^{ckpt[0]}: model_args num_centers=5 needs at least \d+ B \(the network's weights in float64\), "
        r"more than this machine's available memory \(100 B\); load it on a machine with more free memory",
    ):
        load_model(ckpt[0])


# --- What is given as a checkpoint: said before it is read ---------------------------------------------


def test_a_url_is_refused_not_folded_into_a_file_name():
    for load in (load_model, read_checkpoint, load_sealed):
        with pytest.raises(ValueError, match=r"^https://example\.com/run/checkpoint\.pt is a URL; aco-rbfn reads"):
            load("https://example.com/run/checkpoint.pt")


def test_what_is_not_a_checkpoint_file_is_named(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "link").symlink_to(tmp_path / "gone.pt")
    cases = {
        tmp_path: "a directory",
        tmp_path / "fifo": r"a FIFO \(named pipe\)",  # never opened: it would block
        "/dev/null": "a character device",
        tmp_path / "link": rf"a dangling symbolic link \(to {tmp_path / 'gone.pt'}\)",
    }
    for path, kind in cases.items():
        with pytest.raises(ValueError, match=rf"^{path} is {kind}, not a checkpoint: a checkpoint is a regular file"):
            load_model(path)
    with pytest.raises(ValueError, match=r"an empty path names no checkpoint"):
        load_model("")
    with pytest.raises(FileNotFoundError, match=r"no checkpoint at ~/nowhere.pt \(~ is not expanded: give the full"):
        load_model("~/nowhere.pt")
    with pytest.raises(TypeError, match=r"checkpoint path 42 is of type int; expected a file path"):
        load_model(42)


def test_exports_given_as_a_checkpoint_say_what_they_are(tmp_path):
    import io
    import zipfile

    from onnx import helper

    graph = helper.make_graph([], "g", [], [])
    (tmp_path / "ik.onnx").write_bytes(helper.make_model(graph).SerializeToString())
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:  # what torch.export.save writes, in short
        z.writestr("archive/archive_format", "pt2")
        z.writestr("archive/models/model.json", "{}")
    (tmp_path / "ik.pt2").write_bytes(out.getvalue())
    for name, kind in (("ik.onnx", "an ONNX model"), ("ik.pt2", "a torch.export program")):
        with pytest.raises(
            ValueError, match=rf"^{tmp_path / name} is {kind} \(an export such as {name}\), not a checkpoint"
        ):
            load_model(tmp_path / name)
