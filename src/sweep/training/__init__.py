"""The training loop: one PPO update is its unit (``loop.train``), each update returns a typed record
(``records``), and everything that extends training is a hook built from config (``hooks``)."""
