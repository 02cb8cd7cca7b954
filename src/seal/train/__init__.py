"""Training: datasets -> checkpoints.

- `transitions`: recorded demonstrations -> chunk-level offline-RL transitions (task and
  sub-plan goals, sparse rewards from success and the recorded critical frames);
- `vgps`: the V-GPS baseline's value function (`seal.value`: the network, its checkpoint and the
  `ChunkScorer` the steering engine's ``value`` method ranks sampled chunks with), trained by IQL
  in one file;
- `vla`: `seal train vla`, the learned reasoning VLA (`seal.policies.vla`) from annotated
  demonstrations.

PyTorch is an optional extra (``pip install -e '.[train]'``); besides this package only
`seal.value.vgps` and `seal.policies.vla` import it.
"""
