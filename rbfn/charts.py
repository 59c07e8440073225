"""IK over the whole joint range: joint space cut into charts, one network a chart.

One network answers one branch of the IK inside a box (`RBFNetwork`). Over the whole URDF range
the IK has several branches (up to 8 on a 6R arm with a spherical wrist, measured: 23 of 64 charts
lead to a solution of a UR5 pose after the polish) and revolute joints wrap around. So:

1. charts: the joints' embedding (cos q, sin q for a revolute joint, q scaled to [-1, 1] for a
   prismatic one; the redundant joint, an input, left out) is clustered by k-means into K charts;
2. each chart's network learns the poses of the samples within `OVERLAP` times their nearest
   chart's distance, its revolute joints' answers as (cos q, sin q) (no wrap to learn), its
   centres chosen as configured (`rbfn.select`: ACO, k-means, ...);
3. every chart answers a target (`ChartedIK.answers`: joints (B, K, n) and each chart's
   closeness, its nearest centre's distance in cover radii), or one chart a target
   (`chart_answers`), the charts ranked by a cheaper closeness (`ranked`: to a summary of 32
   centres a chart); the solver polishes them in that order until one converges
   (`rbfn.solver.IKSolver`).

Measured on the UR5 (2 000 poses over the whole range, 64 charts of 300 k-means centres, 5 steps
polished): polishing every chart's answer solves 99.9 %; the best answer by forward kinematics
alone 80.5 % (90.1 % in 10 steps): the raw answers are far (median 700 tolerances: 0.1 mm + 0.1
deg each), and where they are far the nearest is not the one that converges. Joints learned as
(cos, sin) instead of unwrapped angles: the raw median 700 -> 490 tolerances, the staged polish
98.55 -> 99.25 %. Ranking the 16 charts whose centres lie nearest (cover) by forward kinematics
solves as many as ranking all 64, for a quarter of the forward kinematics.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .centers import kmeans_centers
from .checkpoint import CHARTS_KIND, FORMAT_VERSION, model_from_checkpoint, network_record, save_sealed
from .config import RefineLoss, TrainConfig
from .data import Dataset, Split, full_limits, make_split, stream
from .layer import RBFNetwork, row_blocks
from .progress import Progress
from .robots.robot import Robot

__all__ = [
    "CHARTS_KIND",
    "Charted",
    "ChartedIK",
    "charts_from_checkpoint",
    "embed",
    "chart_config",
    "revolute_joints",
    "save_charts",
    "train_charts",
]

log = logging.getLogger(__name__)

OVERLAP = 1.15  # a sample trains every chart within this factor of its nearest chart's distance
CHART_STREAM = 901  # the random stream of the charts' training joints (rbfn.data.stream)
BLOCK_ELEMENTS = 1 << 20  # (charts, rows, centres) Gaussians a block of `ChartedIK.answers` (8 MB in float64)
FAR_CENTRE = 1e3  # where padding centres sit (scaled units: no input comes near)
GATE_CENTRES = 32  # a chart's centres summarised by this many for `ChartedIK.ranked` (measured below)
RANK_ROWS = 512  # rows a product of `ChartedIK.ranked` (its distances (rows, K G) stay in cache)
GATE_LLOYD = 10  # Lloyd iterations of that summary (from farthest-point seeds)
# `ChartedIK._stacked`'s parts, in its order (a frozen copy's buffers are stacked_<name>).
_STACKED = ("offsets", "scales", "centres", "widths", "heads", "biases", "tails", "covers")


def revolute_joints(robot: Robot) -> torch.Tensor:
    """(n,) bool: True for the free joints that turn (revolute or continuous), False for prismatic."""
    types = [j.joint_type for j in robot.chain.get_joints()]
    return torch.tensor([types[i] != "prismatic" for i in robot.free])


def _sample_range(robot: Robot) -> tuple[torch.Tensor, torch.Tensor]:
    """Where training joints are drawn: the URDF limits, a revolute joint with more than a turn
    of range cut to one turn inside them (its other turns reach the same poses)."""
    low, high = full_limits(robot)
    turn = revolute_joints(robot) & (high - low > 2 * math.pi)
    mid = 0.5 * (low + high)
    low = torch.where(turn, (mid - math.pi).clamp(min=low), low)
    high = torch.where(turn, low + 2 * math.pi, high)
    return low, high


def embed(q: torch.Tensor, revolute: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """The charts' embedding (N, e) of joints q (N, n): (cos q, sin q) of the revolute joints, then
    the prismatic joints scaled from [low, high] to [-1, 1]."""
    r, p = revolute.to(q.device), ~revolute.to(q.device)
    lo, hi = low.to(q), high.to(q)
    return torch.cat([q[:, r].cos(), q[:, r].sin(), (2 * (q[:, p] - lo[p]) / (hi[p] - lo[p]) - 1)], -1)


def encode(q: torch.Tensor, revolute: torch.Tensor) -> torch.Tensor:
    """A chart network's outputs (N, 2 r + p) for joints q (N, n): cos, sin of the r revolute
    joints, then the p prismatic joints."""
    r = revolute.to(q.device)
    return torch.cat([q[:, r].cos(), q[:, r].sin(), q[:, ~r]], -1)


def decode(y: torch.Tensor, revolute, middle=None) -> torch.Tensor:
    """Joints (..., n) from a chart network's outputs (..., 2 r + p) (`encode`'s inverse). A revolute
    joint's angle lies within half a turn of its `middle` (n,) (rad; a list of floats or a tensor,
    the prismatic joints' entries unused; None: 0, angles in (-pi, pi]): the middle of its range,
    so that a range reaching past +-pi (the KUKA KR10's second joint, -190 .. 45 deg; the Panda's
    sixth, -1 .. 215 deg) decodes onto itself, not onto the other end of the turn. `revolute`: (n,)
    bool, a tensor or a list (a list keeps it traceable: no data-dependent indexing, so the
    exporters can take it)."""
    flags = [bool(t) for t in revolute]
    turns = [i for i, t in enumerate(flags) if t]
    slides = [i for i, t in enumerate(flags) if not t]
    k = len(turns)
    cos, sin = y[..., :k], y[..., k : 2 * k]
    angle = torch.atan2(sin, cos)
    if middle is not None:  # (cos, sin) turned back by the middle, the angle then from the middle
        m = torch.as_tensor([float(middle[i]) for i in turns], dtype=y.dtype, device=y.device)
        cm, sm = m.cos(), m.sin()
        angle = torch.atan2(sin * cm - cos * sm, cos * cm + sin * sm) + m
    q = torch.cat([angle, y[..., 2 * k :]], -1)  # turns first, then slides
    order = sorted(range(len(flags)), key=(turns + slides).index)
    return q if order == list(range(len(flags))) else q[..., order]


class ChartedIK(nn.Module):
    """K chart networks answering every target: `answers(x)` -> joints (B, K, n) and closeness
    (B, K); `forward(x)`, the joints alone. Inputs as the chart networks' (poses (B, 7), or (B, 8)
    with a redundant joint's value). `centres` (K, e): the charts' centres in `embed`'s space;
    `revolute` (n,) bool; low, high (n,): the joints' range (URDF limits)."""

    revolute: torch.Tensor
    centres: torch.Tensor
    low: torch.Tensor
    high: torch.Tensor

    def __init__(
        self,
        nets: list[RBFNetwork],
        centres: torch.Tensor,
        revolute: torch.Tensor,
        low: torch.Tensor,
        high: torch.Tensor,
    ) -> None:
        super().__init__()
        if not nets:
            raise ValueError("a ChartedIK needs at least one chart network")
        self.nets = nn.ModuleList(nets)
        self.register_buffer("centres", centres.clone())
        self.register_buffer("revolute", revolute.clone().bool())
        self.register_buffer("low", low.clone().to(centres.dtype))
        self.register_buffer("high", high.clone().to(centres.dtype))
        self.turns = [bool(t) for t in revolute]  # `revolute` as a list: decoded without data-dependent indexing
        # each joint's middle (rad, or m): a revolute joint's answer decoded within half a turn of it
        self.middles = [0.5 * (float(a) + float(b)) for a, b in zip(low.tolist(), high.tolist())]
        self.frozen_dtype: torch.dtype | None = None  # set by `frozen`: the dtype of its stacked parameters
        self.gate: torch.Tensor | None = None  # set by `frozen`: `_gate_matrix`, in its dtype

    @property
    def num_charts(self) -> int:
        return len(self.nets)

    @property
    def out_features(self) -> int:
        return int(self.revolute.shape[0])

    @property
    def first(self) -> RBFNetwork:
        """The first chart's network (what the charts share: inputs, target kind)."""
        return self.nets[0]  # type: ignore[return-value]

    def check_inputs(self, x) -> torch.Tensor:
        return self.first.check_inputs(x)

    def answers(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(joints (B, K, n) within `low`..`high`, closeness (B, K): each chart's nearest centre's
        distance over its cover radius, below 1 inside the region the chart was trained on) for
        inputs x (B, d). Every chart at once: the networks' equation y = W h + A z + b batched over
        the charts (charts with fewer centres padded by centres no input comes near)."""
        first = self.first
        f = first._feat(first._inputs(x))  # (B, d): the charts share their input features
        p = self._stacked(f.dtype)
        return row_blocks(lambda fb: self._answer_rows(fb, p), self.rows_per_block, f)

    @property
    def rows_per_block(self) -> int:
        """Rows a block in `answers` and in the ONNX graph: about `BLOCK_ELEMENTS` Gaussians (rows, K, M)."""
        nets: list[RBFNetwork] = list(self.nets)  # type: ignore[arg-type]
        return max(1, BLOCK_ELEMENTS // (self.num_charts * max(net.num_centers for net in nets)))

    def answer_rows(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`answers` for inputs x (B, d) in one piece (no blocks: one graph for any B), the exporters'
        path (`rbfn.export`); on a `frozen` copy."""
        f = self.first._feat(self.first._inputs(x))
        return self._answer_rows(f, self._stacked(f.dtype))

    def frozen(self, dtype: torch.dtype = torch.float32) -> ChartedIK:
        """A copy in `dtype`, eval mode, without gradients, its charts' parameters stacked once
        (`_stacked`, kept as buffers named stacked_*) instead of on every call: the solver's and the
        exporters' form."""
        model = copy.deepcopy(self).to(dtype).eval().requires_grad_(False)
        for name, t in zip(_STACKED, model._stacked(dtype)):
            model.register_buffer(f"stacked_{name}", t)
        model.frozen_dtype = dtype
        model.gate = model._gate_matrix().to(dtype)
        return model

    def _gate_centres(self) -> torch.Tensor:
        """(K, G, d): each chart's centres summarised by G = `GATE_CENTRES` (k-means of them, in its
        scaled input units; a chart of fewer centres keeps its own, the rest padded far)."""
        nets: list[RBFNetwork] = list(self.nets)  # type: ignore[arg-type]
        g = min(GATE_CENTRES, max(net.num_centers for net in nets))
        out = []
        for net in nets:
            c = net.centers.detach()
            s = summarise(c, g) if c.shape[0] > g else c
            out.append(torch.cat([s, s.new_full((g - s.shape[0], s.shape[1]), FAR_CENTRE)]))
        return torch.stack(out)

    def ranked(self, x: torch.Tensor, t: int) -> torch.Tensor:
        """(B, t) the indices of the t charts nearest inputs x (B, d), nearest first: each chart's
        distance to the input, over its cover radius, measured to `_gate_centres`' summary of its
        centres instead of to every centre (a tenth of the work of `answers`' closeness, in one
        matrix product). Measured on 4 000 whole-range poses (test stream of seed 1, 64 charts of
        300 centres, 5 steps): the first chart in this order polishes to a solution for 73.4 % of
        UR5 poses and 66.3 % of Panda poses (by every centre: 75.4 % and 71.8 %); the charts tried
        until one converges, 1.55 and 2.15 a pose (1.51 and 1.93). A `frozen` copy's."""
        if self.gate is None:
            raise RuntimeError("ChartedIK.ranked runs on a frozen copy (ChartedIK.frozen)")
        gate = self.gate
        f = self.first._feat(self.first._inputs(x)).to(gate.dtype)
        k = self.num_charts
        a = torch.cat([f.square(), f, torch.ones_like(f[:, :1])], -1)
        # The (B, K G) distances in pieces of RANK_ROWS rows into one buffer: at once, or each piece
        # allocated afresh, they cost 3-4x the time (page faults of 4-33 MB a call; UR5, 4 096 rows: 7 ms
        # against 23-29 ms)
        d2 = a.new_empty(min(RANK_ROWS, a.shape[0]), gate.shape[1])
        near = a.new_empty(a.shape[0], k)
        for i in range(0, a.shape[0], RANK_ROWS):
            piece = torch.mm(a[i : i + RANK_ROWS], gate, out=d2[: min(RANK_ROWS, a.shape[0] - i)])
            torch.amin(piece.view(piece.shape[0], k, -1), -1, out=near[i : i + piece.shape[0]])
        return near.topk(min(t, k), dim=1, largest=False).indices

    def _gate_matrix(self) -> torch.Tensor:
        """(2 d + 1, K G): the squared distances of inputs' features f (B, d) to every chart's
        `_gate_centres`, over the square of its cover radius, as one product [f^2, f, 1] @ this
        (each chart scales f its own way: |(f - o) / s - g|^2 = sum f^2 / s^2 - 2 f (o / s + g) / s +
        (o / s + g)^2)."""
        p = self._stacked(torch.float64)
        off, sc, cover = p[0], p[1], p[7]  # (K, d), (K, d), (K,)
        g = self._gate_centres().to(torch.float64)  # (K, G, d)
        u = (off / sc)[:, None] + g  # (K, G, d)
        inv = (1.0 / sc)[:, None].expand_as(u)  # (K, G, d)
        c2 = cover.square()[:, None, None]
        rows = [inv.square() / c2, -2.0 * u * inv / c2, (u.square().sum(-1, keepdim=True)) / c2]
        return torch.cat(rows, -1).reshape(-1, 2 * g.shape[-1] + 1).T.contiguous()

    def chart_answers(self, x: torch.Tensor, charts: torch.Tensor) -> torch.Tensor:
        """Joints (B, n) within `low`..`high`: for each input x[i] (B, d), chart charts[i]'s answer.
        One batched evaluation: the rows grouped by chart in pieces of at most the mean count per
        chart, each padded to that (a loop over the charts costs a few dozen small operations a
        chart). A `frozen` copy's."""
        f = self.first._feat(self.first._inputs(x))
        b = f.shape[0]
        if not b:
            return f.new_empty(0, self.out_features)
        present, group, counts = charts.unique(return_inverse=True, return_counts=True)
        order = group.argsort(stable=True)
        g = group[order]
        at = torch.arange(b, device=f.device) - (counts.cumsum(0) - counts)[g]  # place in its chart's rows
        # each chart's rows in pieces of the mean count, so that one crowded chart pads no others
        width = -(-b // present.shape[0])
        pieces = -(-counts // width)
        piece = (pieces.cumsum(0) - pieces)[g] + at // width
        grouped = f.new_zeros(int(pieces.sum()), width, f.shape[1])
        grouped[piece, at % width] = f[order]
        p = tuple(None if t is None else t[present.repeat_interleave(pieces)] for t in self._stacked(f.dtype))
        q = self._answer_rows(grouped, p)[0]  # (width, pieces, n)
        out = q.new_empty(b, q.shape[-1])
        out[order] = q[at % width, piece]
        return out

    def _answer_rows(self, f: torch.Tensor, p: tuple) -> tuple[torch.Tensor, torch.Tensor]:
        """`answers` for input features f (B, d) in one piece, from `_stacked`'s parameters p (each
        chart's on its own rows where f is (K, B, d))."""
        off, sc, mu, w, head, bias, tail, cover = p
        z = ((f if f.dim() == 3 else f[None]) - off[:, None]) / sc[:, None]  # (K, B, d)
        # |z - mu|^2 = |z|^2 + |mu|^2 - 2 z.mu, in place: (K, B, M) is the one large temporary
        d2 = torch.baddbmm(mu.square().sum(-1)[:, None], z, mu.transpose(1, 2), alpha=-2.0)
        d2.add_(z.square().sum(-1, keepdim=True)).clamp_(min=0.0)
        close = (d2.amin(-1).sqrt() / cover[:, None]).T  # (B, K)
        h = d2.div_(w.square()[:, None] * -2.0).exp_()
        y = torch.baddbmm(bias[:, None], h, head.transpose(1, 2))
        if tail is not None:
            y = y.baddbmm_(z, tail.transpose(1, 2))
        q = decode(y, self.turns, self.middles).transpose(0, 1)  # (B, K, n)
        return torch.maximum(torch.minimum(q, self.high.to(q)), self.low.to(q)), close

    def _stacked(self, dtype: torch.dtype):
        """The charts' parameters stacked (K, ...) in `dtype`: offsets, scales (K, d), centres
        (K, M, d), widths (K, M), head weights (K, out, M), biases (K, out), tail weights (K, out,
        d) or None, cover radii (K,); a `frozen` copy's own, in its dtype."""
        if dtype == self.frozen_dtype:
            return tuple(getattr(self, f"stacked_{name}") for name in _STACKED)
        nets: list[RBFNetwork] = list(self.nets)  # type: ignore[arg-type]
        m = max(net.num_centers for net in nets)

        def pad(t: torch.Tensor, value: float, dim: int) -> torch.Tensor:
            extra = m - t.shape[dim]
            if not extra:
                return t
            shape = list(t.shape)
            shape[dim] = extra
            return torch.cat([t, t.new_full(shape, value)], dim)

        def cat(ts) -> torch.Tensor:
            return torch.stack([t.to(dtype) for t in ts])

        tails = [net.tail for net in nets]
        return (
            cat(net.offset for net in nets),
            cat(net.scale for net in nets),
            cat(pad(net.centers, FAR_CENTRE, 0) for net in nets),
            cat(pad(net.widths, 1.0, 0) for net in nets),
            cat(pad(net.head.weight, 0.0, 1) for net in nets),
            cat(net.head.bias for net in nets),
            None if any(t is None for t in tails) else cat(t.weight for t in tails),  # type: ignore[union-attr]
            cat(net.cover_radius for net in nets),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.answers(x)[0]


def summarise(points: torch.Tensor, g: int) -> torch.Tensor:
    """g centres (g, d) of points (N, d), N > g: farthest-point seeds (the first nearest the mean)
    refined by `GATE_LLOYD` Lloyd iterations (k-means). Written here rather than scikit-learn's
    KMeans: it summarises the 64 charts of a UR5 network in about 20 ms, where KMeans takes about
    1 s, paid on every solver's load."""
    d = (points - points.mean(0)).norm(dim=1)
    idx = [int(d.argmin())]
    d = (points - points[idx[0]]).norm(dim=1)
    for _ in range(g - 1):
        idx.append(int(d.argmax()))
        d = torch.minimum(d, (points - points[idx[-1]]).norm(dim=1))
    c = points[idx].clone()
    for _ in range(GATE_LLOYD):
        near = torch.cdist(points, c).argmin(1)
        sums = torch.zeros_like(c).index_add_(0, near, points)
        n = torch.bincount(near, minlength=g).to(points.dtype)
        c = torch.where(n[:, None] > 0, sums / n.clamp(min=1)[:, None], c)
    return c


def chart_config(cfg: TrainConfig) -> TrainConfig:
    """The train config each chart's network is fitted with: `cfg` with `robot.chart_centers`
    centres, no growth, no refinement unless `robot.chart_refine`, and the refinement's mini-batch
    loss on the outputs (`joint`) where `cfg` asks for the task loss (its Jacobian maps joints; the
    charts learn their cosines and sines); what differs from `cfg` is logged."""
    r = cfg.rbfn
    refine = cfg.centers.refine
    if refine.enabled and not cfg.robot.chart_refine:
        log.info("centers.refine.enabled = false for the charts (robot.chart_refine=true refines each)")
        refine = replace(refine, enabled=False)
    if refine.enabled and refine.minibatch.loss == RefineLoss.task:
        log.info(
            "centers.refine.minibatch.loss = joint for the charts (robot.workspace=full: they learn cos q and sin q, "
            "which the task loss's Jacobian does not map)"
        )
        refine = replace(refine, minibatch=replace(refine.minibatch, loss=RefineLoss.joint))
    rbfn = replace(r, num_centers=cfg.robot.chart_centers, growth=replace(r.growth, start=0))
    return replace(cfg, rbfn=rbfn, centers=replace(cfg.centers, refine=refine))


@dataclass
class Charted:
    """`train_charts`' result: the model, the seconds a chart's network took to train, and the
    mean of the charts' validation E (half the mean squared error of their outputs, cos q and sin q
    of a revolute joint)."""

    model: ChartedIK
    seconds_a_chart: float
    val_E: float


def train_charts(cfg: TrainConfig, robot: Robot, progress: Progress | None = None) -> Charted:
    """A `ChartedIK` for `robot` of `cfg.robot.charts` networks, each trained by
    `rbfn.pipeline.train_ik` with `cfg`'s centres, widths, weights and refinement but
    `cfg.robot.chart_centers` centres and no growth, on the samples of its chart: charts x
    `cfg.robot.chart_samples` joints drawn uniformly within the URDF limits (`_sample_range`, stream
    `CHART_STREAM` of `cfg.seed`), their poses from forward kinematics. `progress` follows the charts."""
    from .pipeline import train_ik

    r = cfg.robot
    charts, samples, seed = r.charts, r.chart_samples, cfg.seed
    r.check("robot")
    chart_cfg = chart_config(cfg)
    revolute = revolute_joints(robot)
    low, high = _sample_range(robot)
    n = low.shape[0]
    split = make_split(robot, charts * samples, stream(seed, CHART_STREAM), low, high)
    q, x = split.q.cpu(), split.x.cpu()
    keep = torch.ones(n, dtype=torch.bool)
    if robot.redundant is not None:
        keep[robot.redundant] = False
    e = embed(q[:, keep], revolute[keep], low[keep], high[keep])
    centres = kmeans_centers(e[:50000], charts, seed=seed, restarts=3) if charts > 1 else e.mean(0, keepdim=True)
    dist = torch.cdist(e, centres)
    nearest = dist.amin(1)
    nets, errors = [], []
    t0 = time.perf_counter()
    for k in range(charts):
        mine = (dist[:, k] <= OVERLAP * nearest).nonzero().squeeze(-1)
        yk, xk = encode(q[mine], revolute), x[mine]
        v = max(1, yk.shape[0] // 6)
        data = Dataset(Split(xk[v:], yk[v:]), Split(xk[:v], yk[:v]), Split(xk[:v], yk[:v]))
        result = train_ik(chart_cfg, data, robot=robot)
        nets.append(result.model)
        errors.append(0.5 * float(result.fit.val_mse))
        log.info("chart %d/%d: %d samples, validation E = %.3g", k + 1, charts, yk.shape[0], errors[-1])
        if progress is not None:
            progress.at("charts", k + 1, charts, "charts")
    model = ChartedIK(nets, centres, revolute, *full_limits(robot))
    return Charted(model, (time.perf_counter() - t0) / charts, sum(errors) / charts)


def save_charts(
    path: str | Path, model: ChartedIK, robot: dict[str, Any], config: dict[str, Any], metrics: dict[str, Any]
) -> None:
    """Write `model` to `path` as a sealed checkpoint of kind `CHARTS_KIND` (plain data and tensors,
    atomically): format_version, kind, package_version, charts (centres, revolute, low, high),
    networks (one `rbfn.checkpoint.network_record` a chart), robot (`Robot.record`), config, metrics."""
    from . import __version__

    save_sealed(
        path,
        {
            "format_version": FORMAT_VERSION,
            "kind": CHARTS_KIND,
            "package_version": __version__,
            "charts": {k: getattr(model, k).detach().cpu() for k in ("centres", "revolute", "low", "high")},
            "networks": [network_record(net) for net in model.nets],  # type: ignore[arg-type]
            "robot": robot,
            "config": config,
            "metrics": metrics,
        },
    )


def charts_from_checkpoint(ckpt: dict[str, Any]) -> ChartedIK:
    """The `ChartedIK` of a charted checkpoint dict (`rbfn.checkpoint.read_checkpoint`), in eval mode."""
    c = ckpt["charts"]
    nets = [model_from_checkpoint(rec) for rec in ckpt["networks"]]
    return ChartedIK(nets, c["centres"], c["revolute"], c["low"], c["high"]).eval().requires_grad_(False)
