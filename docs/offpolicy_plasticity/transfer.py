"""Does a trained TD3 policy fly a condition it was not trained under? Per re-evaluation named by run.sh transfer (the
final policy of every continual pilot run flown under one fixed condition, sweep.reevaluate), each run's mean final
distance to the target (m) and crash share. The flip runs ended under -x 3 m/s (segment 3), the payload runs at mass
x1.5 in still air. Run from the repo root against the study's store:

    MLFLOW_TRACKING_URI=sqlite:////work/studies/offpolicy/mlflow.db \
        .venv/bin/python docs/offpolicy_plasticity/transfer.py
"""
from __future__ import annotations

from sweep.report import load

CONDITIONS = {   # the re-evaluation's name -> what it flies (run.sh transfer)
    "still": "still air", "plus3": "+x 3 m/s", "minus3": "-x 3 m/s", "plus5": "+x 5 m/s", "minus5": "-x 5 m/s",
    "mass1": "mass x1.0", "mass15": "mass x1.5", "mass2": "mass x2.0 (thrust-to-weight 0.98: cannot hover)",
    "rotor07": "rotor 1 at 70%", "rotor05": "rotor 1 at 50%"}


def main() -> None:
    client = load.client_for(load.tracking_uri())
    exp_id, _ = load.pick_experiment(client, "offpolicy-plasticity")
    runs = load.load_runs(client, exp_id)[0]
    runs = runs[runs["agent"] == "td3"].sort_values(["wind", "seed"])
    names = [f"{r.wind} s{r.seed}" for r in runs.itertuples()]
    print("| flown under | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for name, what in CONDITIONS.items():
        cells = []
        for run_id in runs["run_id"]:
            m = client.get_run(run_id).data.metrics
            d, c = m.get(f"{name}/eval/final_distance"), m.get(f"{name}/eval/crash_rate")
            cells.append("–" if d is None else f"{d:.2f} m" + (f", {100 * c:.0f}% crashed" if c else ""))
        print(f"| {what} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
