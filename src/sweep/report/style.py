"""One look for every figure: agent order, colours and line styles (the same in every figure), labels,
column-width fonts."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

KNOWN = ["ppo", "l2", "recom_l2"]
LABELS = {"ppo": "PPO", "l2": "L2 + PPO", "recom_l2": "RECOM + L2 PPO"}
# Okabe-Ito (colour-blind safe): fixed colours for the paper's agents, then further ones for unknown agents.
FIXED = {"ppo": "#D55E00", "l2": "#0072B2", "recom_l2": "#009E73"}
EXTRA = ["#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442", "#999999"]
# Line styles too, so that coinciding curves (e.g. RECOM before its first update) stay visible.
DASHES = {"ppo": "-", "l2": (0, (4, 1.5)), "recom_l2": (0, (1.2, 1.2))}
OTHER_DASH = (0, (6, 1.5, 1.2, 1.5))  # agents without a fixed style
# Once a split agent's conditions have used every free colour, the colours repeat with these (no agent's) dashes.
ROUND_DASHES = [(0, (3, 1, 1, 1, 1, 1)), (0, (8, 2)), (0, (0.6, 2)), (0, (6, 1, 1, 1, 1, 1, 1, 1)), (0, (2, 2)),
                (0, (10, 1.5, 2, 1.5)), (0, (3, 3)), (0, (1, 1, 4, 1))]

COLUMN_WIDTH = 3.5  # inches (one column of a two-column paper)
RC = {"font.size": 7, "axes.labelsize": 7, "axes.titlesize": 7, "xtick.labelsize": 7, "ytick.labelsize": 7,
      "legend.fontsize": 7, "legend.title_fontsize": 7, "lines.linewidth": 1.0, "axes.linewidth": 0.6,
      "grid.linewidth": 0.4, "grid.alpha": 0.4, "savefig.dpi": 300, "pdf.fonttype": 42,
      "axes.spines.top": False, "axes.spines.right": False}


def ordered(agents) -> list[str]:
    """The paper's agents in the paper's order, then any other agent alphabetically."""
    agents = set(agents)
    return [a for a in KNOWN if a in agents] + sorted(agents - set(KNOWN))


def palette(agents) -> dict[str, str]:
    unknown = [a for a in ordered(agents) if a not in FIXED]
    return {**FIXED, **{a: EXTRA[i % len(EXTRA)] for i, a in enumerate(unknown)}}


def dashes(agent: str):
    return DASHES.get(agent, OTHER_DASH)


def looks(agent_of: dict[str, str]) -> dict[str, tuple]:
    """(colour, line style) of each condition (``agent_of``: condition -> its agent, in display order).

    An agent with one condition keeps its own colour and dash (fixed for the paper's agents), so without --by
    every figure looks as the agents alone would. The first condition of a split paper agent keeps the agent's
    colour too; the other conditions of split agents take, in order, the colours nobody uses yet, with their
    agent's dash, and when those run out the same colours again with ROUND_DASHES. No two conditions look alike
    (up to len(remaining colours) x (1 + len(ROUND_DASHES)) of them).
    """
    agents = list(agent_of.values())
    colors = palette(agents)
    out = {}
    for cond, agent in agent_of.items():
        if agents.count(agent) == 1:
            out[cond] = (colors[agent], dashes(agent))
        elif agent in FIXED and not any(agent_of[c] == agent for c in out):
            out[cond] = (FIXED[agent], dashes(agent))
    used = {color for color, _ in out.values()}
    free = [c for c in [*FIXED.values(), *EXTRA] if c not in used] or EXTRA
    rest = [cond for cond in agent_of if cond not in out]
    for k, cond in enumerate(rest):
        lap, i = divmod(k, len(free))
        out[cond] = (free[i], dashes(agent_of[cond]) if lap == 0 else ROUND_DASHES[(lap - 1) % len(ROUND_DASHES)])
    return {cond: out[cond] for cond in agent_of}


def label(agent: str) -> str:
    return LABELS.get(agent, agent)


def apply() -> None:
    plt.rcParams.update(RC)
