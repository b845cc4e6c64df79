"""One look for every figure: agent order, colours and line styles (the same in every figure and every report),
column-width fonts.

Colours. Every agent of conf/agent/ (and ``reset_all``) has its own colour, fixed by name (AGENT_COLOURS), so an
agent looks the same in every panel, figure and report. Thirteen colours are Okabe-Ito's and Paul Tol's
colour-blind-safe sets; the fourteenth was searched for on an sRGB grid, at mid lightness, as far as possible from
them and from GREY. Any two differ by at least MIN_DELTA_E (CIE76 ΔE in CIELAB) for normal vision and as simulated
for deuteranopia and protanopia (Machado et al. 2009; tests/test_report.py measures it). An agent not named here
takes the first colour that no agent of the report has; once those run out, colours repeat with ROUND_DASHES.
Agents a figure does not highlight are drawn thin in GREY (``figures``).
"""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

KNOWN = ["ppo", "l2", "recom_l2"]  # the paper's agents (legend labels: each agent's YAML `label:`, conditions.py)
AGENT_COLOURS = {
    "ppo": "#D55E00", "l2": "#0072B2", "recom_l2": "#009E73",    # the paper's agents (Okabe-Ito)
    "reset_all": "#000000",                                      # the fresh-network reference
    "recom_l2_relative": "#882255", "l2_lr_decay": "#E69F00", "l2_lr_decay_8m": "#33BBEE",
    "ppo_target_kl": "#332288", "layer_norm": "#CC79A7", "cbp_l2": "#117733", "redo": "#EE6677",
    "shrink_perturb": "#006CD1", "l2_init": "#EE99AA",
    "layer_norm_l2_lr_decay_8m": "#5A2DFF",   # the 14th: ΔE >= 36 from the 13 and GREY in all three visions
}
PALETTE = list(AGENT_COLOURS.values())
MIN_DELTA_E = 14.0  # the palette's smallest pairwise ΔE over normal vision, deuteranopia and protanopia
GREY = "#CCCCCC"    # the agents a figure does not highlight (thin, no band, no legend entry; ΔE >= 11 from every colour)
# Line styles of the paper's agents, so that coinciding curves (e.g. RECOM before its first update) stay visible;
# every other agent is solid.
DASHES = {"ppo": "-", "l2": (0, (4, 1.5)), "recom_l2": (0, (1.2, 1.2))}
OTHER_DASH = "-"
# Once a report's conditions have used every free colour, the colours repeat with these dashes.
ROUND_DASHES = [(0, (8, 2)), (0, (0.6, 2)), (0, (3, 1, 1, 1, 1, 1)), (0, (2, 2)), (0, (6, 1, 1, 1, 1, 1, 1, 1)),
                (0, (10, 1.5, 2, 1.5)), (0, (3, 3)), (0, (1, 1, 4, 1))]

COLUMN_WIDTH = 3.5  # inches (one column of a two-column paper)
PAGE_WIDTH = 7.16   # inches (both columns)
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


def arm_title(wind: str) -> str:
    """A panel's title for an arm (metrics.condition_arm): 'wind flip', 'wind none, vehicle payload'."""
    return "wind " + wind.replace("+", ", vehicle ")


def figure_width(panels: int) -> float:
    """One column for one panel, both columns for more."""
    return COLUMN_WIDTH if panels <= 1 else PAGE_WIDTH


def looks(agent_of: dict[str, str]) -> dict[str, tuple]:
    """(colour, line style) of each series (``agent_of``: series -> its agent, in display order; a series is an
    agent, or one of an agent's --by conditions drawn in the same panel). The report computes it once from all its
    series, so a series looks the same in every figure.

    An agent's first series takes the agent's own look (AGENT_COLOURS and its dash; an agent not named there the
    first colour that no agent of the report has). Each further series of the same agent takes the first look no
    series has yet: a free colour with the agent's dash, then each colour with each of ROUND_DASHES. No two series
    look alike (up to 9 x 14 of them).
    """
    present = set(agent_of.values())
    free = [c for c in PALETTE if c not in {AGENT_COLOURS[a] for a in present if a in AGENT_COLOURS}]
    own, out = {}, {}
    for agent in dict.fromkeys(agent_of.values()):  # agents in display order
        if agent in AGENT_COLOURS:
            own[agent] = (AGENT_COLOURS[agent], dashes(agent))
        elif free:
            own[agent] = (free.pop(0), dashes(agent))
    for series, agent in agent_of.items():
        if agent in own and own[agent] not in out.values():
            out[series] = own[agent]
    for series in [s for s in agent_of if s not in out]:
        used = {colour for colour, _ in out.values()}
        fresh = [(c, dashes(agent_of[series])) for c in free + PALETTE if c not in used]
        again = [(c, d) for d in ROUND_DASHES for c in PALETTE]
        out[series] = next(look for look in fresh + again if look not in out.values())
    return {series: out[series] for series in agent_of}


def apply() -> None:
    plt.rcParams.update(RC)
