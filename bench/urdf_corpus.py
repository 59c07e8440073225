"""How many real arms train with the plain command: every single-arm URDF under a folder, through
`python train.py robot=urdf robot.urdf=FILE robot.end_link=LINK` and nothing else but the sizes.

    python -m bench.urdf_corpus FOLDER [--limit N] [--timeout 600] [--out corpus.jsonl]

A URDF counts as a single arm where its kinematic tree has one trunk: from the root, each link
has at most one child subtree that holds a moving joint, until the first link with two or more
(a gripper's fingers) or none; the end link is that link, and the trunk holds 3 to 7 moving
joints. Humanoids, legged robots, two-armed robots and wheeled bases (several subtrees with
moving joints at the root, or fewer than 3 moving joints on the trunk) are skipped and counted
as such. Each arm trains at a small size (`rbfn.num_centers`, the data sizes, the charts of
`robot.workspace=full`, robot=urdf's default, and `centers=kmeans` below, so that a corpus of a
hundred arms fits an hour on 2 cores); a run's outcome is `trained` or the first line of the error
that stopped it. One JSON line per URDF goes to `--out`, and a table of outcomes by reason to
stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from lxml import etree

__all__ = ["trunk", "main"]

MOVING = ("revolute", "continuous", "prismatic")
SMALL = [
    "centers=kmeans",
    "rbfn.num_centers=64",
    "data.n_train=2000",
    "data.n_val=500",
    "data.n_test=500",
    "rbfn.growth.start=0",
    "robot.charts=8",
    "robot.chart_centers=64",
    "robot.chart_samples=500",
    "progress=false",
    "export=false",
]


def trunk(path: Path) -> tuple[str | None, int, str]:
    """(the trunk's end link or None, its moving joints, why it is no single arm ('' when it is))
    of the URDF at `path`."""
    try:
        root = etree.parse(str(path), etree.XMLParser(resolve_entities=False, no_network=True)).getroot()
    except (etree.XMLSyntaxError, OSError) as e:
        return None, 0, f"unreadable: {e}"
    children: dict[str, list[tuple[str, str]]] = {}
    parents = set()
    for j in root.iter("joint"):
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            continue
        children.setdefault(p.get("link"), []).append((c.get("link"), j.get("type", "")))
        parents.add(c.get("link"))
    links = [lk.get("name") for lk in root.iter("link")]
    roots = [lk for lk in links if lk not in parents]
    if len(roots) != 1:
        return None, 0, f"{len(roots)} root links"

    def moving_below(link: str) -> int:
        return sum((t in MOVING) + moving_below(c) for c, t in children.get(link, []))

    link, count = roots[0], 0
    while True:
        subtrees = [(c, t) for c, t in children.get(link, []) if t in MOVING or moving_below(c) > 0]
        if len(subtrees) != 1:
            break
        c, t = subtrees[0]
        count += t in MOVING
        link = c
        if moving_below(link) == 0:
            break
    if count < 3:
        return None, count, "no arm: fewer than 3 moving joints on one trunk (a base, a hand, a humanoid)"
    if count > 7:
        return None, count, f"no single arm: {count} moving joints on one trunk"
    return link, count, ""


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--limit", type=int, default=0, help="at most this many single arms (0: all)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds a training run may take")
    p.add_argument("--out", type=Path, default=Path("corpus.jsonl"))
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    files = sorted(args.folder.rglob("*.urdf"))
    arms, outcomes = 0, Counter()
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), MKL_NUM_THREADS=str(args.threads))
    train = Path(__file__).resolve().parent.parent / "train.py"
    with args.out.open("w") as out, tempfile.TemporaryDirectory() as tmp:
        for f in files:
            end, joints, why = trunk(f)
            row = {"urdf": str(f.relative_to(args.folder)), "end_link": end, "joints": joints}
            if end is None:
                row["outcome"] = "skipped: " + why
                outcomes["skipped"] += 1
                out.write(json.dumps(row) + "\n")
                continue
            if args.limit and arms >= args.limit:
                break
            arms += 1
            cmd = [
                sys.executable,
                str(train),
                "robot=urdf",
                f"robot.urdf={f.resolve()}",
                f"robot.end_link={end}",
                *SMALL,
                f"hydra.run.dir={tmp}/{arms}",
            ]
            t0 = time.perf_counter()
            try:
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, env=env)
                ok = r.returncode == 0
                lines = [ln for ln in (r.stderr + r.stdout).splitlines() if ln.strip()]
                err = next((ln for ln in reversed(lines) if "Error" in ln or "error" in ln), lines[-1] if lines else "")
            except subprocess.TimeoutExpired:
                ok, err = False, f"timed out after {args.timeout:g} s"
            row["seconds"] = round(time.perf_counter() - t0, 1)
            row["outcome"] = "trained" if ok else err[:300]
            outcomes["trained" if ok else "failed"] += 1
            out.write(json.dumps(row) + "\n")
            out.flush()
            print(f"{row['urdf']}: {joints} joints to {end}: {row['outcome'][:160]} ({row['seconds']} s)", flush=True)
    print(
        f"{arms} single arms: {outcomes['trained']} trained ({outcomes['trained'] / max(arms, 1):.0%}), "
        f"{outcomes['failed']} failed; {outcomes['skipped']} URDFs skipped (no single arm); threads {args.threads}"
    )


if __name__ == "__main__":
    main()
