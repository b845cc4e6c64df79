"""Conditions: what the report aggregates over seeds, an agent plus the values of the ``--by`` params.

Without ``--by`` a condition is an agent, labelled with the ``label:`` of its YAML as its runs logged it (e.g.
"L2 + PPO"). With ``--by agent.l2.coef,agent.l2.mode`` it is (agent, coef, mode), labelled "L2 + PPO (coef=0.001,
mode=decoupled)" (a key is shown by its last path component, more components where two keys would read the same).
A setting of a component the run switched off (an enclosing ``enabled`` param is false, e.g. ``agent.l2.coef`` of
a PPO run, whose ``agent.l2.enabled`` is False) does not apply: it is ``NA``, left out of the label, and does not
split the agent's runs.

Figures draw the conditions in panels (``Conditions.panels``). With several agents, the ``--by`` values are
small multiples: one panel per value (e.g. one per layout), each agent one series labelled and coloured as the agent
in every panel; a condition whose value does not apply (NA) appears in every panel. With one agent, its
conditions are the series of one panel (what compares them, e.g. SB3 against JAX), each with a look of its own.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from sweep.report import style
from sweep.report.load import NA, ReportError


def short_names(keys: list[str]) -> dict[str, str]:
    """Last path component of each key; more components for keys that would otherwise read the same."""
    depth = dict.fromkeys(keys, 1)
    while True:
        names = {k: ".".join(k.split(".")[-depth[k]:]) for k in keys}
        clash = [k for k in keys if list(names.values()).count(names[k]) > 1 and depth[k] < len(k.split("."))]
        if not clash:
            return names
        for k in clash:
            depth[k] += 1


def same(a: str, b: str) -> bool:
    """Equal as text, or as numbers (so that 1e-3 names the logged 0.001)."""
    if a == b:
        return True
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return False


def _value_order(v: str) -> tuple:
    """NA first, then numbers numerically, then text."""
    if v == NA:
        return (0, 0.0, "")
    try:
        return (1, float(v), "")
    except ValueError:
        return (2, 0.0, v)


@dataclass
class Conditions:
    """The conditions of a report: ``table`` has one row per condition (index: its label; columns: agent and
    the --by keys), in display order; ``looks`` maps a label to its (colour, line style); ``labels`` an agent to
    its label (a condition's label without the --by values); ``split``: the --by values are panels (several
    agents), not series of one panel; ``short``: each --by key as the labels show it."""
    by: list[str]
    table: pd.DataFrame
    looks: dict[str, tuple]
    labels: dict[str, str]
    split: bool = False
    short: dict[str, str] = field(default_factory=dict)

    @property
    def order(self) -> list[str]:
        return list(self.table.index)

    def color(self, cond: str) -> str:
        return self.looks[cond][0]

    def dash(self, cond: str):
        return self.looks[cond][1]

    def agent(self, cond: str) -> str:
        return self.table.loc[cond, "agent"]

    def series(self, cond: str) -> str:
        """A condition's legend entry: its agent's label where panels carry the --by values, else its own label."""
        return self.labels[self.agent(cond)] if self.split else cond

    def panels(self, present) -> list[tuple[str, list[str]]]:
        """(title, conditions in display order) of each panel that draws the conditions ``present``: one untitled
        panel, or with ``split`` one per --by value (in value order), titled e.g. 'n_envs=16', a condition whose
        value does not apply (NA) in every panel whose other values it matches."""
        shown = [c for c in self.order if c in set(present)]
        if not self.split:
            return [("", shown)]
        values = {c: tuple(self.table.loc[c, self.by]) for c in shown}
        keys = sorted({v for v in values.values() if NA not in v}, key=lambda v: [_value_order(x) for x in v])

        def fits(v, key):
            return all(x == k or x == NA for x, k in zip(v, key))
        keys += sorted({v for v in values.values() if not any(fits(v, k) for k in keys)},
                       key=lambda v: [_value_order(x) for x in v])
        return [(", ".join(f"{self.short[k]}={x}" for k, x in zip(self.by, key) if x != NA),
                 [c for c in shown if fits(values[c], key)]) for key in keys]


def build(runs: pd.DataFrame, by: list[str]) -> tuple[pd.DataFrame, Conditions]:
    """(``runs`` with a ``condition`` column holding the label, the Conditions of all runs)."""
    short = short_names(by)
    fields = ["agent", *by]
    table = runs[fields].drop_duplicates().copy()
    label = agent_labels(runs)
    rank = {a: i for i, a in enumerate(style.ordered(table["agent"], key=lambda a: label[a].casefold()))}
    table = table.sort_values(fields, key=lambda col: col.map(rank) if col.name == "agent" else col.map(_value_order))
    table.index = [label[row["agent"]] + _suffix(row, by, short) for _, row in table.iterrows()]
    labels = {tuple(row[fields]): cond for cond, row in table.iterrows()}
    runs = runs.assign(condition=[labels[tuple(r)] for r in runs[fields].itertuples(index=False)])
    split = bool(by) and table["agent"].nunique() > 1
    series = dict(zip(table["agent"], table["agent"])) if split else dict(zip(table.index, table["agent"]))
    look = style.looks(series)
    looks = {cond: look[agent if split else cond] for cond, agent in table["agent"].items()}
    return runs, Conditions(by, table, looks, label, split, short)


def agent_labels(runs: pd.DataFrame) -> dict[str, str]:
    """Agent -> its legend label: the label its newest run logged (load.agent_label), followed by the agent's
    name in brackets where several agents share a label."""
    label = runs.sort_values("start_time").groupby("agent")["label"].last()
    shared = label.duplicated(keep=False)
    return {agent: f"{text} [{agent}]" if shared[agent] else text for agent, text in label.items()}


def _suffix(row: pd.Series, by: list[str], short: dict[str, str]) -> str:
    shown = [f"{short[k]}={row[k]}" for k in by if row[k] != NA]
    return f" ({', '.join(shown)})" if shown else ""


def parse_baseline(text: str, conds: Conditions) -> tuple[str, str]:
    """(KEY, the logged VALUE) of ``--baseline KEY=VALUE``; one-line errors for what cannot be a baseline."""
    if not conds.by:
        raise ReportError("--baseline needs --by (it compares conditions that differ in one --by key or the agent)")
    key, sep, value = text.partition("=")
    if not sep or not key or not value:
        raise ReportError(f"--baseline {text!r}: expected KEY=VALUE, e.g. agent=ppo")
    if key not in ["agent", *conds.by]:
        raise ReportError(f"--baseline key {key!r} is neither 'agent' nor a --by key ({', '.join(conds.by)})")
    values = sorted(set(conds.table[key]) - {NA}, key=_value_order)
    match = [v for v in values if same(v, value)]
    if not match:
        raise ReportError(f"--baseline {text!r}: no run has {key}={value} (values: {', '.join(values)})")
    return key, match[0]


def baseline_of(table: pd.DataFrame, cond: str, key: str, value: str) -> str | None:
    """The condition of ``table`` equal to ``cond`` in every field but ``key``, whose value is ``value``.

    A field that does not apply to the candidate (NA) matches any value (PPO is the baseline of every L2
    setting); among several candidates the one with the most exactly equal fields wins. None for a condition
    that is itself a baseline or that has none in ``table``.
    """
    row = table.loc[cond]
    if same(row[key], value):
        return None
    fields = [f for f in table.columns if f != key]
    best, score = None, -1
    for other, cand in table[table[key] == value].iterrows():
        if all(cand[f] == row[f] or cand[f] == NA for f in fields):
            exact = sum(cand[f] == row[f] for f in fields)
            if exact > score:
                best, score = other, exact
    return best

