"""Training and checkpoint loading: nerfstudio's trainer with checkpoints that survive a kill."""
