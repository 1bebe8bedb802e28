"""The package's layering: every import points down, and no module imports itself through others.

``LAYERS`` lists the subpackages (and top-level modules) of ``cafe_mpc`` from the bottom up. A module may
import modules of its own layer or of a lower one, never of a higher one; the import graph between
modules, and between the packages of one layer, has no cycle. Every ``import`` statement counts: at module
level, inside functions and methods, in ``try`` blocks. Exempt: imports under ``if TYPE_CHECKING:`` (they
never run; they only name types for annotations, which ``from __future__ import annotations`` keeps
unevaluated). The check reads the sources with ``ast``; nothing is imported.

Besides the order: the settings schema (``config``) imports no other package of ``cafe_mpc``; the solver
(``solver``) reaches nothing of the package but ``core``, through any chain of imports; the library front
end (``api``) and the assembly (``assembly``: a config -> its controller) reach neither the experiment
harness, the report, the simulator (``sim``) nor MuJoCo, through any chain of imports (and a subprocess that
builds a ``cafe_mpc.Controller`` shows MuJoCo never loaded).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = "cafe_mpc"
"""The library a user embeds."""
LAB = "cafe_mpc_lab"
"""The lab above it: plants, experiments, reports, benchmarks, the command line."""
SOURCES = Path(__file__).resolve().parents[1] / "src"
SOURCE = SOURCES / PACKAGE

LAYERS: list[tuple[str, ...]] = [
    ("config",),  # the settings schema: run configs, weights, estimator tuning, loading (no domain imports)
    ("core",),  # per-knot solver interface, contact flags, Measurement, Plan, controller interfaces
    ("robots",),  # robot tables, URDF/MJCF generation, Robot
    ("dynamics",),  # whole-body and SRB models, impact, transition, statics, SRB parameters of a robot
    ("ocp",),  # costs, constraints, barriers, knots, contact schedules and gaits
    ("solver",),  # MS-iLQR
    ("reference", "planners", "trajopt"),  # locomotion reference; the planners (CAFE, template); offline TO
    ("low_level", "estimation"),  # low-level controllers: PD, Riccati (33), VWBC (34); the state estimator
    ("control",),  # closed loops: the MPC loop over a low-level controller, a plan follower
    ("assembly",),  # a config -> its controller (planner, low level, real-time and estimator front ends)
    ("api",),  # the library front end (cafe_mpc.Controller): no simulator below it
    ("lab.sim",),  # the lab: MuJoCo plant, closed-loop simulation, Pinocchio-vs-MuJoCo consistency
    ("lab.experiments", "lab.report", "lab.bench"),  # runs, metrics, plots, benchmarks
    ("lab.cli",),  # the cafe-mpc command
]
"""Layers from the bottom up; a name is a subpackage (``cafe_mpc/<name>/``) or a module (``<name>.py``) of the
library, or ``lab.<name>`` for one of the lab (``cafe_mpc_lab``)."""

LAYER_OF = {name: index for index, names in enumerate(LAYERS) for name in names}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def component(module: str) -> str:
    """``cafe_mpc.ocp.knots`` -> ``ocp``; ``cafe_mpc_lab.cli`` -> ``lab.cli``; ``cafe_mpc`` and
    ``cafe_mpc_lab`` -> ``""``."""
    parts = module.split(".")
    if len(parts) < 2:
        return ""
    return f"lab.{parts[1]}" if parts[0] == LAB else parts[1]


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imported_modules(source: str, module: str, is_package: bool, known: set[str]) -> set[str]:
    """Modules of the package that ``source`` imports anywhere (functions included), except under
    ``if TYPE_CHECKING:``. ``from a.b import c`` counts as ``a.b.c`` when that is a module, else ``a.b``."""
    tree = ast.parse(source)
    found: set[str] = set()

    def resolve(node: ast.ImportFrom) -> str:
        if node.level == 0:
            return node.module or ""
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        return ".".join([*base, node.module] if node.module else base)

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            target = resolve(node)
            for alias in node.names:
                candidate = f"{target}.{alias.name}"
                found.add(candidate if candidate in known else target)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    own = set()
    for name in found:
        if name.split(".")[0] not in (PACKAGE, LAB):
            continue
        while name not in known and "." in name:  # ``import cafe_mpc.x.y.Name``-style leftovers
            name = name.rsplit(".", 1)[0]
        if name in known and name != module:
            own.add(name)
    return own


def external_imports(source: str, module_level_only: bool = False) -> set[str]:
    """Top-level names of the packages outside ``cafe_mpc`` that ``source`` imports (``import mujoco`` ->
    ``mujoco``), anywhere or only at module level; ``if TYPE_CHECKING:`` blocks are exempt."""
    found: set[str] = set()

    def visit(node: ast.AST, depth: int) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child, depth)
            return
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
        inside = isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
        if module_level_only and inside:
            return
        for child in ast.iter_child_nodes(node):
            visit(child, depth + inside)

    visit(ast.parse(source), 0)
    return found - {PACKAGE, LAB}


def reachable(graph: dict[str, set[str]], starts: set[str]) -> set[str]:
    """Every module of the package that ``starts`` import, directly or through others."""
    seen: set[str] = set()
    todo = list(starts)
    while todo:
        module = todo.pop()
        for target in graph.get(module, ()):
            if target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def import_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """``{module: (source, is_package)}`` -> ``{module: modules of the package it imports}``."""
    known = set(sources)
    return {
        module: imported_modules(source, module, is_package, known)
        for module, (source, is_package) in sources.items()
    }


def package_sources(roots: tuple[Path, ...] = (SOURCE, SOURCES / LAB)) -> dict[str, tuple[str, bool]]:
    """``{module: (source, is_package)}`` of every module of the library and the lab."""
    return {
        module_name(path, root): (path.read_text(), path.name == "__init__.py")
        for root in roots
        for path in root.rglob("*.py")
    }


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Imports from a module to a module of a higher layer, as readable lines."""
    problems = []
    for module, targets in sorted(graph.items()):
        source = component(module)
        if source == "":
            continue
        for target in sorted(targets):
            destination = component(target)
            if destination == "" or destination == source:
                continue
            if LAYER_OF[destination] > LAYER_OF[source]:
                problems.append(
                    f"{module} (layer {LAYER_OF[source]}: {source}) imports {target} "
                    f"(layer {LAYER_OF[destination]}: {destination})"
                )
    return problems


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def connect(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                connect(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            members = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                members.append(member)
                if member == node:
                    break
            if len(members) > 1:
                found.append(sorted(members))

    for node in sorted(graph):
        if node not in index:
            connect(node)
    return found


def component_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {}
    for module, targets in graph.items():
        source = component(module)
        for target in targets:
            destination = component(target)
            if source and destination and destination != source:
                edges.setdefault(source, set()).add(destination)
    return edges


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(package_sources())


def test_every_package_has_a_layer(graph):
    components = {component(module) for module in graph} - {""}
    missing = sorted(components - set(LAYER_OF))
    assert not missing, f"add these to LAYERS in tests/test_layers.py (and the README's layout): {missing}"


def test_imports_point_down(graph):
    problems = upward_imports(graph)
    assert not problems, "upward imports:\n" + "\n".join(problems)


def test_no_import_cycle_between_modules(graph):
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_no_import_cycle_between_packages(graph):
    found = cycles(component_graph(graph))
    assert not found, "package cycles (within a layer):\n" + "\n".join(" <-> ".join(c) for c in found)


FRONT_ENDS = ("api", "assembly")
"""What turns a config into a controller without a simulator: the library front end and the assembly."""
FORBIDDEN_FOR_FRONT_ENDS = ("lab.experiments", "lab.report", "lab.sim", "lab.cli", "lab.bench")
"""Packages the front ends must not reach: the harness, the report, the simulator and the commands."""


def test_the_library_imports_nothing_of_the_lab(graph):
    """No module of ``cafe_mpc`` imports ``cafe_mpc_lab`` (anywhere, functions included)."""
    found = sorted(
        f"{module} imports {target}"
        for module, targets in graph.items()
        if module.split(".")[0] == PACKAGE
        for target in targets
        if target.split(".")[0] == LAB
    )
    assert not found, "the library must not import the lab:\n" + "\n".join(found)


def test_the_config_schema_imports_no_domain_package(graph):
    found = sorted(
        f"{module} imports {target}"
        for module, targets in graph.items()
        if component(module) == "config"
        for target in targets
        if component(target) != "config"
    )
    assert not found, "the config schema must not import the library:\n" + "\n".join(found)


SOLVER = "solver"
"""The generic MS-iLQR solver: it sees problems through ``core`` alone (the per-knot interface and the state
manifolds' compiled operations)."""
SOLVER_EXTERNAL = {"numpy", "numba", "scipy"}
"""The packages outside the standard library the solver may import."""


def test_the_solver_imports_only_core(graph):
    """No module of ``solver`` imports, directly or through others, any part of the package but ``core``
    (nor the lab), and none imports a third-party package but numpy, numba and scipy: the solver knows no
    robot, dynamics, cost or setting."""
    solver = {module for module in graph if component(module) == SOLVER}
    assert solver, "no solver modules found"
    found = sorted(
        f"{module} reaches {target}"
        for module in solver
        for target in reachable(graph, {module})
        if component(target) not in (SOLVER, "core")
    )
    assert not found, "the solver must import only core:\n" + "\n".join(found)
    sources = package_sources((SOURCE,))
    outside = {
        module: sorted(external_imports(sources[module][0]) - set(sys.stdlib_module_names) - SOLVER_EXTERNAL)
        for module in sorted(solver)
    }
    outside = {module: names for module, names in outside.items() if names}
    assert not outside, f"the solver imports packages other than {sorted(SOLVER_EXTERNAL)}: {outside}"


def test_the_api_and_the_assembly_reach_neither_harness_nor_simulator(graph):
    starts = {module for module in graph if component(module) in FRONT_ENDS}
    found = sorted(
        module for module in reachable(graph, starts) if component(module) in FORBIDDEN_FOR_FRONT_ENDS
    )
    assert not found, f"api/assembly reach: {found}"


def test_the_api_and_the_assembly_never_import_mujoco():
    """Not in their own modules (anywhere), nor at module level in anything they import: MuJoCo is the
    simulator's (a robot given as an MJCF file is converted with it, inside ``robots.model_file``)."""
    sources = package_sources()
    graph = import_graph(sources)
    own = {module for module in sources if component(module) in FRONT_ENDS}
    direct = sorted(module for module in own if "mujoco" in external_imports(sources[module][0]))
    assert not direct, f"import mujoco in {direct}"
    loaded = sorted(
        module
        for module in reachable(graph, own) | own
        if "mujoco" in external_imports(sources[module][0], module_level_only=True)
    )
    assert not loaded, f"api/assembly load mujoco through {loaded}"


def test_building_a_library_controller_loads_no_simulator_nor_harness():
    code = (
        "import sys\n"
        "import cafe_mpc\n"
        "controller = cafe_mpc.Controller('trot', ['mpc.latency=fixed'])\n"
        "bad = [m for m in sys.modules if m == 'mujoco' or m.startswith(('mujoco.', 'cafe_mpc_lab'))]\n"
        "print(bad)\n"
    )
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert output.strip() == "[]", output


def _loaded_after_import(modules: list[str]) -> list[str]:
    """``sys.modules`` of a fresh interpreter after importing ``modules`` (and nothing else)."""
    code = "import importlib, sys\n" + "".join(f"importlib.import_module({m!r})\n" for m in modules)
    code += "print('\\n'.join(sorted(sys.modules)))\n"
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return output.split()


def test_importing_the_api_and_the_assembly_loads_no_simulator_nor_harness():
    """Every module of ``api`` and ``assembly`` imported in a fresh interpreter: neither MuJoCo nor the
    harness, the report or the simulator is in ``sys.modules`` (imports at module level, transitively)."""
    sources = package_sources()
    front = sorted(module for module in sources if component(module) in FRONT_ENDS)
    loaded = _loaded_after_import(front)
    forbidden = (LAB,)
    bad = [m for m in loaded if m == "mujoco" or m.startswith(("mujoco.", *forbidden))]
    assert not bad, f"importing api/assembly loads {bad}"


def test_importing_the_config_schema_loads_no_domain_package():
    """``cafe_mpc.config`` and its modules load no other package of ``cafe_mpc`` (nor MuJoCo)."""
    sources = package_sources()
    schema = sorted(module for module in sources if component(module) == "config")
    loaded = _loaded_after_import(schema)
    bad = [m for m in loaded if m == "mujoco" or (m.startswith(PACKAGE + ".") and component(m) != "config")]
    assert not bad, f"importing the config schema loads {bad}"


def test_the_checker_catches_upward_imports_cycles_and_function_level_imports():
    """The checks themselves, on a small made-up package."""
    sources = {
        "cafe_mpc": ("", True),
        "cafe_mpc.core": ("", True),
        "cafe_mpc.core.a": ("import numpy\n", False),
        "cafe_mpc.ocp": ("", True),
        "cafe_mpc.ocp.b": ("from cafe_mpc.core import a\n", False),
        # an upward import inside a function, and a relative one at module level
        "cafe_mpc.ocp.c": ("from .b import x\ndef f():\n    from cafe_mpc.low_level.d import y\n", False),
        "cafe_mpc.low_level": ("", True),
        "cafe_mpc.low_level.d": (
            "from typing import TYPE_CHECKING\n"
            "from cafe_mpc.ocp.b import z\n"
            "if TYPE_CHECKING:\n    from cafe_mpc_lab.cli import w\n",  # exempt
            False,
        ),
        "cafe_mpc.low_level.e": ("import cafe_mpc.low_level.f\n", False),
        "cafe_mpc.low_level.f": ("from cafe_mpc.low_level import e\n", False),
        "cafe_mpc_lab.cli": ("", False),
    }
    graph = import_graph(sources)
    assert graph["cafe_mpc.ocp.c"] == {"cafe_mpc.ocp.b", "cafe_mpc.low_level.d"}
    assert graph["cafe_mpc.low_level.d"] == {"cafe_mpc.ocp.b"}
    assert upward_imports(graph) == [
        f"cafe_mpc.ocp.c (layer {LAYER_OF['ocp']}: ocp) imports cafe_mpc.low_level.d "
        f"(layer {LAYER_OF['low_level']}: low_level)",
    ]
    assert cycles(graph) == [["cafe_mpc.low_level.e", "cafe_mpc.low_level.f"]]
    assert cycles(component_graph(graph)) == [["low_level", "ocp"]]
    # what the front ends reach, and where a third-party package is imported
    assert reachable(graph, {"cafe_mpc.ocp.c"}) == {
        "cafe_mpc.ocp.b",
        "cafe_mpc.low_level.d",
        "cafe_mpc.core.a",
    }
    assert external_imports("import numpy\ndef f():\n    import mujoco\n") == {"numpy", "mujoco"}
    assert external_imports("def f():\n    import mujoco\n", module_level_only=True) == set()
    assert external_imports("from mujoco import viewer\n", module_level_only=True) == {"mujoco"}
