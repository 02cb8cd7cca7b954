"""Method names a person would write, made from the configuration a results store keeps.

A store knows a method by its canonical settings (`MethodSpec.canonical`): the policy, how
candidates are chosen, every setting that changes results, checkpoints named by the digest of
their weights. `seal eval` labels it ``seal[policy=vla,render=fast,policy_ckpt=009dcdd7fb35]``;
a report reads better with "reasoning VLA + SEAL (oracle)". The rules:

- the policy first: "scripted expert", "reasoning VLA" and "twin" (the shipped VLA checkpoints,
  recognised by their weights' digest), "VLA checkpoint 1a2b3c" for any other VLA, "remote policy";
- then the steering method: nothing for base, "+ SEAL (<verifier>)", "+ V-GPS", "+ random pick";
- then, in one parenthesis, only what differs from the usual: K when it is not 10, the verifier's
  noise, rounds, pick rule, render model, physics mismatch and so on.

The unsteered twin reads "twin (pi0)": it stands where the paper's plain pi0 stands. Two
configurations can share a name (two V-GPS checkpoints, say); the report tells them apart with
the config hash (`seal.report.data`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

# MethodSpec's defaults for the settings named here (a test checks they agree). Kept as data so a
# report does not import the steering code and what it pulls in.
DEFAULTS = {"k": 10, "rounds": 2, "render": "stock", "mode": "sync", "knobs": "misaligned", "pick": "first",
            "verify_order": "slot", "check_every": 20, "subplan_budget": 200, "planner": "", "prompt": "task",
            "value_goal": "task", "false_positive": 0.0, "false_negative": 0.0}
SHIPPED_VLA_NAMES = {"reason": "reasoning VLA", "twin": "twin"}
STEERING_NAMES = {"seal": "SEAL", "value": "V-GPS", "random": "random pick"}
VERIFIER_NAMES = {"oracle": "oracle", "noisy": "noisy oracle", "learned": "learned verifier",
                  "openai": "OpenAI VLM", "gemini": "Gemini VLM"}
# `learned:expert`: trained on the scripted expert's rounds; `learned:vla_rounds`: fine-tuned on the first VLA's;
# `learned:dagger_rounds`: that one on the DAgger rounds 1-3 too; `learned:pad_labels`: on the round-2 VLA's SEAL
# rounds with picks labelled by the pad check. Those set aside since carry their label in their manifest.
EARLIER_VERIFIER_NAMES = {"expert": "expert rounds", "vla_rounds": "the first VLA's rounds",
                          "dagger_rounds": "the DAgger rounds", "pad_labels": "pad-check labels"}
# V-GPS Q-functions shipped beside the default (`seal.value.DEFAULT_SHIPPED`, which goes unnamed)
VALUE_NAMES = {"l10_demos": "Q from demonstrations only", "l10_twin_rollouts": "Q with the twin's rollouts"}
# Settings a name never shows: identities already in the policy's name, digests, or what the
# method name says.
_SILENT = {"method", "policy", "policy_ckpt", "value_ckpt"}


@dataclass(frozen=True)
class KnownVLA:
    """A VLA checkpoint a name can be given to: what to call it and the render it was trained in."""

    name: str
    render: str
    twin: bool = False  # a non-reasoning twin: it stands where the paper's plain pi0 stands


def shipped_vlas() -> dict[str, KnownVLA]:
    """Weights digest (as a store holds it) -> the shipped VLA checkpoint it is, read from the
    checkpoints' manifests (no hashing; a missing or unreadable manifest is skipped)."""
    from seal.checkpoint import MANIFEST
    from seal.policies.vla.locate import SHIPPED, WEIGHTS

    out = {}
    for key, path in SHIPPED.items():
        try:
            manifest = json.loads((path / MANIFEST).read_text())
        except (OSError, ValueError):
            continue
        digest = str((manifest.get("files", {}).get(WEIGHTS) or {}).get("sha256") or manifest.get("weights_sha256", ""))
        if digest:
            render = (manifest.get("render") or {}).get("mode", "stock")
            # a checkpoint kept when a retrained one replaced it carries its label in its manifest
            label = (manifest.get("shipped") or {}).get("label") if key not in SHIPPED_VLA_NAMES else None
            out[digest[:12]] = KnownVLA(label or SHIPPED_VLA_NAMES.get(key, key), render,
                                        twin=key == "twin" or key.startswith("twin_"))
    return out


def earlier_verifiers() -> dict[str, str]:
    """Weights digest -> name of the learned-verifier checkpoints shipped before the current one
    (`seal.verify.learned.SHIPPED`), so rows made with them do not read as the shipped verifier's."""
    from seal.checkpoint import MANIFEST
    from seal.errors import InvalidInput
    from seal.verify.learned import CHECKPOINT, SHIPPED

    out = {}
    for name, path in SHIPPED.items():
        try:
            digest = CHECKPOINT.digest(path)
            # set aside by `seal.verify.ship`: the label it was given then
            label = (json.loads((path / MANIFEST).read_text()).get("shipped") or {}).get("label")
        except (InvalidInput, OSError, ValueError):  # a damaged or missing copy: its rows keep the generic name
            continue
        out[digest] = f"learned verifier from {EARLIER_VERIFIER_NAMES.get(name) or label or name}"
    return out


def shipped_verifier() -> str | None:
    """Weights digest of the shipped learned verifier (`learned`), None if it is missing or damaged."""
    from seal.errors import InvalidInput
    from seal.verify.learned import CHECKPOINT, DEFAULT_CHECKPOINT

    try:
        return CHECKPOINT.digest(DEFAULT_CHECKPOINT)
    except (InvalidInput, OSError):
        return None


def shipped_values() -> dict[str, str]:
    """Weights digest -> shipped name of the package's V-GPS Q-functions, read from their manifests
    (no hashing; an unreadable manifest is skipped)."""
    from seal.checkpoint import MANIFEST
    from seal.value import shipped

    out = {}
    for name, path in shipped().items():
        try:
            digest = (json.loads((path / MANIFEST).read_text()).get("shipped") or {}).get("digest")
        except (OSError, ValueError):
            continue
        if digest:
            out[str(digest)] = name
    return out


def _value_phrase(config: dict) -> str | None:
    """A shipped Q-function other than the default, by name; the default and unknown runs go unnamed
    (two unknown ones are told apart by their config hash)."""
    from seal.value import DEFAULT_SHIPPED

    name = shipped_values().get(str(config.get("value_ckpt") or ""))
    if name is None or name == DEFAULT_SHIPPED:
        return None
    return VALUE_NAMES.get(name, f"Q-function {name}")


def display_name(config: dict, vlas: dict[str, KnownVLA] | None = None) -> str:
    """The name of a stored method configuration, e.g. "reasoning VLA + SEAL (oracle, K=4)".

    ``vlas``: VLA checkpoints to recognise by digest (default: the shipped ones)."""
    vlas = shipped_vlas() if vlas is None else vlas
    method = str(config.get("method", ""))
    policy = policy_name(config, vlas)
    notes = _steering_notes(config) + _setting_notes(config, vlas)
    if method == "base":
        head = policy
        if is_twin(config, vlas):
            notes.insert(0, "pi0")
    else:
        head = f"{policy} + {STEERING_NAMES.get(method, method)}"
    leftover = [f"{k}={_show(v)}" for k, v in sorted(config.items()) if k not in _SILENT and k not in _NAMED]
    notes += leftover  # a setting this module does not know yet still tells configurations apart
    return head + (f" ({', '.join(notes)})" if notes else "")


def is_twin(config: dict, vlas: dict[str, KnownVLA]) -> bool:
    """Whether a configuration's policy is a shipped twin (the current one or one kept by name)."""
    known = vlas.get(str(config.get("policy_ckpt", ""))) if config.get("policy") == "vla" else None
    return bool(known and known.twin)


def policy_name(config: dict, vlas: dict[str, KnownVLA]) -> str:
    """Who acts: "scripted expert", "reasoning VLA", "twin", "VLA checkpoint 1a2b3c", ..."""
    policy = str(config.get("policy", ""))
    if policy == "scripted":
        name = "clean scripted expert" if config.get("knobs") == "clean" else "scripted expert"
        # A stored configuration without "grip" ran before the expert read Held: it took an object carried on
        # a finger's body for dropped (`ScriptedExpert.grip`). Two experts, two names.
        return f"{name} (pad-contact grip)" if config.get("grip", "pads") == "pads" else name
    if policy == "vla":
        digest = str(config.get("policy_ckpt", ""))
        known = vlas.get(digest)
        return known.name if known else f"VLA checkpoint {digest[:6]}".rstrip()
    if policy == "remote":
        return "remote policy"
    return policy or "unknown policy"


def usual_render(config: dict, vlas: dict[str, KnownVLA]) -> str | None:
    """The render a policy runs with when none is asked for (None: not known for this checkpoint)."""
    if config.get("policy") == "vla":
        known = vlas.get(str(config.get("policy_ckpt", "")))
        return known.render if known else None
    return DEFAULTS["render"]


def _steering_notes(config: dict) -> list[str]:
    """What a steering method adds to its name: the verifier (always, for SEAL) and its settings."""
    method = config.get("method")
    if method == "base":
        return []
    notes = []
    if method == "seal":
        notes.append(_verifier_phrase(config))
        notes += [f"{label} {100 * float(config[key]):g}%" for key, label in
                  (("false_positive", "false passes"), ("false_negative", "false fails"))
                  if float(config.get(key, 0.0)) != DEFAULTS[key]]
    if config.get("threshold") is not None:
        notes.append(f"threshold {float(config['threshold']):g}")
    if "k" in config and int(config["k"]) != DEFAULTS["k"]:
        notes.append(f"K={config['k']}")
    if method == "seal":
        if int(config.get("rounds", DEFAULTS["rounds"])) != DEFAULTS["rounds"]:
            notes.append(f"{config['rounds']} rounds")
        if config.get("pick", DEFAULTS["pick"]) != DEFAULTS["pick"]:
            notes.append(f"{config['pick']} pick")
        if config.get("verify_order", DEFAULTS["verify_order"]) != DEFAULTS["verify_order"]:
            notes.append(f"verdicts by {config['verify_order']}")
        if int(config.get("check_every", DEFAULTS["check_every"])) != DEFAULTS["check_every"]:
            notes.append(f"check every {config['check_every']} steps")
        if config.get("done_check") == "trust":
            notes.append("policy's done trusted")
        # Stored before the rule existed: a repeated sub-plan text was placed by counting the done items
        # (`seal.policies.base.Reasoning.position`), which misjudges "it" after a garbled done list
        if config.get("subplan_ref", "count") == "count":
            notes.append("repeats by count")
        if config.get("miss_score", "zero") == "graded":  # the oracle ranks misses for the fallback
            notes.append("graded fallback")
    if method == "value" and (q := _value_phrase(config)):
        notes.append(q)
    if config.get("value_goal", DEFAULTS["value_goal"]) != DEFAULTS["value_goal"]:
        notes.append(f"{config['value_goal'].replace('subplan', 'sub-plan')} goal")
    return notes


def _verifier_phrase(config: dict) -> str:
    verifier = str(config.get("verifier", "oracle"))
    model = config.get("model")
    if verifier in ("openai", "gemini") and model:
        return str(model)
    if verifier == "learned" and model:
        earlier = earlier_verifiers().get(str(model))
        if earlier:
            return earlier
        if str(model) != shipped_verifier():  # a run that never shipped: not to be read as the shipped one
            return f"learned verifier {model}"
    name = VERIFIER_NAMES.get(verifier, verifier)
    # The oracle checks a pick with Held (`seal.verify.oracle`); a stored oracle configuration without
    # "grasp" ran before that check existed, with robosuite's pad check: say so.
    if verifier in ("oracle", "noisy") and config.get("grasp", "pads") == "pads":
        return f"{name}, pad-contact picks"
    return name


def _setting_notes(config: dict, vlas: dict[str, KnownVLA]) -> list[str]:
    """Settings of the episode itself (any method): render, replay, physics, budgets, planner."""
    notes = []
    render = config.get("render")
    if render and render != usual_render(config, vlas):
        notes.append(f"{render} render")
    if config.get("mode", DEFAULTS["mode"]) != DEFAULTS["mode"]:
        notes.append(str(config["mode"]))
    if config.get("mismatch"):
        notes.append("physics mismatch " + _show(config["mismatch"]))
    if int(config.get("subplan_budget", DEFAULTS["subplan_budget"])) != DEFAULTS["subplan_budget"]:
        notes.append(f"sub-plan budget {config['subplan_budget']}")
    if config.get("planner"):
        model = config.get("planner_model")
        notes.append(f"{config['planner']} planner" + (f" {model}" if model else ""))
    if config.get("prompt", DEFAULTS["prompt"]) != DEFAULTS["prompt"]:
        notes.append(f"{config['prompt'].replace('subplan', 'sub-plan')} prompt")
    if float(config.get("noise_scale", 1.0)) != 1.0:
        notes.append(f"flow noise x{float(config['noise_scale']):g}")
    return notes


# Settings the functions above put into words (or deliberately leave out).
_NAMED = {"knobs", "render", "mode", "mismatch", "subplan_budget", "planner", "planner_model", "annotations", "prompt",
          "k", "rounds", "verifier", "model", "false_positive", "false_negative", "pick", "verify_order",
          "check_every", "done_check", "value_goal", "threshold", "grasp", "grip", "noise_scale", "subplan_ref",
          "miss_score"}


def _show(value) -> str:
    if isinstance(value, list):  # a physics mismatch: friction/mass/damping
        return "/".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return str(value)
