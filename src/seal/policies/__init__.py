"""Who acts: the `ReasoningPolicy` protocol (`base.py`) and the registry of policies.

``make_policy(name, options, task, seed=...)`` builds one: ``scripted`` (the scripted expert,
`expert/`), ``remote`` (an openpi-protocol server, `seal.serving.client`) or ``vla`` (a learned
VLA checkpoint, `vla/`; ``vla:PATH`` names one). Each entry carries its options class
(`options.py`): its settings, flags, canonical form and checkpoint digest. A new policy is one
line, ``POLICIES.register(name, "module:factory", OptionsClass)``, with a factory
``(options, task, *, seed) -> ReasoningPolicy``.
"""

from __future__ import annotations

from seal.policies.options import RemoteOptions, ScriptedOptions, VLAOptions
from seal.registry import Plugin, Registry

POLICIES = Registry("policy", {
    "scripted": Plugin("seal.policies.expert.policy:scripted_policy", ScriptedOptions,
                       "the scripted expert (reads the scene's state; --knobs)"),
    "remote": Plugin("seal.serving.client:remote_policy", RemoteOptions,
                     "an openpi-protocol server at --host/--port (docs/serving.md)"),
    "vla": Plugin("seal.policies.vla.policy:vla_policy", VLAOptions,  # vla, vla:twin, vla:PATH
                  "a learned VLA checkpoint (vla: the shipped one, vla:twin its twin, vla:PATH)"),
})


def make_policy(name: str, options, task, *, seed: int = 0):
    """A `ReasoningPolicy` for one task; close it with ``policy.close()`` when done. ``options``:
    the policy's options, or anything that has them as attributes (a `MethodSpec`)."""
    return POLICIES.make(name, POLICIES.options_of(name, options), task, seed=seed)


def servable() -> tuple[str, ...]:
    """The policies `seal serve` can put behind a socket: all but clients of another policy server
    (their options say ``client``)."""
    return tuple(n for n in POLICIES.names if not getattr(POLICIES.options(n), "client", False))
