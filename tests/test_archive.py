"""Study archives (``sweep.archive``): a real tiny run exported from one store, imported into another, skipped there
by ``resume=auto``; thinning keeps the ends."""
from __future__ import annotations

import numpy as np
import pytest
from mlflow.tracking import MlflowClient

from conftest import TINY, compose_cfg, new_store
from sweep.archive import archive_files, export, import_, load, main, thin
from sweep.run import run
from sweep.tracking import ARCHIVED_FROM

EXP = "recom-hover"  # conf/config.yaml tracking.experiment


def test_thin_keeps_first_last_and_at_most_max_points():
    steps, values = np.arange(0, 10_000, 7), np.arange(0, 10_000, 7) * 0.5
    s, v = thin(steps, values, max_points=50)
    assert len(s) == 50 and s[0] == 0 and s[-1] == steps[-1] and np.all(np.diff(s) > 0)
    assert np.array_equal(v, s * 0.5)  # rows stay together
    short = np.arange(5)
    assert thin(short, short, max_points=50)[0] is short  # fewer points: kept whole


def test_export_import_round_trip_and_resume_skips_imported_runs(tmp_path, monkeypatch, capsys):
    source, target = new_store(tmp_path / "a.db"), new_store(tmp_path / "b.db")
    overrides = ["agent=recom_l2", "seed=4", "wind=paper", *TINY]
    monkeypatch.setenv("MLFLOW_TRACKING_URI", source)
    original_id = run(compose_cfg(overrides), tmp_path / "job_a")

    assert export(source, EXP, tmp_path / "archive", where={"wind": "none"}) == []  # --where: no such run
    for where, message in ((["--where", "wnd=none"], "--where wnd: no FINISHED run of 'recom-hover' has that tag"),
                           (["--where", "seed"], "expected KEY=VALUE")):  # a typo is an error, not an empty export
        assert main(["export", "--experiment", EXP, "--out", str(tmp_path / "x"), "--uri", source, *where]) == 2
        assert message in capsys.readouterr().err
    written = export(source, EXP, tmp_path / "archive", max_points=2, where={"seed": "4", "agent.l2.enabled": "True"})
    assert len(written) == 1 and export(source, EXP, tmp_path / "archive") == []  # each run once
    assert load(written[0]).run_id == original_id
    (tmp_path / "archive" / "sub").mkdir()  # import searches directories recursively
    written = [written[0].rename(tmp_path / "archive" / "sub" / written[0].name)]

    assert import_(archive_files([str(tmp_path / "archive")]), target) == (1, 0)
    assert import_(written, target) == (0, 1)  # importing twice adds nothing
    a, b = MlflowClient(source), MlflowClient(target)
    [orig] = a.search_runs([a.get_experiment_by_name(EXP).experiment_id])
    [copy] = b.search_runs([b.get_experiment_by_name(EXP).experiment_id])
    assert copy.info.status == "FINISHED" and copy.data.tags[ARCHIVED_FROM] == original_id
    assert (copy.info.start_time, copy.info.end_time) == (orig.info.start_time, orig.info.end_time)
    assert copy.data.params == orig.data.params
    assert {k: v for k, v in copy.data.tags.items() if k != ARCHIVED_FROM} == orig.data.tags
    assert copy.data.metrics == orig.data.metrics  # the latest value of every key
    for key in orig.data.metrics:
        full = [(m.step, m.value) for m in sorted(a.get_metric_history(original_id, key), key=lambda m: m.step)]
        kept = [(m.step, m.value) for m in sorted(b.get_metric_history(copy.info.run_id, key), key=lambda m: m.step)]
        assert kept == (full if len(full) <= 2 else [full[0], full[-1]]), key
    artifacts = {x.path for x in b.list_artifacts(copy.info.run_id)}
    assert artifacts == {"config.yaml", "eval_trajectories.npz"}  # the default --artifacts: no model

    # The same job against the target store: resume=auto finds the imported run FINISHED and trains nothing.
    monkeypatch.setenv("MLFLOW_TRACKING_URI", target)
    assert run(compose_cfg(overrides), tmp_path / "job_b") == copy.info.run_id
    assert len(b.search_runs([b.get_experiment_by_name(EXP).experiment_id])) == 1
    # Exporting the target store into the same archive writes nothing: the imported run is the archived one.
    assert export(target, EXP, tmp_path / "archive" / "sub") == []


def test_cli_errors_name_the_problem(tmp_path, capsys):
    uri = new_store(tmp_path / "empty.db")
    assert main(["export", "--experiment", "nope", "--out", str(tmp_path / "x"), "--uri", uri]) == 2
    assert "no experiment 'nope'" in capsys.readouterr().err
    assert main(["import", str(tmp_path / "missing.npz"), "--uri", uri]) == 2
    assert "not an archive file" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["export", "--experiment", "x"])  # --out is required
