"""Who acts: the `ReasoningPolicy` protocol (`base.py`) and the registry of policies.

``make_policy(name, spec, task, seed=...)`` builds one from a `seal.steer.method.MethodSpec`:
``scripted`` (the scripted expert, `expert/`), ``remote`` (an openpi-protocol server,
`seal.serving.client`) or ``vla`` (a learned VLA checkpoint, `vla/`; ``vla:PATH`` names one). A learned policy registers a factory ``(spec, task, seed) -> policy``
with ``POLICIES.register(name, "module:factory")``.
"""

from __future__ import annotations

from seal.registry import Registry

POLICIES = Registry("policy", {
    "scripted": "seal.policies.expert.policy:scripted_policy",
    "remote": "seal.serving.client:remote_policy",
    "vla": "seal.policies.vla.policy:vla_policy",  # a learned VLA checkpoint: vla, vla:twin, vla:PATH
})


def make_policy(name: str, spec, task, *, seed: int = 0):
    """A `ReasoningPolicy` for one task; close it with ``policy.close()`` when done."""
    return POLICIES.make(name, spec, task, seed=seed)
