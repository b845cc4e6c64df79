"""The pilot's segment-length measure: when does a fresh network first hover under the change?

Every agent's first segment and every segment of reset_all start from a freshly drawn network. For each, the
timesteps from the segment's start to its first evaluation at >= 50% success (stats.segment_evaluations'
hover_after). A segment length fits the study when the fresh networks that hover within the longest segment
tried do so within it. Run from the repo root, against the study's store:

    MLFLOW_TRACKING_URI=sqlite:////work/studies/plasticity/mlflow.db .venv/bin/python docs/plasticity_study/fresh_networks.py
"""
import sys

from sweep.report import load, stats


def main(experiment: str = "plasticity-pilot") -> None:
    client = load.client_for(load.tracking_uri())
    exp_id, _ = load.pick_experiment(client, experiment)
    runs = load.load_runs(client, exp_id)[0]
    ev = stats.segment_evaluations(load.load_histories(client, runs), runs)
    ev = ev.merge(runs[["run_id", "agent", "wind"]], on="run_id")
    for wind, w in ev.groupby("wind"):
        fresh = w[(w["segment"] == 0) | (w["agent"] == "reset_all")]
        later = w[(w["segment"] > 0) & (w["agent"] != "reset_all")]
        for name, part in (("fresh networks (every first segment, reset_all's later ones)", fresh),
                           ("continual networks after a change", later)):
            h = (part["hover_after"].dropna() / 1e6).sort_values()
            by = ", ".join(f"{(h <= m + 0.01).sum()} by {m}M" for m in (1, 2, 3, 4))
            print(f"wind {wind}, {name}: {len(part)} segments, {len(h)} hovered ({len(h) / len(part):.0%}); "
                  f"first hover at {by}; median {h.median():.2f}M")


if __name__ == "__main__":
    main(*sys.argv[1:])
