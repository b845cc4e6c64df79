"""Which agents a figure draws in colour, and in which order its legend lists them.

A panel with more than MAX_COLOURED agents is unreadable in colour (twelve curves and their bands wash into
one). Then a figure colours, with bands and a legend entry: the top ``top`` conditions of each of its panels by
the leaderboard's primary measure, the reference agents (REFERENCES: PPO and the fresh-network ``reset_all``)
and any agent named with ``--highlight``; it draws the rest as thin grey lines without band or legend entry,
and says in its note which ones. An agent coloured in one panel is coloured in every panel of the figure.

The ranking is the leaderboard's (tables.leaderboard): "keeps hovering" (the mean over seeds of the share of a
run's late evaluations at >= 50% success, stats.late_evaluations), highest first, ties and runs without
evaluations during training by the IQM of the final training reward. In a wind whose runs are scored on
re-learning (relearning.py: evaluated under the condition being learned, after a change) the re-learning AUC
ranks instead, the plasticity study's primary measure.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from rliable import metrics as rly

from sweep.report.conditions import Conditions

MAX_COLOURED = 6             # agents in a panel that are all drawn in colour
TOP = 3                      # with more: the top conditions of each panel in colour
REFERENCES = ("ppo", "reset_all")  # always in colour


def ranking(runs: pd.DataFrame, per_run: pd.DataFrame, late: pd.DataFrame,
            relearn: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per wind and condition: ``keeps_hovering`` (mean over seeds; NaN without late evaluations), ``relearning``
    (mean over seeds; NaN without) and ``iqm_final_reward``, with ``rank`` (0 = first) within the wind by the
    primary measure (``relearning`` where the wind has it, else ``keeps_hovering``), then the reward, highest
    first."""
    df = runs[["run_id", "wind", "condition"]].merge(per_run[["run_id", "final_reward"]], on="run_id", how="left")
    df = df.merge(late[["run_id", "keeps_hovering"]], on="run_id", how="left")
    relearn = relearn if relearn is not None else pd.DataFrame(columns=["run_id", "relearning"])
    df = df.merge(relearn[["run_id", "relearning"]], on="run_id", how="left")
    rows = []
    for (wind, cond), g in df.groupby(["wind", "condition"], sort=False):
        reward = g["final_reward"].to_numpy(dtype=float)
        reward = reward[np.isfinite(reward)]
        rows.append({"wind": wind, "condition": cond, "keeps_hovering": g["keeps_hovering"].mean(),
                     "relearning": pd.to_numeric(g["relearning"]).mean(),
                     "iqm_final_reward": float(rly.aggregate_iqm(reward[:, None])) if len(reward) else np.nan})
    table = pd.DataFrame(rows, columns=["wind", "condition", "keeps_hovering", "relearning", "iqm_final_reward"])
    scored = table.groupby("wind")["relearning"].transform(lambda v: v.notna().any())
    table["primary"] = table["relearning"].where(scored, table["keeps_hovering"])
    table = table.sort_values(["wind", "primary", "iqm_final_reward"], ascending=[True, False, False],
                              na_position="last", kind="stable")
    table["rank"] = table.groupby("wind").cumcount()
    return table.reset_index(drop=True)


@dataclass
class Highlight:
    """``rank[(wind, condition)]``: the position in the ranking; ``coloured[wind]``: the agents drawn in colour;
    ``top``: how many of each panel's conditions were chosen."""
    rank: dict[tuple[str, str], int]
    coloured: dict[str, set[str]] = field(default_factory=dict)
    top: int = TOP

    def is_coloured(self, wind: str, agent: str) -> bool:
        return agent in self.coloured.get(wind, ())

    def ranked(self, wind: str, conditions) -> list[str]:
        """``conditions`` by rank in ``wind`` (those without one last, in the order given)."""
        conditions = list(conditions)
        return sorted(conditions, key=lambda c: (self.rank.get((wind, c), np.inf), conditions.index(c)))


def choose(table: pd.DataFrame, runs: pd.DataFrame, conds: Conditions, top: int = TOP,
           named: list[str] = ()) -> Highlight:
    """The Highlight of every wind of ``runs`` from the ``ranking`` ``table``."""
    out = Highlight({(r.wind, r.condition): int(r.rank) for r in table.itertuples()}, top=top)
    for wind in runs["wind"].unique():
        panels = conds.panels(runs.loc[runs["wind"] == wind, "condition"])
        agents = {conds.agent(c) for _, cs in panels for c in cs}
        if max(len({conds.agent(c) for c in cs}) for _, cs in panels) <= MAX_COLOURED:
            out.coloured[wind] = agents
            continue
        chosen = {conds.agent(c) for _, cs in panels for c in out.ranked(wind, cs)[:top]}
        out.coloured[wind] = chosen | (agents & {*REFERENCES, *named})
    return out
