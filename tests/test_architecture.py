"""The dependency rule of docs/architecture.md, checked on the source (no simulator needed).

Imports are read with `ast` from every module under src/seal, including imports inside
functions (a lazy import is still a dependency), so a rule broken anywhere fails here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


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


MODULES = {_module_name(p): p for p in sorted((SRC / "seal").rglob("*.py"))}


def _in(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def test_the_source_tree_is_where_the_rules_look():
    # If the layout moved, the rules below would pass vacuously.
    for name in ("seal.sim.world", "seal.verify.oracle", "seal.steer.engine", "seal.eval.execute",
                 "seal.policies.expert.plan", "seal.sim.lexicon", "seal.vlm"):
        assert name in MODULES, name


# (importer package or module, what it must not import, why)
RULES = [
    ("seal.sim", "seal.policies.expert", "sim knows nothing of policies"),
    ("seal.verify", "seal.policies.expert", "a verifier judges outcomes, not how the expert produced them"),
    ("seal.steer.engine", "seal.policies.expert", "the loop works with any ReasoningPolicy"),
    ("seal.steer.selection", "seal.policies.expert", "the loop works with any ReasoningPolicy"),
    ("seal.eval", "seal.policies.expert", "a method names its policy; the registry builds it"),
]
SIM_MAY_IMPORT = ("seal.sim", "seal.errors")


@pytest.mark.parametrize("importer,forbidden,why", RULES)
def test_dependency_rule(importer, forbidden, why):
    broken = [f"{name}:{line} imports {mod}" for name, path in MODULES.items() if _in(name, importer)
              for mod, _, line in _imports(path) if _in(mod, forbidden)]
    assert not broken, f"{why}: " + "; ".join(broken)


def test_sim_imports_only_sim():
    broken = [f"{name}:{line} imports {mod}" for name, path in MODULES.items() if _in(name, "seal.sim")
              for mod, _, line in _imports(path) if _in(mod, "seal") and not any(_in(mod, ok) for ok in SIM_MAY_IMPORT)]
    assert not broken, "sim is the bottom layer: " + "; ".join(broken)


def test_no_private_names_across_packages():
    """``from seal.x.y import _name`` only within package seal.x: another package's private names
    are not an interface."""
    broken = []
    for name, path in MODULES.items():
        own = ".".join(name.split(".")[:2])
        for mod, names, line in _imports(path):
            if _in(mod, "seal") and not _in(mod, own):
                broken += [f"{name}:{line} imports {mod}.{n}" for n in names if n.startswith("_") and n != "__version__"]
    assert not broken, "; ".join(broken)


def test_no_import_cycles_at_module_level():
    """Module-level imports form no cycle (a lazy import inside a function is how a plug-in
    registry or a CLI defers work; it does not run at import time)."""
    graph = {}
    for name, path in MODULES.items():
        deps = set()
        for mod, names, _ in _imports(path, top_level_only=True):
            # `from pkg import module` depends on that module; `from module import name` on the module
            targets = [f"{mod}.{n}" for n in names if f"{mod}.{n}" in MODULES] or [mod]
            deps.update(t for t in targets if t in MODULES and t != name)
        graph[name] = deps
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return stack[stack.index(dep):] + [dep]
            if dep not in state:
                cycle = visit(dep)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_rules_catch_a_breach(tmp_path):
    """The checker itself: a module that breaks the rule is reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from seal.policies.expert.plan import plan_task\n    from seal.verify.vlm import _x\n")
    found = _imports(bad)
    assert ("seal.policies.expert.plan", ["plan_task"], 2) in found and ("seal.verify.vlm", ["_x"], 3) in found
    assert _imports(bad, top_level_only=True) == []
