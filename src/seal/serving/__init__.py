"""Policy servers: openpi's websocket protocol both ways, with SEAL's reasoning extension.

- `protocol`: keys, metadata, the reasoning text, the privileged scene on the wire; checks
  (the reasoning text's grammar is `seal.policies.base`'s);
- `client`: `OpenpiPolicy`, a `ReasoningPolicy` on any openpi-protocol server;
- `server`: `PolicyServer` / `seal serve`, any SEAL policy behind the same protocol.

A server that does not reason gets its sub-plans from a planner (`seal.policies.planners`).

See ``docs/serving.md``.
"""
