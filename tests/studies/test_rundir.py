"""Run-directory files: figures written whole, once rendered for both the file and TensorBoard."""

from matplotlib.figure import Figure
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from torch.utils.tensorboard import SummaryWriter

from rbfn.studies.rundir import write_figure


def test_write_figure_writes_the_png_and_the_same_image_to_tensorboard(tmp_path):
    fig = Figure(figsize=(2, 1))
    fig.subplots().plot([0, 1], [1, 0])
    with SummaryWriter(str(tmp_path / "tb")) as writer:
        write_figure(fig, tmp_path / "f.png", 50, writer, "fig/line")
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "tb"]  # no temporary left
    events = EventAccumulator(str(tmp_path / "tb"), size_guidance={"images": 0}).Reload()
    (image,) = events.Images("fig/line")
    assert (image.width, image.height) == (100, 50)  # 2 x 1 in at 50 dpi
    assert image.encoded_image_string == (tmp_path / "f.png").read_bytes()  # the same PNG
