import json

from rbfn.summarize import compare, find_jobs, load_jobs, main, summarize


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
                _job(tmp_path, n, [f"centers={c}", f"rbfn.num_centers={m}", f"seed={seed}"],
                     {"test_pos_err_mm_median": err, "select_seconds": 1.0})
                n += 1
    swept, rows = summarize(load_jobs(tmp_path), ("test_pos_err_mm_median",))
    assert swept == ["centers", "rbfn.num_centers"]
    assert len(rows) == 4
    by = {g: stats["test_pos_err_mm_median"] for g, _, stats in rows}
    assert by[("aco", "10")][0] == 1.5                      # mean of 1.0 and 2.0
    assert abs(by[("aco", "10")][1] - 0.7071) < 1e-3        # sample std
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "| aco | 10 | 2 |" in out
    assert (tmp_path / "summary.csv").is_file() and (tmp_path / "summary.png").is_file()


def test_compare_pairs_jobs_by_seed(tmp_path, capsys):
    n = 0
    for c, err in (("aco", (1.0, 3.0)), ("kmeans", (2.0, 2.5)), ("random", (9.0, 9.0))):
        for seed in (0, 1):
            _job(tmp_path, n, [f"centers={c}", "rbfn.num_centers=10", f"seed={seed}"],
                 {"test_pos_err_mm_median": err[seed]})
            n += 1
    swept, rows = compare(load_jobs(tmp_path), "centers", "aco", "kmeans", ("test_pos_err_mm_median",))
    assert swept == []                                      # M is not swept here
    ((g, pairs, stats),) = rows
    diff, std, ratio, wins = stats["test_pos_err_mm_median"]
    assert (pairs, diff, wins) == (2, -0.25, 1)             # (1 - 2 + 3 - 2.5) / 2; seed 0 only
    assert abs(std - 0.75 * 2 ** 0.5) < 1e-12 and abs(ratio - (0.5 + 1.2) / 2) < 1e-12
    main([str(tmp_path), "--metrics", "test_pos_err_mm_median", "--compare", "centers=aco,kmeans"])
    assert "| 2 | -0.25 ± 1.1 | 0.850 | 1/2 |" in capsys.readouterr().out


def test_jobs_without_metrics_are_listed_with_their_error(tmp_path, capsys):
    import os

    _job(tmp_path, 0, ["rbfn.num_centers=10", "seed=0"], {"test_pos_err_mm_median": 2.0})
    _job(tmp_path, 1, ["rbfn.num_centers=20", "seed=0"], {"test_pos_err_mm_median": 1.0})
    # Failed in validation: no .hydra, the error and overrides in failed.json.
    (tmp_path / "2").mkdir()
    (tmp_path / "2" / "train.log").write_text("")
    (tmp_path / "2" / "failed.json").write_text(json.dumps({
        "error": "ValueError", "message": "rbfn.num_centers=100000 is not allowed | too many",
        "overrides": ["rbfn.num_centers=100000", "seed=0"]}))
    # Stopped without failed.json (killed): its last ERROR log line, if any, is the error.
    (tmp_path / "3" / ".hydra").mkdir(parents=True)
    (tmp_path / "3" / ".hydra" / "overrides.yaml").write_text("- rbfn.num_centers=40\n- seed=0\n")
    (tmp_path / "3" / "last.pt").write_bytes(b"")
    (tmp_path / "3" / "train.log").write_text("[2026-01-01 00:00:00,000][train][INFO] - resuming\n"
                                              "[2026-01-01 00:00:01,000][rbfn][ERROR] - out of memory\n")
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
        ("0", "completed"), ("1", "completed"), ("2", "failed"), ("3", "unfinished"), ("4", "unfinished"),
        ("5", "completed")]
    assert jobs[2].overrides == {"rbfn.num_centers": "100000", "seed": "0"}
    assert jobs[3].error == "out of memory"
    assert jobs[4].error.startswith("no metrics.json")
    assert len(load_jobs(tmp_path)) == 3

    main([str(tmp_path), "--metrics", "test_pos_err_mm_median"])
    out = capsys.readouterr().out
    assert ("| 2 | failed | rbfn.num_centers=100000 | ValueError: rbfn.num_centers=100000 is not allowed "
            "\\| too many |") in out
    assert "| 3 | unfinished | rbfn.num_centers=40 | out of memory |" in out
    assert "6 jobs: 3 completed, 1 failed, 2 unfinished" in out
    assert "| 2 | failed |" in (tmp_path / "summary.md").read_text()


def test_a_sweep_where_every_job_failed_is_still_summarized(tmp_path, capsys):
    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "failed.json").write_text(json.dumps({"error": "ValueError", "message": "bad",
                                                            "overrides": ["seed=0"]}))
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "No completed job." in out and "| 0 | failed | seed=0 | ValueError: bad |" in out
