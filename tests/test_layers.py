"""The package's layers, checked on the real import graph (every import statement, also
those inside functions): a lower layer never imports a higher one, and nothing forms a cycle.

docs/design.md lists the layers: the errors, logs and array aliases at the bottom, then messages;
protocols; odometry; recording; floors; mapping; sim; evaluation, export and live; the CLI and
the daemon on top.
"""

from __future__ import annotations

import pkgutil

import grimp
import pytest

import baromap

#: Top to bottom. Each entry is one layer; modules in a set are siblings that must not
#: import each other either. A module may import any module of a lower layer.
LAYERS: tuple[str | set[str], ...] = (
    "baromap.cli",
    {"baromap.evaluation", "baromap.export", "baromap.live", "baromap.liveview"},
    "baromap.sim",
    "baromap.mapping",
    "baromap.floors",
    "baromap.recording",
    "baromap.odometry",
    {"baromap.protocols", "baromap.jsonmsg", "baromap.discovery", "baromap.building"},
    "baromap.messages",
    {"baromap.errors", "baromap.logs", "baromap.arrays"},
)


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("baromap", "baromapd")


def _named(layer: str | set[str]) -> set[str]:
    return {layer} if isinstance(layer, str) else layer


def test_every_part_of_baromap_has_a_layer() -> None:
    placed = set().union(*(_named(layer) for layer in LAYERS))
    parts = {f"baromap.{m.name}" for m in pkgutil.iter_modules(baromap.__path__)}
    assert parts - placed == set(), "place every new module or package in LAYERS"


def test_no_import_runs_up_a_layer(graph: grimp.ImportGraph) -> None:
    illegal = graph.find_illegal_dependencies_for_layers(layers=LAYERS)
    described = sorted(
        f"{dep.importer} -> {dep.imported} via "
        + "; ".join(
            "/".join(sorted(route.heads)) + " -> " + "/".join(sorted(route.tails))
            for route in dep.routes
        )
        for dep in illegal
    )
    assert described == []


def test_the_library_never_imports_the_daemon(graph: grimp.ImportGraph) -> None:
    importers = {
        importer
        for module in graph.modules
        if module == "baromapd" or module.startswith("baromapd.")
        for importer in graph.find_modules_that_directly_import(module)
        if importer == "baromap" or importer.startswith("baromap.")
    }
    assert importers == set()


def test_no_import_cycle_between_modules(graph: grimp.ImportGraph) -> None:
    modules = sorted(m for m in graph.modules if m.startswith(("baromap", "baromapd")))
    cycles = []
    for module in modules:
        for imported in graph.find_modules_directly_imported_by(module):
            if graph.chain_exists(imported, module):
                cycles.append(f"{module} <-> {imported}")
    assert cycles == []
