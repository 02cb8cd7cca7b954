"""Policy servers: openpi's websocket protocol both ways, with SEAL's reasoning extension.

- `protocol`: keys, metadata, the reasoning text, the privileged scene on the wire; checks;
- `client`: `OpenpiPolicy`, a `ReasoningPolicy` on any openpi-protocol server;
- `server`: `PolicyServer` / `seal serve`, any SEAL policy behind the same protocol;
- `planners`: sub-plans for servers that do not reason (annotations, a VLM).

See ``docs/serving.md``.
"""
