"""One look for every figure: agent order, colours (the same in every figure), labels, column-width fonts."""
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
    return DASHES.get(agent, (0, (6, 1.5, 1.2, 1.5)))


def label(agent: str) -> str:
    return LABELS.get(agent, agent)


def apply() -> None:
    plt.rcParams.update(RC)
