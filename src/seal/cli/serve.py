"""`seal serve`: a registered policy over openpi's websocket protocol."""

from __future__ import annotations

import json
import os

from seal.cli.common import policy_help, scripted_knobs
from seal.errors import InvalidInput


def add(sub) -> None:
    serve = sub.add_parser("serve", help="serve a SEAL policy over openpi's websocket protocol (docs/serving.md)")
    serve.add_argument("--policy", default="scripted", help=policy_help(_served) + " (default scripted)")
    serve.add_argument("--knobs", default=scripted_knobs()[0], choices=scripted_knobs()[1], help="scripted only")
    serve.add_argument("--host", default="127.0.0.1", help="0.0.0.0 to accept other machines")
    serve.add_argument("--port", type=int, default=8000, help="0: any free port (printed on stdout)")
    serve.add_argument("--task", default="", help="scripted: task for clients that do not configure one, e.g. "
                                                  "libero_10/0 (vla needs none)")
    serve.add_argument("--max-batch", type=int, default=64, help="largest batched request accepted")
    serve.add_argument("--seed", type=int, default=0)
    serve.add_argument("--plain", action="store_true",
                       help="answer like a plain pi0 server: actions only, no reasoning, think or batching")
    serve.add_argument("--require-api-key", action="store_true",
                       help="refuse handshakes without 'Authorization: Api-Key $OPENPI_API_KEY' (/healthz stays open)")
    serve.set_defaults(func=_cmd_serve)


def _served(name: str) -> bool:
    from seal.policies import servable

    return name in servable()


def _cmd_serve(args) -> int:
    from dataclasses import replace

    from seal.policies import POLICIES, servable
    from seal.serving.server import PolicyServer, check_port, policy_server

    name, colon, path = args.policy.partition(":")
    served = servable()
    if name not in served or (colon and not POLICIES.options(name).checkpoint):
        valid = [v for n in served for v in ((n, f"{n}:PATH") if POLICIES.options(n).checkpoint else (n,))]
        raise InvalidInput(f"unknown --policy {args.policy!r} for seal serve; valid: {', '.join(valid)}")
    if args.max_batch < 1:
        raise InvalidInput(f"--max-batch must be >= 1, got {args.max_batch}")
    check_port(args.port)  # before a checkpoint loads; a port in use is found when the server binds
    api_key = None
    if args.require_api_key:
        api_key = os.environ.get("OPENPI_API_KEY")
        if not api_key:
            raise InvalidInput("--require-api-key: set the key in the OPENPI_API_KEY environment variable "
                               "(never on the command line)")
    options = POLICIES.options_of(name, args)  # the serve flags it declares (--knobs)
    if colon:
        options = replace(options, **{options.checkpoint: path})
    factory, info, meta, default_task = policy_server(name, options, seed=args.seed, max_batch=args.max_batch,
                                                      plain=args.plain, task=args.task)
    server = PolicyServer(factory, info, host=args.host, port=args.port, default_task=default_task, api_key=api_key,
                          metadata=meta)

    def ready(port: int) -> None:  # one JSON line on stdout: scripts (and tests) read the port from it
        print(json.dumps({"event": "listening", "url": f"ws://{args.host}:{port}", "port": port}), flush=True)

    server.serve_forever(ready)
    print(json.dumps({"event": "stopped", "requests": server.requests}), flush=True)
    return 0
