import json
import os
import shutil

import pytest

from rbfn.studies.summarize import compare, find_jobs, load_jobs, main, summarize

from ..conftest import error_line


def _job(root, num, overrides, metrics):
    d = root / str(num)
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (d / "metrics.json").write_text(json.dumps(metrics))


def test_groups_by_swept_keys_over_seeds(tmp_path, capsys):
    n = 0
    for c in ("aco", "kmeans"):
        for m in (10, 40):
            for seed in (0, 1):
                err = (1.0 if c == "aco" else 2.0) * 10 / m + seed
                _job(
                    tmp_path,
                    n,
                    [f"centers={c}", f"rbfn.num_centers={m}", f"seed={seed}"],
                    {"test_pos_err_mm_median": err, "select_seconds": 1.0},
                )
                n += 1
    swept, rows = summarize(load_jobs(tmp_path), ("test_pos_err_mm_median",))
    assert swept == ["centers", "rbfn.num_centers"]
    assert len(rows) == 4
    by = {g: stats["test_pos_err_mm_median"] for g, _, stats in rows}
    assert by[("aco", "10")][0] == 1.5  # mean of 1.0 and 2.0
    assert abs(by[("aco", "10")][1] - 0.7071) < 1e-3  # sample std
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "| aco | 10 | 2 |" in out
    assert (tmp_path / "summary.csv").is_file() and (tmp_path / "summary.png").is_file()


def test_compare_pairs_jobs_by_seed(tmp_path, capsys):
    n = 0
    for c, err in (("aco", (1.0, 3.0)), ("kmeans", (2.0, 2.5)), ("random", (9.0, 9.0))):
        for seed in (0, 1):
            _job(
                tmp_path,
                n,
                [f"centers={c}", "rbfn.num_centers=10", f"seed={seed}"],
                {"test_pos_err_mm_median": err[seed]},
            )
            n += 1
    swept, rows = compare(load_jobs(tmp_path), "centers", "aco", "kmeans", ("test_pos_err_mm_median",))
    assert swept == []  # M is not swept here
    ((_g, pairs, stats),) = rows
    diff, std, ratio, wins = stats["test_pos_err_mm_median"]
    assert (pairs, diff, wins) == (2, -0.25, 1)  # (1 - 2 + 3 - 2.5) / 2; seed 0 only
    assert abs(std - 0.75 * 2**0.5) < 1e-12 and abs(ratio - (0.5 + 1.2) / 2) < 1e-12
    main([str(tmp_path), "--metrics", "test_pos_err_mm_median", "--compare", "centers=aco,kmeans"])
    assert "| 2 | -0.25 ± 1.1 | 0.850 | 1/2 |" in capsys.readouterr().out


def test_jobs_without_metrics_are_listed_with_their_error(tmp_path, capsys):
    import os

    _job(tmp_path, 0, ["rbfn.num_centers=10", "seed=0"], {"test_pos_err_mm_median": 2.0})
    _job(tmp_path, 1, ["rbfn.num_centers=20", "seed=0"], {"test_pos_err_mm_median": 1.0})
    # Failed in validation: no .hydra, the error and overrides in failed.json.
    (tmp_path / "2").mkdir()
    (tmp_path / "2" / "train.log").write_text("")
    (tmp_path / "2" / "failed.json").write_text(
        json.dumps(
            {
                "error": "ValueError",
                "message": "rbfn.num_centers=100000 is not allowed | too many",
                "overrides": ["rbfn.num_centers=100000", "seed=0"],
            }
        )
    )
    # Stopped without failed.json (killed): its last ERROR log line, if any, is the error.
    (tmp_path / "3" / ".hydra").mkdir(parents=True)
    (tmp_path / "3" / ".hydra" / "overrides.yaml").write_text("- rbfn.num_centers=40\n- seed=0\n")
    (tmp_path / "3" / "last.pt").write_bytes(b"")
    (tmp_path / "3" / "train.log").write_text(
        "[2026-01-01 00:00:00,000][train][INFO] - resuming\n[2026-01-01 00:00:01,000][rbfn][ERROR] - out of memory\n"
    )
    (tmp_path / "4").mkdir()
    (tmp_path / "4" / "train.log").write_text("")
    # A rerun that completed after a recorded failure counts as completed.
    _job(tmp_path, 5, ["rbfn.num_centers=80", "seed=0"], {"test_pos_err_mm_median": 0.5})
    (tmp_path / "5" / "failed.json").write_text(json.dumps({"error": "RuntimeError", "message": "old"}))
    os.utime(tmp_path / "5" / "failed.json", ns=(1, 1))
    # submitit's folder is no job.
    (tmp_path / ".submitit" / "7_0").mkdir(parents=True)
    (tmp_path / ".submitit" / "7_0" / "7_0_log.log").write_text("[x][y][ERROR] - noise\n")

    jobs = find_jobs(tmp_path)
    assert [(j.path.name, j.status) for j in jobs] == [
        ("0", "completed"),
        ("1", "completed"),
        ("2", "failed"),
        ("3", "unfinished"),
        ("4", "unfinished"),
        ("5", "completed"),
    ]
    assert jobs[2].overrides == {"rbfn.num_centers": "100000", "seed": "0"}
    assert jobs[3].error == "out of memory"
    assert jobs[4].error.startswith("no metrics.json")
    assert len(load_jobs(tmp_path)) == 3

    main([str(tmp_path), "--metrics", "test_pos_err_mm_median"])
    out = capsys.readouterr().out
    assert (
        "| 2 | failed | rbfn.num_centers=100000 | ValueError: rbfn.num_centers=100000 is not allowed \\| too many |"
    ) in out
    assert "| 3 | unfinished | rbfn.num_centers=40 | out of memory |" in out
    assert "6 jobs: 3 completed, 1 failed, 2 unfinished" in out
    assert "| 2 | failed |" in (tmp_path / "summary.md").read_text()


def test_a_sweep_where_every_job_failed_is_still_summarized(tmp_path, capsys):
    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "failed.json").write_text(
        json.dumps({"error": "ValueError", "message": "bad", "overrides": ["seed=0"]})
    )
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "No completed job." in out and "| 0 | failed | seed=0 | ValueError: bad |" in out


# Bad inputs: a malformed job is listed and skipped, a bad argument is a one-line error (exit 2)
# that writes nothing, and a good summary is replaced only by a complete one.

GOOD = {"test_pos_err_mm_median": 2.0, "select_seconds": 1.0, "selector": "aco", "growth": [{"val_E": 1.0}]}


def _sweep(root):
    """Four good jobs: centers aco / kmeans, seeds 0 and 1."""
    for n, (c, seed) in enumerate((c, s) for c in ("aco", "kmeans") for s in (0, 1)):
        _job(root, n, [f"centers={c}", f"seed={seed}"], {**GOOD, "test_pos_err_mm_median": 1.0 + n})
    return root


def _outputs(root):
    return {f.name: f.read_bytes() for f in sorted(root.iterdir()) if f.is_file()}


def _error_line(capsys, *argv, status=2):
    return error_line(capsys, main, "python -m rbfn.studies.summarize", *argv, status=status)


@pytest.mark.parametrize(
    "text, why",
    [
        ('"oops"', "holds a JSON string, not an object"),
        ("{not json", "not valid JSON"),
        ("[1, 2]", "holds a JSON array"),
        ("3.5", "holds a JSON number"),
        ("null", "holds a JSON null"),
        ("", "not valid JSON"),
        (b"\xff\xfe{}", "not valid JSON"),
        ('{"test_pos_err_mm_median": NaN}', "NaN is not a JSON number"),
        ('{"test_pos_err_mm_median": -Infinity}', "-Infinity is not a JSON number"),
        ('{"test_pos_err_mm_median": 1e400}', "test_pos_err_mm_median is a number beyond float's range"),
        ('{"test_pos_err_mm_median": 1' + "0" * 400 + "}", "test_pos_err_mm_median is a number beyond float's range"),
        ('{"test_pos_err_mm_median": "1.5"}', 'test_pos_err_mm_median is a JSON string ("1.5"), not a number'),
        ('{"test_pos_err_mm_median": [1.0]}', "test_pos_err_mm_median is a JSON array ([1.0]), not a number"),
        ('{"test_pos_err_mm_median": {"a": 1}}', 'test_pos_err_mm_median is a JSON object ({"a": 1}), not a number'),
        ('{"test_pos_err_mm_median": true}', "test_pos_err_mm_median is a JSON boolean (true), not a number"),
        (None, "metrics.json cannot be read: Is a directory"),
        ("fifo", "metrics.json cannot be read: it is a FIFO (named pipe), not a regular file; not read"),
        ("big", "metrics.json cannot be read: it holds 3 GiB, more than 64 MiB; not read"),
        ("dangling", "metrics.json cannot be read: No such file or directory"),
    ],
)
def test_a_malformed_job_is_listed_and_the_good_ones_summarized(tmp_path, capsys, text, why):
    """Also a metrics.json that is no file or too large to read: never read (a FIFO is not waited on)."""
    _sweep(tmp_path)
    bad = tmp_path / "4" / "metrics.json"
    _job(tmp_path, 4, ["centers=random", "seed=0"], {})
    if text in (None, "fifo", "dangling"):
        bad.unlink()
        {None: bad.mkdir, "fifo": lambda: os.mkfifo(bad), "dangling": lambda: bad.symlink_to("gone")}[text]()
    elif text == "big":
        os.truncate(bad, 3 << 30)  # sparse: no disk used
    else:
        bad.write_bytes(text if isinstance(text, bytes) else text.encode())
    main([str(tmp_path), "--metrics", "test_pos_err_mm_median"])
    out = capsys.readouterr().out
    assert "| aco | 2 | 1.5 ± 0.71 |" in out and "| kmeans | 2 | 3.5 ± 0.71 |" in out
    assert "random" not in out.split("Jobs not summarized")[0]  # the bad job is in no row
    assert "| 4 | malformed | centers=random seed=0 |" in out and why in out
    assert "5 jobs: 4 completed, 0 failed, 0 unfinished, 1 malformed" in out
    assert (tmp_path / "summary.md").read_text() in out


def test_a_null_metric_is_a_blank_cell_not_a_malformed_job(tmp_path, capsys):
    """train.py writes null where a metric does not apply (ridge after refinement)."""
    _job(tmp_path, 0, ["solver=ridge"], {"ridge": 1e-6})
    _job(tmp_path, 1, ["solver=refine"], {"ridge": None})
    main([str(tmp_path), "--metrics", "ridge"])
    out = capsys.readouterr().out
    assert "| refine | 1 |  |" in out and "| ridge | 1 | 1e-06 ± 0 |" in out and "malformed" not in out


@pytest.mark.parametrize(
    "metrics, message",
    [
        (
            ["test_pos_err_mm_mediam"],
            (
                "--metrics: no number named 'test_pos_err_mm_mediam' (did you mean "
                "'test_pos_err_mm_median'?) in any job's metrics.json; the jobs' numeric "
                "metrics are: select_seconds, test_pos_err_mm_median"
            ),
        ),
        (
            ["select_seconds", "selector", "nothing_like_it"],
            (
                "--metrics: no number named 'selector' (did you mean "
                "'select_seconds'?), 'nothing_like_it' in any job's "
                "metrics.json"
            ),
        ),
        (["growth"], "no number named 'growth'"),
    ],
)
def test_an_unknown_metric_is_an_error_and_writes_nothing(tmp_path, capsys, metrics, message):
    main([str(_sweep(tmp_path))])
    good = _outputs(tmp_path)
    assert set(good) == {"summary.md", "summary.csv"}
    err = _error_line(capsys, tmp_path, "--metrics", *metrics)
    assert message in err
    assert _outputs(tmp_path) == good


@pytest.mark.parametrize(
    "spec, message",
    [
        (
            "center=aco,kmeans",
            (
                "--compare center=aco,kmeans: center is not a swept override (did you mean "
                "centers?); swept: centers, seed"
            ),
        ),
        ("rbfn.num_centers=10,20", "rbfn.num_centers is not a swept override"),
        (
            "centers=aco,kmean",
            (
                "--compare centers=aco,kmean: expected centers=A,B with A and B two different "
                "values of centers: aco, kmeans"
            ),
        ),
        ("centers=aco", "expected centers=A,B"),
        ("centers=aco,aco", "two different values"),
        ("centers=aco,kmeans,random", "two different values"),
        ("=aco,kmeans", "--compare =aco,kmeans: expected KEY=A,B"),
        ("centers", "expected KEY=A,B"),
    ],
)
def test_a_bad_compare_is_an_error_and_writes_nothing(tmp_path, capsys, spec, message):
    main([str(_sweep(tmp_path))])
    good = _outputs(tmp_path)
    assert message in _error_line(capsys, tmp_path, "--compare", spec)
    assert _outputs(tmp_path) == good


def test_compare_accepts_values_holding_commas(tmp_path, capsys):
    for n, (w, seed) in enumerate((w, s) for w in ("[1,2]", "[3,4]") for s in (0, 1)):
        _job(tmp_path, n, [f"widths={w}", f"seed={seed}"], {"test_pos_err_mm_median": 1.0 + n})
    main([str(tmp_path), "--metrics", "test_pos_err_mm_median", "--compare", "widths=[1,2],[3,4]"])
    assert "widths: [1,2] against [3,4], paired by seed" in capsys.readouterr().out


def test_a_missing_or_empty_sweep_dir_is_an_error_and_writes_nothing(tmp_path, capsys):
    assert "SWEEP_DIR " + str(tmp_path / "nope") + ": no such directory" in _error_line(capsys, tmp_path / "nope")
    (tmp_path / "file").write_text("x")
    assert "is not a directory" in _error_line(capsys, tmp_path / "file")
    (tmp_path / "empty").mkdir()
    assert "no job directories under" in _error_line(capsys, tmp_path / "empty")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "file"] and not any((tmp_path / "empty").iterdir())


def test_a_write_protected_summary_is_kept_unless_forced(tmp_path, capsys):
    main([str(_sweep(tmp_path))])
    md = tmp_path / "summary.md"
    md.write_text("kept")
    md.chmod(0o444)
    (tmp_path / "summary.csv").write_text("old csv")
    err = _error_line(capsys, tmp_path)
    assert f"{md} is write-protected (mode 0o444); not replacing it (--force replaces it)" in err
    assert md.read_text() == "kept" and (tmp_path / "summary.csv").read_text() == "old csv"
    main([str(tmp_path), "--force"])
    assert "| aco | 2 |" in md.read_text() and (md.stat().st_mode & 0o777) == 0o444
    assert "old csv" not in (tmp_path / "summary.csv").read_text()
    assert not list(tmp_path.glob("*.tmp"))


def test_an_output_that_cannot_be_written_is_an_error_and_writes_nothing(tmp_path, capsys):
    main([str(_sweep(tmp_path))])
    good = _outputs(tmp_path)
    (tmp_path / "summary.csv").unlink()
    (tmp_path / "summary.csv").mkdir()
    assert f"{tmp_path / 'summary.csv'} is a directory" in _error_line(capsys, tmp_path)
    (tmp_path / "out").write_text("a file")
    assert "--out " in _error_line(capsys, tmp_path, "--out", tmp_path / "out" / "summary")
    assert _outputs(tmp_path) == {**{k: v for k, v in good.items() if k != "summary.csv"}, "out": b"a file"}


def test_files_are_written_all_or_none(tmp_path, monkeypatch):
    """A failure while writing the second file (here: the disk fills up) replaces neither."""
    from rbfn.files import write_files

    (tmp_path / "a").write_text("old a")
    calls = []

    def fsync(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OSError):
        write_files({tmp_path / "a": b"new a", tmp_path / "b": b"new b"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"] and (tmp_path / "a").read_text() == "old a"


@pytest.mark.parametrize(
    "record, error",
    [
        ([1], "unreadable failed.json: a JSON array, not an object"),
        ({"error": "ValueError", "message": "bad", "overrides": 5}, "ValueError: bad"),
    ],
)
def test_a_malformed_failed_json_is_listed(tmp_path, capsys, record, error):
    _sweep(tmp_path)
    (tmp_path / "4").mkdir()
    (tmp_path / "4" / "failed.json").write_text(json.dumps(record))
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "| aco | 2 |" in out and f"| 4 | failed |  | {error} |" in out


def _scandir_failing_at(monkeypatch, where):
    """os.scandir raising PermissionError for directory `where` (as a mode-000 directory does for a
    user who is not root)."""
    scandir = os.scandir

    def fake(path="."):
        if os.path.realpath(path) == os.path.realpath(where):
            raise PermissionError(13, "Permission denied")
        return scandir(path)

    monkeypatch.setattr(os, "scandir", fake)


def test_an_unreadable_job_or_sweep_directory_is_named_not_skipped(tmp_path, capsys, monkeypatch):
    _sweep(tmp_path)
    _scandir_failing_at(monkeypatch, tmp_path / "3")
    main([str(tmp_path), "--metrics", "test_pos_err_mm_median"])
    out = capsys.readouterr().out
    assert "| 3 | unreadable |  | the directory cannot be read: Permission denied |" in out
    assert "4 jobs: 3 completed, 0 failed, 0 unfinished, 1 unreadable" in out
    _scandir_failing_at(monkeypatch, tmp_path)
    assert f"SWEEP_DIR {tmp_path}: cannot be read: Permission denied" in _error_line(capsys, tmp_path)


def test_a_log_is_searched_in_its_tail_only(tmp_path, monkeypatch):
    import rbfn.studies.summarize

    (tmp_path / "0").mkdir()
    first, last = "[t][train][ERROR] - early\n", "[t][train][ERROR] - the last\n"
    (tmp_path / "0" / "train.log").write_text(first + "x" * 5000 + "\n" + last)
    monkeypatch.setattr(rbfn.studies.summarize, "LOG_TAIL_BYTES", 200)
    assert find_jobs(tmp_path)[0].error == "the last"


def test_a_stale_figure_is_removed_with_the_tables_it_belonged_to(tmp_path, capsys, monkeypatch):
    """A summary without a figure (here: a single M left) removes the earlier summary.png, in the same
    all-or-none step as the tables; a write-protected one is kept unless --force."""
    for n, m in enumerate((10, 40)):
        _job(tmp_path, n, [f"rbfn.num_centers={m}", "seed=0"], {"test_pos_err_mm_median": 1.0})
    main([str(tmp_path)])
    png = tmp_path / "summary.png"
    assert png.is_file()
    shutil.rmtree(tmp_path / "1")
    png.chmod(0o444)
    assert f"{png} is write-protected" in _error_line(capsys, tmp_path)
    png.chmod(0o644)
    old = _outputs(tmp_path)
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(28, "No space left on device")))
    assert "nothing was replaced" in _error_line(capsys, tmp_path, status=1)
    assert _outputs(tmp_path) == old  # the figure kept with its tables
    monkeypatch.undo()
    main([str(tmp_path)])
    assert f"removed the stale {png}" in capsys.readouterr().out
    assert not png.exists() and {"summary.md", "summary.csv"} <= set(_outputs(tmp_path))
    assert not list(tmp_path.glob("*.tmp"))
    png.mkdir()  # a directory of that name is no figure: left alone
    main([str(tmp_path)])
    assert png.is_dir() and "removed the stale" not in capsys.readouterr().out


def _multirun(root, task, params=None, launcher="hydra._internal.core_plugins.basic_launcher.BasicLauncher"):
    """The parts of Hydra's multirun.yaml the summarizer reads."""
    (root / "multirun.yaml").write_text(
        "hydra:\n"
        f"  sweep:\n    dir: {root}\n    subdir: ${{hydra.job.num}}\n"
        f"  launcher:\n    _target_: {launcher}\n"
        "  sweeper:\n    _target_: hydra._internal.core_plugins.basic_sweeper.BasicSweeper\n"
        "    max_batch_size: null\n"
        + (f"    params:\n{''.join(f'      {k}: {v}' + chr(10) for k, v in params.items())}" if params else "")
        + "  overrides:\n    task:\n"
        + "".join(f"    - {t}\n" for t in task)
    )


def test_a_job_whose_directory_is_gone_is_counted_from_the_sweeps_list(tmp_path, capsys):
    """A job that failed before writing any result and could not write its failed.json (a full disk)
    is tidied away: the sweep's multirun.yaml still lists it. Failed where a later job started (the
    launcher starts them in order), missing where none did (not started, or lost so)."""
    _multirun(tmp_path, ["centers=aco,kmeans", "data.n_train=300"], params={"seed": "0,1,2"})
    jobs = [(c, s) for s in (0, 1, 2) for c in ("aco", "kmeans")]  # params first, then the command line
    for n in (0, 2, 3):
        c, s = jobs[n]
        _job(tmp_path, n, [f"centers={c}", "data.n_train=300", f"seed={s}"], {"test_pos_err_mm_median": 1.0})
    (tmp_path / "4").mkdir()  # made by Hydra, nothing written yet
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "| 1 | failed | centers=kmeans seed=0 | no job directory: it started (a later job did)" in out
    assert "| 4 | unfinished | centers=aco seed=2 | its directory holds no record yet" in out
    assert "| 5 | missing | centers=kmeans seed=2 | no job directory: not started" in out
    assert "6 jobs: 3 completed, 1 failed, 1 unfinished, 1 missing" in out
    # A SLURM array starts its tasks in any order: a gone job is missing, whatever started after it.
    _multirun(tmp_path, ["centers=aco,kmeans", "seed=0,1,2"], launcher="hydra_plugins.submitit_launcher.SlurmLauncher")
    main([str(tmp_path)])
    assert "| 1 | missing |" in capsys.readouterr().out


@pytest.mark.parametrize(
    "text, note",
    [
        ("{{{", "multirun.yaml is not a Hydra multirun's"),
        ("hydra: {}\n", "multirun.yaml is not a Hydra multirun's (no 'sweep')"),
        (None, "multirun.yaml cannot be read: Is a directory"),
    ],
)
def test_an_unreadable_sweep_list_is_named(tmp_path, capsys, text, note):
    _sweep(tmp_path)
    if text is None:
        (tmp_path / "multirun.yaml").mkdir()
    else:
        (tmp_path / "multirun.yaml").write_text(text)
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert f"Not counted: {note}" in out and "jobs without a directory cannot be counted" in out
    assert "4 jobs: 4 completed" in out
