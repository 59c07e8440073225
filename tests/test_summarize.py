import json

from rbfn.summarize import load_jobs, main, summarize


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
