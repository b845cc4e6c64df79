"""One look for every figure: agent order, colours and line styles (the same in every figure), column-width
fonts."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

KNOWN = ["ppo", "l2", "recom_l2"]  # the paper's agents (legend labels: each agent's YAML `label:`, conditions.py)
# Okabe-Ito (colour-blind safe): fixed colours for the paper's agents, then further ones for other agents (Okabe-Ito,
# then Tol's wine and olive, grey, brown; no yellow, too faint on white): eleven agents, eleven colours.
FIXED = {"ppo": "#D55E00", "l2": "#0072B2", "recom_l2": "#009E73"}
EXTRA = ["#CC79A7", "#E69F00", "#56B4E9", "#000000", "#882255", "#999933", "#999999", "#8C564B"]
# Line styles too, so that coinciding curves (e.g. RECOM before its first update) stay visible.
DASHES = {"ppo": "-", "l2": (0, (4, 1.5)), "recom_l2": (0, (1.2, 1.2))}
OTHER_DASH = (0, (6, 1.5, 1.2, 1.5))  # agents without a fixed style
# Once the conditions have used every free colour, the colours repeat with these (no agent's) dashes, the first
# ones least like OTHER_DASH.
ROUND_DASHES = [(0, (8, 2)), (0, (0.6, 2)), (0, (3, 1, 1, 1, 1, 1)), (0, (2, 2)), (0, (6, 1, 1, 1, 1, 1, 1, 1)),
                (0, (10, 1.5, 2, 1.5)), (0, (3, 3)), (0, (1, 1, 4, 1))]

COLUMN_WIDTH = 3.5  # inches (one column of a two-column paper)
RC = {"font.size": 7, "axes.labelsize": 7, "axes.titlesize": 7, "xtick.labelsize": 7, "ytick.labelsize": 7,
      "legend.fontsize": 7, "legend.title_fontsize": 7, "lines.linewidth": 1.0, "axes.linewidth": 0.6,
      "grid.linewidth": 0.4, "grid.alpha": 0.4, "savefig.dpi": 300, "pdf.fonttype": 42,
      "axes.spines.top": False, "axes.spines.right": False}


def ordered(agents, key=None) -> list[str]:
    """The paper's agents in the paper's order, then any other agent alphabetically (by ``key(agent)``, e.g. its
    label, if given)."""
    agents = set(agents)
    return [a for a in KNOWN if a in agents] + sorted(agents - set(KNOWN), key=key)


def dashes(agent: str):
    return DASHES.get(agent, OTHER_DASH)


def looks(agent_of: dict[str, str]) -> dict[str, tuple]:
    """(colour, line style) of each condition (``agent_of``: condition -> its agent, in display order). The report
    computes it once from all its conditions, so a condition looks the same in every figure.

    The paper's agents keep their fixed look (a split one: its first condition). Every other condition takes the
    first look that no condition has yet: one of the EXTRA colours (then those of paper agents absent from the
    report) with its agent's dash (OTHER_DASH for other agents), or once those run out, each colour with each of
    ROUND_DASHES in turn. Agents with one condition choose first. No two conditions look alike (up to
    9 x len(EXTRA) of them).
    """
    out = {}
    for cond, agent in agent_of.items():
        if agent in FIXED and agent not in [agent_of[c] for c in out]:
            out[cond] = (FIXED[agent], dashes(agent))
    colours = EXTRA + [FIXED[a] for a in FIXED if a not in agent_of.values()]
    agents = list(agent_of.values())
    rest = sorted((c for c in agent_of if c not in out), key=lambda c: agents.count(agent_of[c]) > 1)
    for cond in rest:
        used = {colour for colour, _ in out.values()}
        fresh = [(c, dashes(agent_of[cond])) for c in colours if c not in used]
        again = [(c, d) for d in ROUND_DASHES for c in colours]
        out[cond] = next(look for look in fresh + again if look not in out.values())
    return {cond: out[cond] for cond in agent_of}


def apply() -> None:
    plt.rcParams.update(RC)
