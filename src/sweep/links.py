"""``python -m sweep.links [EXPERIMENT ...]``: the MLflow UI links that open each experiment's Runs table.

``mlflow ui`` (MLflow 3) opens an experiment on its GenAI overview ("Traces"), one toggle away from the runs;
these links open the runs table directly. Without arguments: every experiment of the store, newest first.
"""
from __future__ import annotations

import sys

from sweep.tracking import experiment_names, experiment_url, tracking_uri


def main(argv: list[str]) -> int:
    uri = tracking_uri()
    names = argv or experiment_names(uri)
    if len(names) == 1 and argv:
        print(experiment_url(uri, names[0]) or f"(no experiment {names[0]!r} in {uri})")
        return 0
    for name in names:
        print(f"{name}: {experiment_url(uri, name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
