"""Every metric the report reads, once: its MLflow key, label, unit, and the figure panel and table it goes to.

Producers log under these keys (``evaluate`` the evaluation fields, SB3 / the JAX learner ``rollout/*`` and
``train/*``, ``sweep.plasticity`` ``plasticity/*``, RECOM ``recom/*``); ``sweep.report`` reads the keys, draws
the panels and fills the tables from this module only, so a panel cannot name a key the loader does not fetch.

* ``EVAL_FIELDS``: one evaluation (``evaluate``), logged under the prefix of the policy scored (``POLICIES``):
  the final policy under ``eval/*`` (also every ``eval.every_timesteps`` during training), the best ones kept
  while training (``sweep.best_policy``) under ``eval_best/*`` and ``eval_best_eval/*`` with ``SOURCE_FIELDS``.
* ``CURVES``: training histories (step = timesteps), each a panel of a figure file ``<figure>_<wind>``, in
  panel order; ``final`` names the per-run column of its final value (mean over the last 10% of training) that
  the summary table shows under ``title``. A hook may declare more beside its class (``Hook.curves``), which the
  report adds for the runs that ran it (``register``).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EvalField:
    """One number of the evaluation protocol: ``name`` under a policy's prefix; shown as value x ``scale``."""
    name: str
    title: str
    unit: str
    scale: float = 1.0
    digits: int = 2
    table3: bool = False   # a column of Table III (final and best policy side by side)


EVAL_FIELDS = (
    EvalField("success_rate", "Success", "(%)", 100.0, 0, table3=True),
    EvalField("mse_x", "MSE x", "(m²)", table3=True),
    EvalField("mse_y", "MSE y", "(m²)", table3=True),
    EvalField("mse_z", "MSE z", "(m²)", table3=True),
    EvalField("final_distance", "Final distance", "(m)"),
    EvalField("return", "Return", ""),
    EvalField("crash_rate", "Crashes", "(%)", 100.0, 0),
)
TABLE3 = tuple(f for f in EVAL_FIELDS if f.table3)
# the timestep a kept policy was taken at and its score there (logged with its evaluation)
SOURCE_FIELDS = ("source_step", "source_score")

# The policies a run scores at its final step (eval.policy final|best|both) -> their metric prefix. "best" is
# the paper's "policy that produced the highest reward" (highest rollout/ep_rew_mean), "best_eval" the one at
# the highest in-training eval return. Stores logged before eval.policy existed have eval/* only.
POLICIES = {"final": "eval", "best": "eval_best", "best_eval": "eval_best_eval"}
# sweep.best_policy's readings -> the policy they keep
KEPT = {"reward": "best", "eval": "best_eval"}


def eval_key(policy: str, field: str) -> str:
    """The MLflow key of ``field`` (an EVAL_FIELDS or SOURCE_FIELDS name) for ``policy`` (a POLICIES key)."""
    return f"{POLICIES[policy]}/{field}"


EVAL_KEYS = ([eval_key("final", f.name) for f in EVAL_FIELDS]
             + [eval_key(p, f) for p in ("best", "best_eval") for f in [x.name for x in EVAL_FIELDS] + list(SOURCE_FIELDS)])


@dataclass(frozen=True)
class Curve:
    """One training history: ``key`` (step = timesteps) drawn times ``scale`` as a panel of figure ``figure``
    (None: loaded, not drawn). ``always``: every run logs it (the report says which runs lack it). ``percent``:
    y from just below 0 (at least to 1, so an all-zero curve is not centred on 0; a panel where every value is 0
    says so); ``ylim``: fixed y limits instead. ``sparse``: logged at few steps (evaluations), drawn on its
    logged steps with a marker at each; its figure is written only if some run logged it at >= 2 steps.
    ``ylabel`` and ``note`` (what the panel's reading is, below the figure's legend) may name the thresholds
    of the runs drawn: ``{dormant_tau}``, ``{saturation}``, ``{dead_fraction}``, ``{signed_mean_tau}``.
    ``final``/``title``/``digits``: the per-run column of its final value and how the summary shows it."""
    key: str
    ylabel: str = ""
    figure: str | None = None
    scale: float = 1.0
    logy: bool = False
    percent: bool = False
    ylim: tuple[float, float] | None = None
    sparse: bool = False
    note: str = ""
    always: bool = False
    final: str | None = None
    title: str = ""
    digits: int = 2


REWARD = "rollout/ep_rew_mean"
EVAL_SUCCESS = eval_key("final", "success_rate")   # also logged during training (eval.every_timesteps)
EVAL_DISTANCE = eval_key("final", "final_distance")   # likewise: the mean over the flights of the distance at the end
AT_BOUND = "recom/at_bound"
PROBE, PROBE_FRESH = "plasticity/probe_loss", "plasticity/probe_loss_fresh"

CURVES = [
    Curve(REWARD, "Mean episode reward", "reward", always=True, final="final_reward", title="Final reward",
          digits=1),
    Curve("rollout/ep_len_mean", "Mean episode length (steps)", "episode_length", always=True),
    # the policy network's readings a tanh network can show (issue 18), each a share of its hidden units pooled
    # over the layers (saturated: of its activations); older stores have the first and the last only
    Curve("plasticity/dormant_ratio", "Sokar dormant,\nτ = {dormant_tau} (%)", "dormant", 100.0, percent=True,
          note="Sokar dormant: units with E|h| ≤ τ × the layer's mean E|h|.", always=True,
          final="final_dormant_ratio", title="Final dormant (%)"),
    Curve("plasticity/dormant_ratio_tau0.1", "Sokar dormant,\nτ = 0.1 (%)", "dormant", 100.0, percent=True),
    Curve("plasticity/dead_tanh_ratio", "Dead tanh\nunits (%)", "dormant", 100.0, percent=True,
          note="Dead tanh: units with |h| > {saturation} on ≥ {dead_fraction} of the batch (stuck at ±1).",
          final="final_dead_tanh_ratio", title="Final dead tanh (%)"),
    Curve("plasticity/signed_mean_ratio", "Signed mean\n≈ 0 (%)", "dormant", 100.0, percent=True,
          note="Signed mean ≈ 0: units with |E h| ≤ {signed_mean_tau} × the layer's mean E|h| "
               "(a unit swinging between ±1 counts: not an idle unit).",
          final="final_signed_mean_ratio", title="Final signed-mean≈0 (%)"),
    Curve("plasticity/saturated_ratio", "Saturated\nactivations (%)", "dormant", 100.0, percent=True,
          note="Saturated: activations with |h| > {saturation} (for tanh, 100 − Plasticine's active share).",
          always=True, final="final_saturated_ratio", title="Final saturated (%)"),
    Curve("plasticity/active_ratio"),
    Curve("plasticity/weight_norm", "Weight norm, policy + value nets", "weight_norm", always=True,
          final="final_weight_norm", title="Final weight norm", digits=1),
    Curve("train/learning_rate", "Learning rate", "learning_rate", logy=True, always=True),
    Curve(EVAL_SUCCESS, "Evaluation success (%)", "eval_success", 100.0, ylim=(-3, 103), sparse=True),
    Curve(eval_key("final", "crash_rate"), "Evaluation crashes (%)", "eval_crash", 100.0, ylim=(-3, 103), sparse=True),
    Curve(EVAL_DISTANCE, "Evaluation final\ndistance (m)", "eval_distance", logy=True, sparse=True,
          note="Final distance: the mean over the evaluation's flights of the distance to the target at the end "
               "(a crash keeps its exit point)."),
    # PPO's own health: how far each update moves a policy whose exploration noise shrinks
    Curve("train/std", "Policy std\n(action units)", "ppo_update", logy=True,
          final="final_policy_std", title="Final policy std", digits=3),
    Curve("train/approx_kl", "Approx. KL\nper update", "ppo_update", logy=True,
          final="final_approx_kl", title="Final approx KL", digits=3),
    Curve("train/clip_fraction", "Clip fraction (%)", "ppo_update", 100.0, percent=True),
    # the plasticity probe (Lyle et al. 2022): a copy of the policy net fitted to random targets at every wind
    # change and at the end; a net that has lost plasticity fits worse (higher loss)
    Curve(PROBE, "Probe loss\n(after N steps)", "probe", logy=True, sparse=True,
          note="Probe: a copy of the policy net fitted for plasticity.probe.steps Adam steps to fixed random targets "
               "on recent observations, at every wind change and at the end; higher = fits worse.",
          final="final_probe_loss", title="Final probe loss", digits=4),
    Curve("plasticity/probe_loss_early", "Probe loss\n(after N/10 steps)", "probe", logy=True, sparse=True),
    Curve(PROBE_FRESH, "Probe loss,\nfresh network", "probe", logy=True, sparse=True,
          note="Fresh network: the same fit from a newly drawn network on the same data (the reference).",
          final="final_probe_loss_fresh", title="Final probe loss, fresh net", digits=4),
    Curve(AT_BOUND),   # RECOM: 1 where an LR update was clipped to a bound (the summary's share)
]

# figure file stem -> its panels, top to bottom (the first panel's metric decides whether the figure is drawn)
FIGURES: dict[str, list[Curve]] = {}
for _curve in CURVES:
    if _curve.figure:
        FIGURES.setdefault(_curve.figure, []).append(_curve)
CURVE_KEYS = [c.key for c in CURVES if c.always]
OPTIONAL_KEYS = [c.key for c in CURVES if not c.always]
FINALS = {c.final: c.key for c in CURVES if c.final}   # per-run column -> the curve whose final value it holds


def register(curves) -> list[Curve]:
    """Add the curves a hook declares beside itself (``Hook.curves``: a diagnostic's or a remedy's own readings) to
    the ones above, each key once, so the report loads, draws and tabulates them like these; returns the new ones.
    The report calls it with the hooks of the runs it reads (``sweep.report.load.hook_curves``)."""
    new = []
    for c in curves:
        if c.key in {k.key for k in CURVES}:
            continue
        new.append(c)
        CURVES.append(c)
        if c.figure:
            FIGURES.setdefault(c.figure, []).append(c)
        (CURVE_KEYS if c.always else OPTIONAL_KEYS).append(c.key)
        if c.final:
            FINALS[c.final] = c.key
    return new


# ---- run tags the report and the re-evaluation split runs by ------------------------------------------------------
TAG_DEFAULTS = {"vehicle": "nominal"}  # runs logged before the tag existed flew RotorPy's vehicle


def condition_arm(tags: dict[str, str]) -> str:
    """The conditions a run trained under, as one name: its wind, ``+<vehicle>`` where the vehicle is not nominal
    (``paper``, ``none+payload``): what the report's panels and the re-evaluation's rows are split by."""
    vehicle = tags.get("vehicle", TAG_DEFAULTS["vehicle"])
    return tags.get("wind", "?") + ("" if vehicle == "nominal" else f"+{vehicle}")
