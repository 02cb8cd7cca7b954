"""The dependency rule of docs/architecture.md, checked on the source (no simulator needed).

A module's dependencies are read with `ast` from every file under src/seal:

- its imports, including those inside functions (a lazy import is still a dependency);
- the dotted plug-in paths it names, ``"seal.package.module:attr"`` (a registry entry such as
  ``POLICIES``' or ``SCORERS``', a ``.register(...)`` argument, the benchmark table): imported on
  first use, they are dependencies all the same;
- ``import_module("seal....")`` with a literal name.

So a rule broken anywhere, at import time or on first use, fails here. An import under
``if TYPE_CHECKING:`` counts for the layers (an annotation names what it depends on) but not for
cycles (it never runs).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

# docs/architecture.md's layers, bottom first: (what the layer is, the packages and modules in it).
# A module belongs to the layer of the longest entry that is it or a package above it ("seal" is
# the package root alone: its version). Arrows point down only: a module may depend on modules of
# its own layer and the layers below, never on a layer above. (Within a layer, the cycle check
# below keeps the arrows one-way.)
LAYERS = [
    ("the root: SEAL's errors and version", ("seal", "seal.errors")),
    ("the world", ("seal.sim",)),
    ("services that know no SEAL concept", ("seal.registry", "seal.options", "seal.checkpoint", "seal.vlm",
                                            "seal.datasets", "seal.progress")),
    ("plug-ins at the loop's seams: who acts (policies, sub-plan planners, an openpi server's client), "
     "who judges (verifiers), who scores (the value function)",
     ("seal.policies", "seal.verify", "seal.value", "seal.serving", "seal.serving.protocol", "seal.serving.client")),
    ("one episode: the steering loop, an un-steered episode, a policy server, reasoning annotation",
     ("seal.steer", "seal.episode", "seal.serving.server", "seal.annotate")),
    ("many episodes: evaluation, recordings, verification cases, DAgger, suite checks",
     ("seal.eval", "seal.demos", "seal.collect", "seal.dagger", "seal.suite_tools")),
    ("datasets and stores to checkpoints and reports", ("seal.train", "seal.report")),
    ("commands", ("seal.benchmarks", "seal.cli")),
]

# "seal.package.module:attr" (attr may be dotted: "VGPSScorer.load")
DOTTED = re.compile(r"^(seal(?:\.[A-Za-z_]\w*)*):([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)$")


def _module_name(path: Path, root: Path = SRC) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules(root: Path = SRC) -> dict[str, Path]:
    return {_module_name(p, root): p for p in sorted((root / "seal").rglob("*.py"))}


MODULES = _modules()


def _in(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _imports(path: Path, *, top_level_only: bool = False) -> list[tuple[str, list[str], int]]:
    """(imported module, names taken from it, line) for every import in the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out = []
    for node in nodes:
        if isinstance(node, ast.Import):
            out += [(alias.name, [], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, [alias.name for alias in node.names], node.lineno))
    return out


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The module a dotted name imports: itself, or the package it lies in (longest known prefix)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in modules:
            return ".".join(parts[:n])
    return None


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of the nodes under ``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``)."""
    inside: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and (getattr(node.test, "id", None) == "TYPE_CHECKING"
                                         or getattr(node.test, "attr", None) == "TYPE_CHECKING"):
            inside.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return inside


def _dependencies(path: Path, modules: dict[str, Path] = MODULES, *,
                  type_only: bool = True) -> list[tuple[str, int, str]]:
    """(SEAL module depended on, line, how) for every import, dotted plug-in path and literal
    ``import_module`` in the file (without ``type_only``: not those under ``if TYPE_CHECKING:``).
    A dotted path whose module does not exist comes back as it is written (see
    `test_dotted_paths_name_what_exists`)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    skip = set() if type_only else _type_checking_only(tree)
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if _in(alias.name, "seal") and (target := _resolve(alias.name, modules)):
                    out.append((target, node.lineno, f"import {alias.name}"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                out.append((f"<relative import at level {node.level}>", node.lineno, "from . import"))
                continue
            if not node.module or not _in(node.module, "seal"):
                continue
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"  # `from package import module`
                target = sub if sub in modules else _resolve(node.module, modules)
                if target:
                    out.append((target, node.lineno, f"from {node.module} import {alias.name}"))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and (m := DOTTED.match(node.value)):
            out.append((m[1], node.lineno, f"plug-in path {node.value!r}"))
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            if called in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant) \
                    and isinstance(node.args[0].value, str) and _in(node.args[0].value, "seal"):
                out.append((_resolve(node.args[0].value, modules) or node.args[0].value, node.lineno,
                            f"{called}({node.args[0].value!r})"))
    return out


def _layer(module: str) -> int | None:
    best, depth = None, -1
    for i, (_, entries) in enumerate(LAYERS):
        for entry in entries:
            hit = module == entry if entry == "seal" else _in(module, entry)
            if hit and entry.count(".") > depth:
                best, depth = i, entry.count(".")
    return best


def _upward(modules: dict[str, Path]) -> list[str]:
    broken = []
    for name, path in modules.items():
        mine = _layer(name)
        for dep, line, how in _dependencies(path, modules):
            theirs = _layer(dep)
            if mine is not None and theirs is not None and theirs > mine:
                broken.append(f"{name}:{line} ({LAYERS[mine][0].split(':')[0]}) -> {dep} "
                              f"({LAYERS[theirs][0].split(':')[0]}) by {how}")
    return broken


def _graph(modules: dict[str, Path]) -> dict[str, dict[str, str]]:
    """module -> {module it depends on at run time: where and how (the first occurrence)}."""
    graph: dict[str, dict[str, str]] = {}
    for name, path in modules.items():
        deps: dict[str, str] = {}
        for dep, line, how in _dependencies(path, modules, type_only=False):
            if dep in modules and dep != name:
                deps.setdefault(dep, f"{name}:{line} {how}")
        graph[name] = deps
    return graph


def _cycles(graph: dict[str, dict[str, str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, deps = work[-1]
            for dep in deps:
                if dep not in index:
                    index[dep] = low[dep] = counter
                    counter += 1
                    stack.append(dep)
                    on_stack.add(dep)
                    work.append((dep, iter(sorted(graph[dep]))))
                    break
                if dep in on_stack:
                    low[node] = min(low[node], index[dep])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def _describe(component: list[str], graph: dict[str, dict[str, str]]) -> str:
    edges = [graph[a][b] + f" -> {b}" for a in component for b in component if b in graph[a]]
    return " | ".join(edges)


def test_the_source_tree_is_where_the_rules_look():
    # If the layout moved, the rules below would pass vacuously.
    for name in ("seal.sim.world", "seal.verify.oracle", "seal.steer.engine", "seal.eval.execute",
                 "seal.policies.expert.plan", "seal.sim.lexicon", "seal.vlm", "seal.value.vgps",
                 "seal.policies.planners", "seal.steer.scoring", "seal.serving.client"):
        assert name in MODULES, name
    # and the dependency reader sees lazy imports and plug-in paths
    seen = {dep for dep, _, _ in _dependencies(MODULES["seal.policies"])}
    assert {"seal.registry", "seal.policies.expert.policy", "seal.serving.client"} <= seen, seen


def test_every_module_has_a_layer_and_every_layer_entry_exists():
    assert not [name for name in MODULES if _layer(name) is None], "add them to LAYERS"
    entries = [e for _, es in LAYERS for e in es]
    assert len(entries) == len(set(entries))
    assert not [e for e in entries if not any(_in(m, e) for m in MODULES)], "stale LAYERS entries"


def test_arrows_point_down_only():
    broken = _upward(MODULES)
    assert not broken, "upward dependencies:\n" + "\n".join(broken)


def test_dotted_paths_name_what_exists():
    """Every "seal.module:attr" plug-in path names a module that defines attr's first part."""
    broken = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.Constant) and isinstance(node.value, str) and (m := DOTTED.match(node.value))):
                continue
            target, attr = m[1], m[2].split(".")[0]
            if target not in MODULES:
                broken.append(f"{name}:{node.lineno} {node.value!r}: no module {target}")
                continue
            tree = ast.parse(MODULES[target].read_text())
            defined = set()
            for top in tree.body:
                if isinstance(top, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    defined.add(top.name)
                elif isinstance(top, (ast.Assign, ast.AnnAssign)):
                    for t in (top.targets if isinstance(top, ast.Assign) else [top.target]):
                        defined.update(n.id for n in ast.walk(t) if isinstance(n, ast.Name))
                elif isinstance(top, (ast.Import, ast.ImportFrom)):
                    defined.update((a.asname or a.name).split(".")[0] for a in top.names)
            if attr not in defined:
                broken.append(f"{name}:{node.lineno} {node.value!r}: {target} defines no {attr}")
    assert not broken, "; ".join(broken)


# (importer package or module, what it must not depend on, why): finer than the layers
RULES = [
    ("seal.sim", "seal.policies.expert", "sim knows nothing of policies"),
    ("seal.verify", "seal.policies.expert", "a verifier judges outcomes, not how the expert produced them"),
    ("seal.steer.engine", "seal.policies.expert", "the loop works with any ReasoningPolicy"),
    ("seal.steer.selection", "seal.policies.expert", "the loop works with any ReasoningPolicy"),
    ("seal.eval", "seal.policies.expert", "a method names its policy; the registry builds it"),
    ("seal.policies.vla", "seal.serving", "a policy is below the wire that serves it"),
]
SIM_MAY_IMPORT = ("seal.sim", "seal.errors")


@pytest.mark.parametrize("importer,forbidden,why", RULES)
def test_dependency_rule(importer, forbidden, why):
    broken = [f"{name}:{line} {how}" for name, path in MODULES.items() if _in(name, importer)
              for dep, line, how in _dependencies(path) if _in(dep, forbidden)]
    assert not broken, f"{why}: " + "; ".join(broken)


def test_sim_imports_only_sim():
    broken = [f"{name}:{line} {how}" for name, path in MODULES.items() if _in(name, "seal.sim")
              for dep, line, how in _dependencies(path) if not any(_in(dep, ok) for ok in SIM_MAY_IMPORT)]
    assert not broken, "sim is the bottom layer: " + "; ".join(broken)


CLI_SHARED = ("seal.cli.common",)  # what the command modules share
CLI_ENTRY = ("seal.cli.__main__",)  # `python -m seal.cli`


def test_cli_command_modules_import_no_other_command():
    """seal.cli is one module per command, its parser built from them by seal.cli itself: a command
    module imports no other command module (nor the package), only the shared module; the shared
    module imports no command; and every command module is one the package builds the parser from."""
    commands = [n for n in MODULES if n.startswith("seal.cli.") and n not in CLI_SHARED + CLI_ENTRY]
    assert len(commands) >= 10, commands
    broken = [f"{name}:{line} {how}" for name in commands + list(CLI_SHARED)
              for dep, line, how in _dependencies(MODULES[name])
              if _in(dep, "seal.cli") and dep != name and (name in CLI_SHARED or dep not in CLI_SHARED)]
    assert not broken, "command modules share only seal.cli.common: " + "; ".join(broken)
    built_from = {dep for dep, _, _ in _dependencies(MODULES["seal.cli"])}
    assert not [n for n in commands if n not in built_from], "seal.cli must import every command module"


def test_no_private_names_across_modules():
    """``from seal.x.y import _name`` only in seal.x.y itself: another module's private names are
    not an interface (a helper two modules share is public in one of them)."""
    broken = []
    for name, path in MODULES.items():
        for mod, names, line in _imports(path):
            if _in(mod, "seal") and mod != name:
                broken += [f"{name}:{line} imports {mod}.{n}" for n in names if n.startswith("_") and n != "__version__"]
    assert not broken, "; ".join(broken)


def test_no_import_cycles():
    """No two modules depend on each other, directly or through others, counting lazy imports and
    plug-in paths: a cycle that only closes at run time still ties the modules together."""
    graph = _graph(MODULES)
    cycles = _cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(_describe(c, graph) for c in cycles)


def test_the_rules_catch_a_breach(tmp_path):
    """The checkers themselves, on a made-up tree: each kind of breach is reported."""
    files = {
        "seal/__init__.py": "",
        "seal/errors.py": "",
        "seal/registry.py": "",
        "seal/sim/__init__.py": "",
        "seal/sim/world.py": "def f():\n    from seal.steer.engine import Steerer\n    from seal.verify.vlm import _x\n",
        "seal/verify/__init__.py": "",
        "seal/verify/vlm.py": "import importlib\n\ndef g():\n    return importlib.import_module('seal.cli')\n",
        "seal/policies/__init__.py": "from seal.registry import Registry\nP = Registry('p', {'a': 'seal.eval.runner:run'})\n"
                                    "P.register('b', 'seal.policies.nowhere:make')\n",
        "seal/steer/__init__.py": "",
        "seal/steer/engine.py": "from seal.steer import method\n",
        "seal/steer/method.py": "def h():\n    from seal.steer.engine import Steerer\n",
        "seal/steer/config.py": "from typing import TYPE_CHECKING\nP = {'base': 'seal.steer.selection:Selection'}\n",
        "seal/steer/selection.py": "import typing\nif typing.TYPE_CHECKING:\n    from seal.steer.config import P\n"
                                   "    from seal.eval.runner import run\n",
        "seal/eval/__init__.py": "",
        "seal/eval/runner.py": "def run():\n    pass\n",
        "seal/cli.py": "",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    modules = _modules(tmp_path)
    up = "\n".join(_upward(modules))
    assert "seal.sim.world:2 (the world) -> seal.steer.engine" in up  # a lazy import
    assert "seal.verify.vlm:4" in up and "import_module('seal.cli')" in up  # a literal import_module
    assert "seal.policies:2" in up and "plug-in path 'seal.eval.runner:run'" in up  # a registry entry
    assert not [line for line in up.splitlines() if "seal.policies.nowhere" in line]  # no layer: not an arrow
    deps = _dependencies(modules["seal.policies"], modules)
    assert ("seal.policies.nowhere", 3, "plug-in path 'seal.policies.nowhere:make'") in deps  # a .register() entry
    assert ("seal.verify.vlm", ["_x"], 3) in _imports(modules["seal.sim.world"])
    graph = _graph(modules)
    assert _cycles(graph) == [["seal.steer.engine", "seal.steer.method"]]  # closed by a lazy import
    # a type-only import closes no cycle (config <-> selection), but is still an upward arrow
    assert "seal.steer.selection:4 (one episode) -> seal.eval.runner" in up
    assert "seal.steer.method:2 from seal.steer.engine import Steerer -> seal.steer.engine" in _describe(
        ["seal.steer.engine", "seal.steer.method"], graph)
