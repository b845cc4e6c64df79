"""Building the PPO agent and its remedies from the ``agent`` config group."""
from sweep.agents.ppo import build_ppo, build_remedies

__all__ = ["build_ppo", "build_remedies"]
