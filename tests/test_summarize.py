import json

from rbfn.summarize import compare, load_jobs, main, summarize


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
