"""Training: datasets -> checkpoints.

- `transitions`: recorded demonstrations -> chunk-level offline-RL transitions (task and
  sub-plan goals, sparse rewards from success and the recorded critical frames);
- `vgps`: the V-GPS baseline's value function, IQL in one file, and the `ChunkScorer` that the
  steering engine's ``value`` method ranks sampled chunks with;
- `vla`: `seal train vla`, the learned reasoning VLA (`seal.policies.vla`) from annotated
  demonstrations.

PyTorch is an optional extra (``pip install -e '.[train]'``); besides this package only
`seal.policies.vla` imports it.
"""
