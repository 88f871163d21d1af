"""The import graph (grimp, imports under ``if TYPE_CHECKING:`` left out, as they never run): no
cycles in ``pipeline``, imports pointing down (a source imports neither another source nor the
run's orchestration; the orchestration names no source), and neither ``pipeline`` nor
``benchmarks`` imports ``tests``."""

from __future__ import annotations

import grimp
import networkx as nx
import pytest

from pipeline.settings.sections import BUILT_IN

# The built-in sources' packages, as the registry names them.
SOURCES = tuple(BUILT_IN.values())


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("pipeline", "benchmarks", "tests", exclude_type_checking_imports=True)


def module_cycles(graph: grimp.ImportGraph, package: str) -> list[list[str]]:
    """The import cycles among the modules of ``package`` (each a list of module names)."""
    edges = nx.DiGraph()
    for module in graph.find_children(package) | graph.find_descendants(package):
        for imported in graph.find_modules_directly_imported_by(module):
            if imported.startswith(f"{package}."):
                edges.add_edge(module, imported)
    return [cycle for cycle in nx.simple_cycles(edges)]


def test_the_pipeline_has_no_import_cycle(graph):
    assert module_cycles(graph, "pipeline") == []


def test_a_planted_cycle_is_found():
    planted = grimp.ImportGraph()
    for name in ("pkg", "pkg.a", "pkg.b"):
        planted.add_module(name)
    planted.add_import(importer="pkg.a", imported="pkg.b")
    planted.add_import(importer="pkg.b", imported="pkg.a")
    assert sorted(map(sorted, module_cycles(planted, "pkg"))) == [["pkg.a", "pkg.b"]]


@pytest.mark.parametrize("source", SOURCES)
def test_a_source_imports_no_other_source_and_not_the_runner(graph, source):
    for other in (*[s for s in SOURCES if s != source], "pipeline.runner", "pipeline.run"):
        chains = graph.find_shortest_chains(importer=source, imported=other, as_packages=True)
        assert not chains, f"{source} reaches {other}: {sorted(chains)[:3]}"


def test_the_runner_names_no_source(graph):
    for source in SOURCES:
        imports = graph.find_matching_direct_imports(import_expression=f"pipeline.runner.** -> {source}.**")
        imports += graph.find_matching_direct_imports(import_expression=f"pipeline.runner.** -> {source}")
        assert not imports, f"the runner imports {source}: {imports[:3]}"


@pytest.mark.parametrize("importer", ["pipeline", "benchmarks"])
def test_tests_are_imported_by_neither_the_package_nor_the_benchmarks(graph, importer):
    chains = graph.find_shortest_chains(importer=importer, imported="tests", as_packages=True)
    assert not chains, f"{importer} imports tests: {sorted(chains)[:3]}"
