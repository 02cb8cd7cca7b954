"""The wire format between SEAL and a policy server: openpi's, plus a small documented extension.

openpi's websocket protocol (``openpi_client.websocket_client_policy`` and openpi's
``WebsocketPolicyServer``): on connect the server sends one msgpack-numpy dict, its metadata;
after that every binary frame from the client is an observation dict and the server answers
with one dict holding ``actions``. A text frame from the server is an error message.

The LIBERO observation keys are openpi's (``observation/image``, ``observation/wrist_image``,
``observation/state``, ``prompt``). Everything SEAL adds is optional and only used when the
server's metadata advertises it under the ``"seal"`` key (see ``docs/serving.md``), so a plain
openpi server never sees a key it does not know:

- reply ``reasoning`` (the three-field text) and ``think`` (bool) beside ``actions``;
- request ``reasoning``: the sub-plan text to act on (absent: the policy reasons itself);
- request ``seal/batch`` = n: the request holds n observations stacked on a leading axis;
- request ``seal/session``, ``seal/row``/``seal/rows`` and ``seal/control`` (configure, reset,
  begin) for stateful policies; ``seal/scene`` for privileged (scripted) policies.

Every check here names the key, what was expected and what came.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from seal.errors import InvalidInput, SealError
from seal.policies.base import ACTION_HORIZON, PREDICT_HORIZON, Reasoning, parse_reasoning
from seal.sim.observation import IMAGE_SIZE, Observation
from seal.sim.scene import Articulation, Body, Box, SceneState, Site

PROTOCOL_VERSION = 1
ACTION_DIM = 7
STATE_DIM = 8

# openpi's LIBERO keys
IMAGE, WRIST, STATE, PROMPT = "observation/image", "observation/wrist_image", "observation/state", "prompt"
ACTIONS = "actions"
# the reasoning extension (request and reply)
REASONING, THINK = "reasoning", "think"
# SEAL's request keys
SESSION, ROW, ROWS, BATCH, SCENE, CONTROL = ("seal/session", "seal/row", "seal/rows", "seal/batch", "seal/scene",
                                            "seal/control")
CONTROLS = ("configure", "reset", "begin")
# the largest request a server reads: both cameras of every row at the larger of 224 and its image
# size, plus this much per row (state, prompt, reasoning, a privileged scene: ~7 KB) and per request
ROW_ALLOWANCE_BYTES = 1 << 20


class PolicyServerError(SealError, RuntimeError):
    """The policy server is unreachable, hung up, timed out, or answered something unusable."""


class ProtocolError(PolicyServerError):
    """A reply (or request) does not have the keys, types or shapes the protocol expects."""


# ---------------------------------------------------------------------------- metadata


@dataclass(frozen=True)
class ServerInfo:
    """What a server supports, read from its metadata. A plain openpi server has none of it."""

    reasoning: bool = False  # replies carry `reasoning` and `think`
    batch: bool = False  # accepts `seal/batch` requests
    max_batch: int = 1
    control: bool = False  # understands `seal/control` messages and sessions
    privileged: bool = False  # needs `seal/scene` (scripted policies only)
    images: bool = True  # needs the two camera images
    # the camera size the policy was trained at: requests may carry images at this size instead of
    # openpi's 224 (a client then renders its cameras at it); 224 images are always accepted
    image_size: int = IMAGE_SIZE
    version: int = 0  # 0: not a SEAL server
    # the largest request message the server reads (bytes; 0: not said). A larger one closes the
    # connection with code 1009, as websockets' size limit does.
    max_request_bytes: int = 0

    @classmethod
    def from_metadata(cls, metadata: Any) -> "ServerInfo":
        if not isinstance(metadata, dict):
            raise ProtocolError(f"server metadata must be a msgpack map, got {type(metadata).__name__}")
        seal = metadata.get("seal")
        if seal is None:
            return cls()
        if not isinstance(seal, dict):
            raise ProtocolError(f"metadata 'seal' must be a map, got {type(seal).__name__}")
        out = {}
        for f in fields(cls):
            if f.name in seal:
                value = seal[f.name]
                want = int if f.name in ("max_batch", "image_size", "version", "max_request_bytes") else bool
                if not isinstance(value, want) or (want is int and isinstance(value, bool)):
                    raise ProtocolError(f"metadata seal.{f.name} must be {want.__name__}, got {value!r}")
                out[f.name] = value
        info = cls(**out)
        if info.max_batch < 1:
            raise ProtocolError(f"metadata seal.max_batch must be >= 1, got {info.max_batch}")
        if not 16 <= info.image_size <= 1024:
            raise ProtocolError(f"metadata seal.image_size must be in 16..1024 px, got {info.image_size}")
        if info.max_request_bytes < 0:
            raise ProtocolError(f"metadata seal.max_request_bytes must be >= 0, got {info.max_request_bytes}")
        return info

    def to_metadata(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def request_limit(max_batch: int, image_size: int = IMAGE_SIZE) -> int:
    """The request size (bytes) a server with these settings reads at most (``max_request_bytes``):
    ``max_batch`` rows of two frames at the larger accepted size plus `ROW_ALLOWANCE_BYTES` each,
    and one allowance for the request itself."""
    side = max(IMAGE_SIZE, image_size)
    return ROW_ALLOWANCE_BYTES + max_batch * (2 * side * side * 3 + ROW_ALLOWANCE_BYTES)


# ---------------------------------------------------------------------------- reasoning text


def read_reasoning(text: Any) -> Reasoning:
    """A request's or reply's ``reasoning``: the three-field text `seal.policies.base.parse_reasoning`
    reads (the inverse of `Reasoning.text()`); one it cannot read is a `ProtocolError`."""
    try:
        return parse_reasoning(text)
    except InvalidInput as exc:
        raise ProtocolError(str(exc)) from None


# ---------------------------------------------------------------------------- privileged scene


def _arr(x: Any, what: str, shape: tuple | None = None) -> np.ndarray:
    """A writable float64 copy (msgpack-numpy hands out read-only views of the frame), finite."""
    try:
        a = np.array(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ProtocolError(f"seal/scene {what}: expected numbers, got {type(x).__name__}") from None
    if shape is not None and a.shape != shape:
        raise ProtocolError(f"seal/scene {what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ProtocolError(f"seal/scene {what}: contains NaN or Inf; expected finite numbers")
    return a


def _num(x: Any, what: str) -> float:
    """A finite float from the wire."""
    return float(_arr(x, what, ()))


def _need(d: Any, keys: tuple[str, ...], what: str) -> dict:
    if not isinstance(d, dict):
        raise ProtocolError(f"seal/scene {what}: expected a map, got {type(d).__name__}")
    missing = [k for k in keys if k not in d]
    if missing:
        raise ProtocolError(f"seal/scene {what}: missing keys {missing}; got {sorted(d)}")
    return d


_BODY = ("pos", "quat", "local_lo", "local_hi", "lo", "hi")


def _body_to(b: Body) -> dict:
    out = {k: getattr(b, k) for k in _BODY}
    if b.parts:  # optional on the wire: fixtures have none
        out["parts"] = [_box_to(g) for g in b.parts]
    return out


def _box_to(g: Box) -> dict:
    return {"center": g.center, "xmat": g.xmat, "half": g.half}


def _box_from(g: Any, what: str) -> Box:
    g = _need(g, ("center", "xmat", "half"), what)
    return Box(center=_arr(g["center"], f"{what}.center", (3,)), xmat=_arr(g["xmat"], f"{what}.xmat", (3, 3)),
               half=_arr(g["half"], f"{what}.half", (3,)))


def _body_from(d: Any, what: str) -> Body:
    d = _need(d, _BODY, what)
    parts = tuple(_box_from(g, f"{what}.parts") for g in d.get("parts", ()))
    return Body(**{k: _arr(d[k], f"{what}.{k}", (4,) if k == "quat" else (3,)) for k in _BODY}, parts=parts)


def scene_to_wire(s: SceneState) -> dict:
    """A `SceneState` as plain maps, lists and arrays (msgpack-numpy packs the arrays)."""
    return {
        "eef_pos": s.eef_pos, "eef_xmat": s.eef_xmat, "finger_axis": s.finger_axis,
        "gripper_width": float(s.gripper_width), "table_z": float(s.table_z), "arm_qpos": s.arm_qpos,
        "bodies": {n: _body_to(b) for n, b in s.bodies.items()},
        "sites": {n: {"pos": x.pos, "xmat": x.xmat, "size": x.size} for n, x in s.sites.items()},
        "joints": {n: float(v) for n, v in s.joints.items()},
        "facts": {n: bool(v) for n, v in s.facts.items()},
        "articulations": {n: {"kind": a.kind, "qpos": float(a.qpos), "range": a.range, "axis": a.axis,
                              "anchor": a.anchor, "part": _body_to(a.part),
                              "geoms": [{"center": g.center, "xmat": g.xmat, "half": g.half} for g in a.geoms]}
                          for n, a in s.articulations.items()},
        "joints_of": {n: list(v) for n, v in s.joints_of.items()},
    }


def scene_from_wire(d: Any) -> SceneState:
    keys = ("eef_pos", "eef_xmat", "finger_axis", "gripper_width", "table_z", "arm_qpos", "bodies", "sites",
            "joints", "facts", "articulations", "joints_of")
    d = _need(d, keys, "top level")
    arts = {}
    for n, a in _need(d["articulations"], (), "articulations").items():
        a = _need(a, ("kind", "qpos", "range", "axis", "anchor", "part", "geoms"), f"articulations[{n}]")
        boxes = tuple(Box(center=_arr(g["center"], "box.center", (3,)), xmat=_arr(g["xmat"], "box.xmat", (3, 3)),
                          half=_arr(g["half"], "box.half", (3,)))
                      for g in (_need(g, ("center", "xmat", "half"), f"articulations[{n}].geoms") for g in a["geoms"]))
        arts[n] = Articulation(kind=str(a["kind"]), qpos=_num(a["qpos"], f"articulations[{n}].qpos"),
                               range=_arr(a["range"], "range", (2,)),
                               axis=_arr(a["axis"], "axis", (3,)), anchor=_arr(a["anchor"], "anchor", (3,)),
                               part=_body_from(a["part"], f"articulations[{n}].part"), geoms=boxes)
    sites = {}
    for n, x in _need(d["sites"], (), "sites").items():
        x = _need(x, ("pos", "xmat", "size"), f"sites[{n}]")
        sites[n] = Site(pos=_arr(x["pos"], f"sites[{n}].pos", (3,)), xmat=_arr(x["xmat"], f"sites[{n}].xmat", (3, 3)),
                        size=_arr(x["size"], f"sites[{n}].size"))
    return SceneState(
        eef_pos=_arr(d["eef_pos"], "eef_pos", (3,)), eef_xmat=_arr(d["eef_xmat"], "eef_xmat", (3, 3)),
        finger_axis=_arr(d["finger_axis"], "finger_axis", (3,)),
        gripper_width=_num(d["gripper_width"], "gripper_width"),
        bodies={n: _body_from(b, f"bodies[{n}]") for n, b in _need(d["bodies"], (), "bodies").items()},
        sites=sites, joints={n: _num(v, f"joints[{n}]") for n, v in _need(d["joints"], (), "joints").items()},
        facts={n: bool(v) for n, v in _need(d["facts"], (), "facts").items()}, table_z=_num(d["table_z"], "table_z"),
        articulations=arts, joints_of={n: tuple(v) for n, v in _need(d["joints_of"], (), "joints_of").items()},
        arm_qpos=_arr(d["arm_qpos"], "arm_qpos"),
    )


# ---------------------------------------------------------------------------- observations


def observation_request(obs: Observation, *, info: ServerInfo) -> dict:
    """One observation in openpi's LIBERO convention, plus the privileged scene if asked for.

    Images go whenever the observation has them (and must, when the server needs them)."""
    if info.images and (obs.agent is None or obs.wrist is None):
        raise InvalidInput("this policy server needs camera images; observe(images=True) first")
    req: dict[str, Any] = {STATE: np.asarray(obs.state, dtype=np.float32), PROMPT: obs.prompt}
    if obs.agent is not None and obs.wrist is not None:
        req[IMAGE], req[WRIST] = obs.agent, obs.wrist
    if info.privileged:
        if obs.scene is None:
            raise InvalidInput("this policy server is a privileged (scripted) policy: observe with "
                               "privileged_atoms=policy.privileged_atoms()")
        req[SCENE] = scene_to_wire(obs.scene)
    return req


def batch_request(reqs: list[dict]) -> dict:
    """n single requests -> one request with arrays stacked on a leading axis."""
    n = len(reqs)
    out: dict[str, Any] = {BATCH: n, PROMPT: reqs[0][PROMPT], STATE: np.stack([r[STATE] for r in reqs])}
    if all(IMAGE in r for r in reqs):
        out[IMAGE] = np.stack([r[IMAGE] for r in reqs])
        out[WRIST] = np.stack([r[WRIST] for r in reqs])
    if SCENE in reqs[0]:
        out[SCENE] = [r[SCENE] for r in reqs]
    return out


def _image(req: dict, key: str, lead: tuple, size: int = IMAGE_SIZE) -> np.ndarray:
    """openpi's 224-px frame, or one at the size the server advertises (``seal.image_size``)."""
    img = req[key]
    wants = [(*lead, s, s, 3) for s in dict.fromkeys((IMAGE_SIZE, size))]
    if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape not in wants:
        got = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
        raise ProtocolError(f"request {key!r}: expected uint8 array of shape {' or '.join(map(str, wants))}, "
                            f"got {got}")
    return img


def parse_request(req: Any, *, needs_images: bool, needs_scene: bool, image_size: int = IMAGE_SIZE,
                  max_batch: int | None = None) -> list[Observation]:
    """Server side: a single or batched request -> observations (validated: shapes, types, finite
    values, at most ``max_batch`` rows; ``max_batch=0`` refuses batched requests)."""
    if not isinstance(req, dict):
        raise ProtocolError(f"a request must be a msgpack map, got {type(req).__name__}")
    n = req.get(BATCH)
    if n is not None and (not isinstance(n, int) or isinstance(n, bool) or n < 1):
        raise ProtocolError(f"request {BATCH!r}: expected a positive int, got {n!r}")
    if n is not None and max_batch == 0:
        raise ProtocolError(f"request {BATCH!r}: this server does not take batched requests (its metadata has "
                            "seal.batch false); send one observation per request")
    if n is not None and max_batch is not None and n > max_batch:
        raise ProtocolError(f"request {BATCH!r}: {n} observations, but this server takes at most {max_batch} per "
                            "request (its metadata's seal.max_batch); split them over several requests")
    lead = () if n is None else (n,)
    required = [STATE, PROMPT] + ([IMAGE, WRIST] if needs_images else []) + ([SCENE] if needs_scene else [])
    missing = [k for k in required if k not in req]
    if missing:
        raise ProtocolError(f"request is missing keys {missing}; got keys {sorted(req)}")
    if not isinstance(req[PROMPT], str):
        raise ProtocolError(f"request 'prompt': expected a string, got {type(req[PROMPT]).__name__}")
    state = req[STATE]
    if not isinstance(state, np.ndarray) or state.shape != (*lead, STATE_DIM) or state.dtype.kind != "f":
        got = f"{state.dtype} {state.shape}" if isinstance(state, np.ndarray) else type(state).__name__
        raise ProtocolError(f"request {STATE!r}: expected float array of shape {(*lead, STATE_DIM)}, got {got}")
    if not np.all(np.isfinite(state)):
        bad = np.flatnonzero(~np.all(np.isfinite(state.reshape(-1, STATE_DIM)), axis=-1)).tolist()
        raise ProtocolError(f"request {STATE!r}: contains NaN or Inf" + (f" (rows {bad})" if n is not None else "")
                            + "; expected finite floats")
    if (IMAGE in req) != (WRIST in req):
        have, lack = (IMAGE, WRIST) if IMAGE in req else (WRIST, IMAGE)
        raise ProtocolError(f"request has {have!r} but not {lack!r}: send both cameras or neither")
    images = ((_image(req, IMAGE, lead, image_size), _image(req, WRIST, lead, image_size))
              if IMAGE in req or needs_images else None)
    scenes = None
    if needs_scene:
        raw = req[SCENE]
        if n is not None and (not isinstance(raw, list) or len(raw) != n):
            raise ProtocolError(f"request {SCENE!r}: expected a list of {n} scenes, got "
                                f"{len(raw) if isinstance(raw, list) else type(raw).__name__}")
        scenes = [scene_from_wire(s) for s in (raw if n is not None else [raw])]
    out = []
    for i in range(n or 1):
        pick = (lambda a: a[i]) if n is not None else (lambda a: a)
        out.append(Observation(state=np.asarray(pick(state), dtype=np.float64), prompt=req[PROMPT],
                               agent=pick(images[0]) if images else None, wrist=pick(images[1]) if images else None,
                               scene=scenes[i] if scenes else None))
    return out


def request_rows(req: dict, n: int | None) -> list[int]:
    """The ``begin(k)`` attempt each observation belongs to (default 0..n-1)."""
    if n is None:
        row = req.get(ROW, 0)
        rows = [row]
    else:
        rows = req.get(ROWS, list(range(n)))
        rows = list(rows.tolist() if isinstance(rows, np.ndarray) else rows) if isinstance(rows, (list, np.ndarray)) else rows
        if not isinstance(rows, list) or len(rows) != n:
            raise ProtocolError(f"request {ROWS!r}: expected a list of {n} ints, got {rows!r}")
    if not all(isinstance(r, int) and not isinstance(r, bool) and r >= 0 for r in rows):
        raise ProtocolError(f"request rows must be non-negative ints, got {rows!r}")
    return rows


# ---------------------------------------------------------------------------- replies


@dataclass
class Reply:
    actions: np.ndarray  # (H, 7) float64, H >= ACTION_HORIZON (at most PREDICT_HORIZON kept)
    think: bool = False
    reasoning: str | None = None


def parse_reply(reply: Any, n: int | None, *, want_reasoning: bool = False) -> list[Reply]:
    """Client side: check a reply for ``n`` stacked observations (None: a single one)."""
    if isinstance(reply, str):
        raise PolicyServerError(f"the policy server answered with an error: {reply.strip()[-2000:]}")
    if not isinstance(reply, dict):
        raise ProtocolError(f"a reply must be a msgpack map with key 'actions', got {type(reply).__name__}")
    if ACTIONS not in reply:
        raise ProtocolError(f"reply is missing key 'actions'; got keys {sorted(map(str, reply))}")
    actions = reply[ACTIONS]
    lead = () if n is None else (n,)
    want = f"a float array of shape {(*lead, 'H', ACTION_DIM)} with H >= {ACTION_HORIZON}"
    if not isinstance(actions, np.ndarray) or actions.dtype.kind not in "fi":
        got = f"{actions.dtype}" if isinstance(actions, np.ndarray) else type(actions).__name__
        raise ProtocolError(f"reply 'actions': expected {want}, got {got}")
    if actions.ndim != len(lead) + 2 or actions.shape[: len(lead)] != lead or actions.shape[-1] != ACTION_DIM \
            or actions.shape[-2] < ACTION_HORIZON:
        raise ProtocolError(f"reply 'actions': expected {want}, got shape {actions.shape}")
    if not np.all(np.isfinite(actions)):
        raise ProtocolError("reply 'actions' contains NaN or Inf")
    think = reply.get(THINK, False)
    thinks = np.asarray(think)
    if thinks.dtype != np.bool_ or thinks.shape not in ((), lead):
        raise ProtocolError(f"reply 'think': expected bool{' or bool array of shape ' + str(lead) if lead else ''}, "
                            f"got {think!r}")
    reasoning = reply.get(REASONING)
    if want_reasoning and reasoning is None:
        raise ProtocolError(f"reply is missing key 'reasoning' (the server's metadata says it reasons); "
                            f"got keys {sorted(map(str, reply))}")
    if reasoning is not None and not isinstance(reasoning, str):
        raise ProtocolError(f"reply 'reasoning': expected a string, got {type(reasoning).__name__}")
    acts = np.asarray(actions, dtype=np.float64)[..., :PREDICT_HORIZON, :]
    if n is None:
        return [Reply(acts, bool(thinks), reasoning)]
    flags = np.broadcast_to(thinks, lead)
    return [Reply(acts[i], bool(flags[i]), reasoning) for i in range(n)]


def check_control(req: dict) -> str:
    ctrl = req[CONTROL]
    if ctrl not in CONTROLS:
        raise ProtocolError(f"unknown {CONTROL} {ctrl!r}; valid: {', '.join(CONTROLS)}")
    return ctrl
