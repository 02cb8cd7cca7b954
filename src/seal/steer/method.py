"""One description of a steering method: `MethodSpec`.

`seal run`, `seal eval`, the benchmarks and the Ray backend all describe what they run with this
one dataclass: the loop's settings (`seal.steer.config.LoopSettings`: the method, K, rounds,
budgets, how verdicts are taken), the prediction physics' mismatch and the render model, and which
policy, verifier and scorer take part, each with its own options (`seal.options.Options`,
registered beside it in ``POLICIES`` / ``VERIFIERS`` / ``SCORERS``). `build_episode`
(`seal.steer.build`) turns it into a running episode.

It is built with today's flat keyword arguments (``MethodSpec(policy="vla:twin", knobs="clean",
value_ckpt=RUN)``): each option goes to the selected plug-in that declares it; an option of a
plug-in that is not selected is checked and ignored (the CLI passes every flag it was given), unless
the option is ``strict``. Reading ``spec.knobs`` reads the option where it lives.

Its canonical form (what changes results) is hashed to name the method in a results store. The
hash must stay what older stores hold, so the rule for a setting added later is: it enters the
canonical form only when it differs from its default (an old configuration, which could only
have the default, hashes as before). Connection details (host, port, URLs, timeouts, transport)
never enter it: they say where a model runs, not what it is. A plug-in's checkpoint enters it as
the digest of its weights, so retraining in place is a new method.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from seal.errors import InvalidInput
from seal.options import Options, cli_type, default_of, has_legacy, hashed, meta, one_of, option
from seal.policies import POLICIES
from seal.registry import Registry
from seal.steer.config import METHODS, LoopSettings, SteerConfig
from seal.steer.scoring import SCORERS
from seal.verify import VERIFIERS

RENDERS = ("stock", "fast")

# The order of keys in the canonical forms stores and labels already hold (the fields of the flat
# MethodSpec that wrote them); keys of plug-ins added since follow, in their own order.
_STORED_ORDER = ("method", "k", "rounds", "verifier", "model", "false_positive", "false_negative", "policy", "knobs",
                 "mode", "render", "value_ckpt", "value_goal", "mismatch", "check_every", "subplan_budget", "planner",
                 "annotations", "planner_model", "prompt", "policy_ckpt", "pick", "verify_order", "done_check")


def parse_mismatch(text: str) -> tuple[float, float, float] | None:
    """``"1.3,0.8,1.2"`` (or with ``/`` inside a ``--methods`` item) -> (friction, mass, damping)."""
    if text is None or not str(text).strip():
        return None
    parts = [p.strip() for p in str(text).replace("/", ",").split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise InvalidInput(f"--mismatch wants three numbers friction,mass,damping (e.g. 1.3,0.8,1.2); "
                           f"got {text!r}") from None
    if len(values) != 3:
        raise InvalidInput(f"--mismatch wants three numbers friction,mass,damping (e.g. 1.3,0.8,1.2); got {text!r}")
    return values


# The plug-in slots of a method: which registry, the field naming the plug-in, the field holding its options.
_SLOTS: tuple[tuple[str, Registry, str], ...] = (("policy", POLICIES, "policy_options"),
                                                  ("verifier", VERIFIERS, "verifier_options"),
                                                  ("scorer", SCORERS, "scorer_options"))


@dataclass(frozen=True, init=False)
class MethodSpec(LoopSettings):
    """A steering method and every setting that changes its results (plus where its models run)."""

    verifier: str = option("oracle", "who judges a candidate (seal)", flag=False)
    policy: str = option("scripted", "who acts", flag=False)
    scorer: str = option("value", "what ranks chunks (value)", later=True, flag=False)
    # None: the policy's own (a learned VLA: the model its demonstrations were recorded in; else stock)
    render: str | None = option(None, "render model: stock | fast (default: the policy's own, i.e. the one a learned "
                                      "VLA's demonstrations were recorded in, else stock)")
    mismatch: tuple[float, float, float] | None = option(
        None, "prediction physics scales 'friction,mass,damping', e.g. 1.3,0.8,1.2", parse=parse_mismatch, later=True)
    policy_options: Options = field(default=None, metadata={"hash": False, "flag": False})  # type: ignore[assignment]
    verifier_options: Options = field(default=None, metadata={"hash": False, "flag": False})  # type: ignore[assignment]
    scorer_options: Options = field(default=None, metadata={"hash": False, "flag": False})  # type: ignore[assignment]

    def __init__(self, method: str = "seal", *, policy_options: Options | None = None,
                 verifier_options: Options | None = None, scorer_options: Options | None = None, **settings: Any):
        own = {f.name: f for f in fields(MethodSpec) if not f.name.endswith("_options")}
        for name, f in own.items():
            object.__setattr__(self, name, settings.pop(name, default_of(f)))
        object.__setattr__(self, "method", method)
        given = {"policy_options": policy_options, "verifier_options": verifier_options,
                 "scorer_options": scorer_options}
        routed: set[str] = set()
        for slot, registry, holder in _SLOTS:
            name, path = _split_path(slot, getattr(self, slot), registry)
            object.__setattr__(self, slot, name)
            cls = registry.options(name)
            base = given[holder] if given[holder] is not None else cls()
            if not isinstance(base, cls):
                raise InvalidInput(f"{holder} for {slot} {name!r} must be a {cls.__name__}, got {type(base).__name__}")
            mine = {f.name: settings[f.name] for f in fields(cls) if f.name in settings}
            if path:
                ckpt = cls.checkpoint
                if ckpt in mine and mine[ckpt] not in (path, default_of(_field(cls, ckpt))):
                    raise InvalidInput(f"{slot} {name}:{path} names a checkpoint and {ckpt}={mine[ckpt]!r} another; "
                                       "give one")
                mine[ckpt] = path
            object.__setattr__(self, holder, replace(base, **mine) if mine else base)
            routed |= set(mine)
        _check_unrouted(self, {k: v for k, v in settings.items() if k not in routed})
        self.__post_init__()

    def __post_init__(self) -> None:
        super().__post_init__()  # the loop's own checks (method, k, rounds, budgets, choices)
        if self.render is None:
            object.__setattr__(self, "render", self.policy_options.preferred_render() or "stock")
        one_of("render", self.render, RENDERS)
        if self.mismatch is not None:
            object.__setattr__(self, "mismatch", tuple(self.mismatch))
            if len(self.mismatch) != 3:
                raise InvalidInput(f"mismatch needs three factors friction,mass,damping; got {self.mismatch!r}")
            self.physics()  # range checks
        for opts, used in self._plugins():
            if used:
                opts.check_in_use(self.method)

    def __getattr__(self, name: str):
        """Today's flat names (``spec.knobs``, ``spec.value_ckpt``) read the option where it lives: the
        selected plug-in's, else the default of the plug-in that declares it."""
        if name.startswith("_") or name.endswith("_options"):
            raise AttributeError(name)
        for _, registry, holder in _SLOTS:
            opts = self.__dict__.get(holder)
            if opts is not None and _field(type(opts), name) is not None:
                return getattr(opts, name)
        for _, registry, _ in _SLOTS:
            for plugin in registry.names:
                f = _field(registry.options(plugin), name)
                if f is not None:
                    return default_of(f)
        raise AttributeError(f"{type(self).__name__!r} has no setting {name!r}")

    def render_warning(self) -> str | None:
        """Why these pixels differ from the ones the policy learned from, or None when they do not."""
        return self.policy_options.render_warning(self.render)

    # ---- what the pieces get ------------------------------------------------------------------
    def steer_config(self, *, seed: int = 0, max_steps: int | None = None) -> SteerConfig:
        """The loop settings of `seal.steer.engine.Steerer` for one episode."""
        return SteerConfig(**{f.name: getattr(self, f.name) for f in fields(LoopSettings)}, seed=seed,
                           max_steps=max_steps)

    def physics(self):
        """The prediction worlds' `PhysicsMismatch`, or None for the true physics."""
        if self.mismatch is None:
            return None
        from seal.sim.world import PhysicsMismatch

        friction, mass, damping = self.mismatch
        return PhysicsMismatch(friction=friction, mass=mass, damping=damping)

    @property
    def verifies(self) -> bool:
        """Its candidates go to a verifier (asked of the method's selection object)."""
        return METHODS.factory(self.method).verifies

    @property
    def scores(self) -> bool:
        """It ranks chunks with a scorer (its checkpoint in ``scorer_options``)."""
        return METHODS.factory(self.method).scores

    @property
    def scorer_checkpoint(self) -> str | None:
        """The path of the scorer's weights (what `seal.steer.scoring.make_scorer` loads)."""
        opts = self.scorer_options
        return getattr(opts, opts.checkpoint) if opts.checkpoint else None

    def _plugins(self) -> list[tuple[Options, bool]]:
        """(options, whether this method uses the plug-in) for the policy, verifier and scorer."""
        return [(self.policy_options, True), (self.verifier_options, self.verifies), (self.scorer_options, self.scores)]

    # ---- identity --------------------------------------------------------------------------------
    def canonical(self) -> dict:
        """The settings that matter for this method (base ignores K and the verifier, ...)."""
        uses = METHODS.factory(self.method).uses
        own = [f.name for f in fields(MethodSpec) if not meta(f)["per_method"] or f.name in uses]
        parts = hashed(self, [n for n in own if n not in ("verifier", "policy", "scorer")])
        if self.verifies:
            parts |= {"verifier": self.verifier, **self.verifier_options.hashed()}
        parts |= {"policy": self.policy, **self.policy_options.hashed()}
        if self.scores:
            parts |= hashed(self, ["scorer"]) | self.scorer_options.hashed()
        d = {k: parts[k] for k in _STORED_ORDER if k in parts} | parts
        for opts, used in self._plugins():  # the weights, not the path, decide the results
            if used and opts.checkpoint:
                d[opts.checkpoint] = opts.digest()  # a checkpoint left at its default: after the rest, as stored
        return d

    @property
    def config_hash(self) -> str:
        return hashlib.sha1(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()[:10]

    @property
    def label(self) -> str:
        """Short column name for reports: the method, plus what differs from its defaults."""
        needed = {}
        if self.scores and self.scorer_options.checkpoint:  # a method that cannot exist without its weights
            needed = {"scorer": self.scorer, self.scorer_options.checkpoint: self.scorer_checkpoint}
        default = MethodSpec(method=self.method, **needed).canonical()
        mine = self.canonical()
        extra = [f"{k}={_show(v)}" for k, v in mine.items() if k != "method" and default.get(k) != v]
        extra += [f"{k}={legacy}" for k, legacy in self._legacy().items() if k in default and k not in mine]
        if needed:  # which weights, by their run directory's name (none given: the shipped one's)
            extra.insert(0, f"ckpt={Path(self.scorer_checkpoint).name or self.scorer_options.weights()[1].name}")
        return self.method + (f"[{','.join(extra)}]" if extra else "")

    def _legacy(self) -> dict:
        """Settings whose value every earlier result ran with (named in a label when in force)."""
        out = {f.name: meta(f)["legacy"] for f in fields(self) if has_legacy(f)}
        for opts, _ in self._plugins():
            out |= {f.name: meta(f)["legacy"] for f in fields(opts) if has_legacy(f)}
        return out


def _field(cls, name: str):
    return next((f for f in fields(cls) if f.name == name), None)


def _split_path(slot: str, name: str, registry: Registry) -> tuple[str, str]:
    """``"vla:PATH"`` -> ("vla", "PATH") for a plug-in whose options name a checkpoint."""
    base, sep, path = name.partition(":")
    if not sep:
        return name, ""
    registry.options(base)  # an unknown name says so, with the valid ones
    takes = [n for n in registry.names if registry.options(n).checkpoint]
    if not registry.options(base).checkpoint:
        raise InvalidInput(f"{slot} {name!r}: only {', '.join(takes)} takes a path ({takes[0]}:PATH)" if takes
                           else f"{slot} {name!r}: no {slot} takes a path")
    return base, path


def _check_unrouted(spec: MethodSpec, settings: dict) -> None:
    """Options of plug-ins that are not selected: each is checked by a plug-in that declares it and
    then ignored (the CLI passes every flag given), unless it is ``strict``."""
    for name, value in settings.items():
        owners = [(slot, plugin, registry.options(plugin)) for slot, registry, _ in _SLOTS
                  for plugin in registry.names if _field(registry.options(plugin), name) is not None]
        if not owners:
            raise TypeError(f"MethodSpec() got an unexpected keyword argument {name!r}")
        slot, plugin, cls = owners[0]
        cls(**{name: value})  # a bad value is an error even where it is ignored
        f = _field(cls, name)
        if meta(f)["strict"] and value != default_of(f):
            raise InvalidInput(f"{name} is for the {plugin} {slot}, not {getattr(spec, slot)!r}")


def _show(value) -> str:
    return "/".join(str(v) for v in value) if isinstance(value, list) else str(value)


# ---- every setting by name (the CLI's flags, `--methods` items) ----------------------------------
@dataclass(frozen=True)
class Setting:
    """One setting a method can be given by name: a loop setting, a plug-in selector or a plug-in's option."""

    name: str
    default: Any
    help: str
    type: Any  # the CLI's argparse type
    parse: Any  # text -> value in a --methods item (None: by the default's type)
    flag: bool

    @property
    def option(self) -> str:
        return "--" + self.name.replace("_", "-")


def settings() -> list[Setting]:
    """Every setting of a method: the loop's and MethodSpec's own, the plug-in selectors (their help
    lists what is registered), then each registered plug-in's options (an option several plug-ins
    declare appears once). Read when asked, so a plug-in registered later is included."""
    out: dict[str, Setting] = {}

    def add(f, help_text: str | None = None, flag: bool | None = None) -> None:
        m = meta(f)
        if f.name in out:
            return
        default = default_of(f)
        help_text = help_text or _with_default(m["help"], default, m["choices"])
        kind = m["type"] or (cli_type(m["parse"]) if m["parse"] else _type_of(default))
        out[f.name] = Setting(f.name, default, help_text, kind, m["parse"], m["flag"] if flag is None else flag)

    selectors = {slot: registry for slot, registry, _ in _SLOTS}
    for f in fields(MethodSpec):
        if f.name.endswith("_options"):
            continue
        if f.name in selectors:
            add(f, _selector_help(f.name, selectors[f.name], default_of(f)), flag=True)
        else:
            add(f)
    for _, registry, _ in _SLOTS:
        for plugin in registry.names:
            for f in fields(registry.options(plugin)):
                add(f)
    return list(out.values())


def _selector_help(slot: str, registry: Registry, default: str) -> str:
    parts = []
    for name in registry.names:
        plugin = registry.plugin(name)
        shown = name + ("[:PATH]" if plugin.options.checkpoint else "") + (" (default)" if name == default else "")
        parts.append(f"{shown}: {plugin.summary}" if plugin.summary else shown)
    return " | ".join(parts)


def _with_default(help_text: str, default, choices) -> str:
    if choices is not None and "|" not in help_text:
        help_text += f" ({' | '.join(c for c in choices if c)})"
    if default is None or default == "":
        return help_text
    return f"{help_text} (default {default})"


def _type_of(default):
    return type(default) if isinstance(default, (int, float)) and not isinstance(default, bool) else str


# ---- text -> spec (the CLI's flags and `seal eval --methods`) ------------------------------------
def convert(key: str, value: str):
    """One ``name=value`` setting of a method, from text to the setting's type."""
    setting = next(s for s in settings() if s.name == key)
    if setting.parse is not None:
        return setting.parse(value)
    current = setting.default
    if isinstance(current, bool):
        flag = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}.get(value.lower())
        if flag is None:  # a typo must not silently read as False
            raise InvalidInput(f"method option {key}={value!r} must be true or false (also 1/0, yes/no)")
        return flag
    kinds = ((int, "an integer"), (float, "a number"))
    for kind, what in kinds:
        if isinstance(current, kind):
            try:
                return kind(value)
            except ValueError:
                raise InvalidInput(f"method option {key}={value!r} must be {what} "
                                   f"(its default: {key}={current})") from None
    return value


def parse_methods(text: str, **defaults) -> list[MethodSpec]:
    """``"base,seal,seal:k=5:rounds=1"`` -> MethodSpecs; ``defaults`` are the CLI's shared flags
    (None: not given). Inside an item, a mismatch is written with slashes: ``seal:mismatch=1.3/0.8/1.2``."""
    names = [s.name for s in settings() if s.name != "method"]
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        method, *overrides = item.split(":")
        given = {k: v for k, v in defaults.items() if v is not None}
        for ov in overrides:
            key, sep, value = ov.partition("=")
            if not sep or key not in names:
                raise InvalidInput(f"bad method option {ov!r} in {item!r}; write name=value with name in "
                                   f"{', '.join(names)}")
            given[key] = convert(key, value)
        out.append(MethodSpec(method=method, **given))  # validated once, with every option in place
    if not out:
        raise InvalidInput(f"no methods given; valid: {', '.join(METHODS.names)}")
    hashes = [m.config_hash for m in out]
    if len(set(hashes)) != len(hashes):
        raise InvalidInput(f"the same method configuration is listed twice in {text!r}")
    return out
