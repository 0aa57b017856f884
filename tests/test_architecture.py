"""The house reads one way: imports go down the layers of the server, never up, and the
modules of one layer import each other without a circle (ARCHITECTURE.md, "Layers").

Read from the source (every import, those under ``TYPE_CHECKING`` included), so a
circle that only a type annotation makes is found too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx

SERVER = Path(__file__).resolve().parent.parent / "server"

#: The layer of each part of the server, by rank: a module imports only from layers ranked
#: lower, or from its own.
LAYERS = {
    "server.app": ("root", 5),  # the composition root: the app, its command, the demo
    "server.cli": ("root", 5),
    "server.__main__": ("root", 5),
    "server.demo": ("root", 5),
    "server.container": ("root", 5),
    "server.running": ("root", 5),
    "server.api": ("api", 4),
    "server.services": ("services", 3),
    "server.storage": ("storage", 2),
    "server.bus": ("bus", 2),
    "server.domain": ("domain", 1),
    "server.errors": ("errors", 0),  # leaves every layer may use
    "server.settings": ("settings", 0),
    "server.metrics": ("metrics", 0),
    "server.logs": ("logs", 0),
}


def layer(module: str) -> tuple[str, int]:
    for prefix in sorted(LAYERS, key=len, reverse=True):
        if module == prefix or module.startswith(prefix + "."):
            return LAYERS[prefix]
    raise AssertionError(f"{module} belongs to no layer of LAYERS")


def module_name(path: Path) -> str:
    parts = path.relative_to(SERVER.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports() -> nx.DiGraph:
    graph = nx.DiGraph()
    modules = {
        module_name(p): p
        for p in SERVER.rglob("*.py")
        if p.parent != SERVER or p.stem != "__init__"
    }
    for name, path in modules.items():
        graph.add_node(name)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for target in targets:
                if target in modules and target not in (name, "server"):
                    graph.add_edge(name, target)
    return graph


def test_every_import_goes_down_the_layers() -> None:
    graph = imports()
    up = [
        f"{a} -> {b}"
        for a, b in graph.edges
        if layer(a)[0] != layer(b)[0] and layer(b)[1] >= layer(a)[1]
    ]
    assert up == []


def test_no_circles_within_a_layer() -> None:
    graph = imports()
    # A package's __init__ re-exporting its modules is not a dependency between them.
    inner = nx.DiGraph(
        (a, b) for a, b in graph.edges if layer(a) == layer(b) and not _is_package(a)
    )
    cycles = list(nx.simple_cycles(inner))
    assert cycles == []


def test_services_are_built_by_the_container_alone() -> None:
    """Nothing below the composition root builds the app's services or the live hub."""
    graph = imports()
    builders = {a for a, b in graph.edges if b == "server.container"}
    assert builders <= {"server.app", "server.cli", "server.demo"}


def _is_package(module: str) -> bool:
    return (SERVER.parent / module.replace(".", "/") / "__init__.py").exists()
