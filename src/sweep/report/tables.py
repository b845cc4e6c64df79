"""Table III (evaluation under wind) and the per-condition summary, as Markdown / LaTeX / CSV."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from sweep.report import stats
from sweep.report.style import label

TABLE3 = [("eval/success_rate", "success_rate", 100.0, "Success rate (%)"),
          ("eval/mse_x", "mse_x", 1.0, "MSE x (m²)"),
          ("eval/mse_y", "mse_y", 1.0, "MSE y (m²)"),
          ("eval/mse_z", "mse_z", 1.0, "MSE z (m²)")]


def _pm(mean: float, half: float, digits: int) -> str:
    if not np.isfinite(mean):
        return "–"
    return f"{mean:.{digits}f}" + (f" ± {half:.{digits}f}" if np.isfinite(half) else "")


def _interval(point: float, lo: float, hi: float, digits: int) -> str:
    if not np.isfinite(point):
        return "–"
    return f"{point:.{digits}f}" + (f" [{lo:.{digits}f}, {hi:.{digits}f}]" if np.isfinite(lo) else "")


def markdown(df: pd.DataFrame) -> str:
    cells = [[str(c) for c in df.columns]] + [[str(v) for v in row] for row in df.itertuples(index=False)]
    lines = ["| " + " | ".join(r) + " |" for r in cells]
    lines.insert(1, "|" + "|".join("---" for _ in df.columns) + "|")
    return "\n".join(lines) + "\n"


def latex(df: pd.DataFrame, caption: str, label_: str) -> str:
    body = df.map(lambda v: str(v).replace("%", r"\%").replace("_", r"\_").replace("±", r"$\pm$")
                  .replace("m²", r"m$^2$"))
    body.columns = [str(c).replace("%", r"\%").replace("m²", r"m$^2$") for c in df.columns]
    return body.to_latex(index=False, column_format="l" * 2 + "c" * (len(df.columns) - 2),
                         caption=caption, label=label_, position="htbp")


def table3(runs: pd.DataFrame, agents: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(numbers: one row per agent x wind with mean / ci95 / n per metric, display table)."""
    numbers, display = [], []
    for (wind, agent), g in runs.groupby(["wind", "agent"], sort=False):
        num = {"agent": agent, "wind": wind, "n_seeds": len(g)}
        shown = {"Control policy": label(agent), "Training wind": wind}
        for key, short, scale, title in TABLE3:
            mean, half, _ = stats.mean_t_ci(g[key] * scale)
            num[f"{short}_mean"], num[f"{short}_ci95"] = mean, half
            shown[title] = _pm(mean, half, 0 if short == "success_rate" else 2)
        shown["Seeds"] = len(g)
        numbers.append(num)
        display.append(shown)
    order = {a: i for i, a in enumerate(agents)}
    key = lambda d: (d["wind"] != "paper", d["wind"], order.get(d["agent"], 99))  # noqa: E731
    idx = sorted(range(len(numbers)), key=lambda i: key(numbers[i]))
    return pd.DataFrame([numbers[i] for i in idx]), pd.DataFrame([display[i] for i in idx])


def summary(runs: pd.DataFrame, per_run: pd.DataFrame, agents: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per agent x wind: final reward, final dormant ratio, collapse, seeds, IQM [CI], P(improve over ppo) [CI]."""
    df = runs.merge(per_run, on="run_id", how="left")
    numbers, display = [], []
    for wind in sorted(df["wind"].unique(), key=lambda w: (w != "paper", w)):
        dw = df[df["wind"] == wind]
        base = dw.loc[dw["agent"] == "ppo", "final_reward"].to_numpy()
        for agent in [a for a in agents if a in set(dw["agent"])]:
            g = dw[dw["agent"] == agent]
            iqm, iqm_lo, iqm_hi = stats.iqm_ci(g["final_reward"])
            poi = stats.poi_ci(g["final_reward"], base) if agent != "ppo" and len(base) else (np.nan,) * 3
            num = {"agent": agent, "wind": wind, "n_seeds": len(g),
                   "final_reward": g["final_reward"].mean(), "final_dormant_ratio": g["final_dormant"].mean(),
                   "collapse": g["collapse"].mean(), "iqm_final_reward": iqm, "iqm_ci_low": iqm_lo,
                   "iqm_ci_high": iqm_hi, "p_improve_over_ppo": poi[0], "p_improve_ci_low": poi[1],
                   "p_improve_ci_high": poi[2]}
            numbers.append(num)
            display.append({"Agent": label(agent), "Wind": wind, "Seeds": len(g),
                            "Final reward": f"{num['final_reward']:.1f}",
                            "Final dormant (%)": f"{100 * num['final_dormant_ratio']:.2f}",
                            "Collapse": f"{num['collapse']:.1f}",
                            "IQM final reward [95% CI]": _interval(iqm, iqm_lo, iqm_hi, 1),
                            "P(> PPO) [95% CI]": _interval(*poi, 2)})
    return pd.DataFrame(numbers), pd.DataFrame(display)


def write_tables(runs: pd.DataFrame, per_run: pd.DataFrame, agents: list[str], out: Path) -> list[Path]:
    t3_numbers, t3_display = table3(runs, agents)
    t3_numbers.to_csv(out / "table3.csv", index=False)
    (out / "table3.md").write_text(
        "Evaluation under constant wind (Table III): mean ± 95% Student-t CI over seeds.\n\n" + markdown(t3_display))
    (out / "table3.tex").write_text(latex(t3_display, "Evaluation under wind: success rate and per-axis position "
                                          "MSE, mean $\\pm$ 95\\% CI over seeds.", "tab:eval"))
    s_numbers, s_display = summary(runs, per_run, agents)
    s_numbers.to_csv(out / "summary.csv", index=False)
    note = (f"Final = mean over the last {stats.FINAL_FRACTION:.0%} of training timesteps; collapse = largest drop "
            "of the reward curve below its running peak (mean over seeds); IQM with 95% stratified-bootstrap CI "
            "(rliable); P(> PPO) = rliable probability of improvement of the final reward over PPO "
            "in the same wind condition.\n\n")
    (out / "summary.md").write_text(note + markdown(s_display))
    return [out / f for f in ("table3.csv", "table3.md", "table3.tex", "summary.csv", "summary.md")]
