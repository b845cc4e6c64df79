"""One look for every figure: agent order, colours and line styles (the same in every figure and every report),
column-width fonts.

Colours. Each agent of the published figures has its own colour, fixed by name (AGENT_COLOURS; never change
them). Thirteen are Okabe-Ito's and Paul Tol's colour-blind-safe sets; the fourteenth was searched for on an sRGB
grid, at mid lightness, as far as possible from them and from GREY. Any two differ by at least MIN_DELTA_E (CIE76
ΔE in CIELAB, ``delta_e``) for normal vision and as simulated for deuteranopia and protanopia (Machado et al. 2009,
VISIONS). Any other agent (a new YAML in conf/agent/ needs no edit here) takes a colour derived from its name:
DERIVED[hash of the name] (``agent_colour``), the same in every report. DERIVED are 23 colours of an sRGB grid
(L* 25-75, chroma >= 25) at least DERIVED_MIN_DELTA_E from every named colour, from GREY and from each other in all
three visions (a lower bound than MIN_DELTA_E: at 14 the gaps between the named colours hold only ~15 such
colours). Two new agents of one report whose names hash to the same colour are told apart: in name order, the
second steps to the next DERIVED colour no agent of the report has (``agent_colours``); with more new agents than
DERIVED colours, ``looks`` falls back to free named colours and ROUND_DASHES. Agents a figure does not highlight
are drawn thin in GREY (``figures``). An agent's fresh twin (``<agent>_fresh``, twin=fresh) takes its agent's colour
and TWIN_DASH, so it reads as the twin.
"""
from __future__ import annotations

import hashlib

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sweep.config import TWIN_SUFFIX  # noqa: E402  (twin=fresh logs its agent as <agent> + TWIN_SUFFIX)

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
# The colours of agents not in AGENT_COLOURS, picked by a hash of the name (in hue order; searched once: the largest
# set found by randomised greedy packing of the 16-level sRGB grid within the bounds below).
DERIVED = ["#994455", "#772233", "#DD2244", "#FF3344", "#CC0022", "#880000", "#FF9966", "#FF8844", "#005511",
           "#11CC66", "#66BBCC", "#55AAFF", "#2288DD", "#2288FF", "#0066EE", "#0044DD", "#4444AA", "#443377",
           "#1100CC", "#4422AA", "#886699", "#664477", "#885577"]
DERIVED_MIN_DELTA_E = 12.0  # a DERIVED colour's smallest ΔE to any named colour, GREY and every other DERIVED
# Colour-vision simulation (Machado, Oliveira & Fernandes 2009, severity 1), on linear sRGB.
VISIONS = {"normal": np.eye(3),
           "deuteranopia": np.array([[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413],
                                     [-0.011820, 0.042940, 0.968881]]),
           "protanopia": np.array([[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216],
                                   [-0.003882, -0.048116, 1.051998]])}
_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])  # linear sRGB -> XYZ
_WHITE = np.array([0.95047, 1.0, 1.08883])  # D65
# Line styles of the paper's agents, so that coinciding curves (e.g. RECOM before its first update) stay visible;
# every other agent is solid.
DASHES = {"ppo": "-", "l2": (0, (4, 1.5)), "recom_l2": (0, (1.2, 1.2))}
OTHER_DASH = "-"
# A fresh twin (twin=fresh: "<agent>_fresh") is drawn in its agent's colour with this dash-dot, unlike every DASHES.
TWIN_DASH = (0, (5, 1.5, 1, 1.5))
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


def twinned(agent: str) -> str | None:
    """The agent whose fresh twin ``agent`` is (``<agent>_fresh``, run with twin=fresh), else None. PPO's twin,
    reset_all, keeps its own colour and name."""
    return agent[:-len(TWIN_SUFFIX)] if agent.endswith(TWIN_SUFFIX) and agent not in AGENT_COLOURS else None


def dashes(agent: str):
    return TWIN_DASH if twinned(agent) else DASHES.get(agent, OTHER_DASH)


def arm_title(wind: str) -> str:
    """A panel's title for an arm (metrics.condition_arm): 'wind flip', 'wind none, vehicle payload'."""
    return "wind " + wind.replace("+", ", vehicle ")


def figure_width(panels: int) -> float:
    """One column for one panel, both columns for more."""
    return COLUMN_WIDTH if panels <= 1 else PAGE_WIDTH


def lab(colour: str, vision: str = "normal") -> np.ndarray:
    """CIELAB (D65) of the hex colour ``colour`` as seen with ``vision`` (a VISIONS key)."""
    srgb = np.array([int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5)])
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    x = _XYZ @ np.clip(VISIONS[vision] @ linear, 0, 1) / _WHITE
    f = np.where(x > 0.008856, np.cbrt(x), 7.787 * x + 16 / 116)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def delta_e(a: str, b: str) -> float:
    """The smallest CIE76 ΔE between two hex colours over VISIONS (normal vision, deuteranopia, protanopia)."""
    return float(min(np.linalg.norm(lab(a, v) - lab(b, v)) for v in VISIONS))


def _slot(agent: str) -> int:
    """The agent's DERIVED index, from a hash of its name (hashlib: the same in every process)."""
    return int.from_bytes(hashlib.sha256(agent.encode()).digest()[:8], "big") % len(DERIVED)


def agent_colour(agent: str) -> str:
    """The agent's own colour: AGENT_COLOURS, a fresh twin its agent's, else DERIVED picked by its name."""
    if twinned(agent):
        return agent_colour(twinned(agent))
    return AGENT_COLOURS.get(agent) or DERIVED[_slot(agent)]


def agent_colours(agents) -> dict[str, str]:
    """Each agent's colour in a report holding ``agents``: its own (``agent_colour``), except that of two agents not
    in AGENT_COLOURS with the same own colour the later by name takes the next DERIVED colour (cyclically) that no
    agent of the report has; once every DERIVED colour is taken, its own again (``looks`` then tells it apart)."""
    agents = list(dict.fromkeys(agents))
    out = {a: AGENT_COLOURS[a] for a in agents if a in AGENT_COLOURS}
    for agent in sorted(a for a in agents if a not in AGENT_COLOURS and not twinned(a)):
        k = _slot(agent)
        free = [c for c in DERIVED[k:] + DERIVED[:k] if c not in out.values()]
        out[agent] = free[0] if free else DERIVED[k]
    for twin in [a for a in agents if twinned(a)]:   # the colour its agent has in this report
        out[twin] = out.get(twinned(twin)) or agent_colour(twin)
    return {a: out[a] for a in agents}


def looks(agent_of: dict[str, str]) -> dict[str, tuple]:
    """(colour, line style) of each series (``agent_of``: series -> its agent, in display order; a series is an
    agent, or one of an agent's --by conditions drawn in the same panel). The report computes it once from all its
    series, so a series looks the same in every figure.

    An agent's first series takes the agent's own look (its colour in ``agent_colours`` of the report's agents
    and its dash). Each further series of the same agent takes the first look no series has yet: a named colour
    no agent of the report has, with the agent's dash, then each named colour with each of ROUND_DASHES. No two
    series look alike (up to 9 x 14 of them).
    """
    colour_of = agent_colours(agent_of.values())
    free = [c for c in PALETTE if c not in colour_of.values()]
    own = {agent: (c, dashes(agent)) for agent, c in colour_of.items()}
    out = {}
    for series, agent in agent_of.items():
        if own[agent] not in out.values():
            out[series] = own[agent]
    for series in [s for s in agent_of if s not in out]:
        used = {colour for colour, _ in out.values()}
        fresh = [(c, dashes(agent_of[series])) for c in free + PALETTE if c not in used]
        again = [(c, d) for d in ROUND_DASHES for c in PALETTE]
        out[series] = next(look for look in fresh + again if look not in out.values())
    return {series: out[series] for series in agent_of}


PAPER_FORMATS = ("png", "pdf")   # the figures' files: PNG at RC's 300 dpi to look at, PDF for the paper
DRAFT_FORMATS, DRAFT_DPI = ("png",), 100   # --draft: a quick look (about 3x faster to write)
formats = list(PAPER_FORMATS)   # what figures.save writes, as apply() last set it


def apply(draft: bool = False) -> None:
    """The report's matplotlib style; ``draft``: PNG only at DRAFT_DPI (``formats``)."""
    plt.rcParams.update(RC)
    if draft:
        plt.rcParams["savefig.dpi"] = DRAFT_DPI
    formats[:] = DRAFT_FORMATS if draft else PAPER_FORMATS
