"""``Cadence``: "every K timesteps, at the first rollout end that reaches the next multiple of K"."""
from __future__ import annotations


class Cadence:
    """Due at the first check with ``timesteps >= next_at``; then ``next_at`` moves past ``timesteps`` by whole
    periods (a rollout longer than K still acts once). Its owner checkpoints ``next_at``."""

    def __init__(self, every: int) -> None:
        self.every = self.next_at = int(every)

    def due(self, timesteps: int) -> bool:
        if timesteps < self.next_at:
            return False
        while self.next_at <= timesteps:
            self.next_at += self.every
        return True
