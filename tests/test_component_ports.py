# Components see the robot through narrow ports: no concrete classes in the contract, no
# reach-through into the control loop, and no import cycle (type-only imports included).
from __future__ import annotations

import ast
import re
import sys

import grimp

from tests.support.paths import REPO

CONTRACT = REPO / "daemon" / "component.py"
COMPONENTS = REPO / "daemon" / "components"
#: the concrete classes the contract used to hand every component
CONCRETE = ("ControlLoop", "HttpServer", "SimRuntime", "MotionGuard")
#: what a component calls the robot base (and what it used to call the control loop)
PORT_NAMES = frozenset({"robot", "control"})
PRODUCT = ("base", "daemon", "drivers", "nav", "sensors", "sim", "slam")


def reach_through(source: str) -> list[str]:
    """``<x>.robot.<a>.<b>`` (or ``.control.``): a component reaching past the port into
    the control loop's parts, as ``line: text``."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)):
            continue
        holder = node.value.value
        name = holder.attr if isinstance(holder, ast.Attribute) else \
            holder.id if isinstance(holder, ast.Name) else None
        if name in PORT_NAMES:
            found.append((node.lineno, ast.unparse(node)))
    return [f"{line}: {text}" for line, text in sorted(found)]


def test_the_contract_names_no_concrete_class() -> None:
    """daemon/component.py hands out Protocols (daemon.robot, daemon.web), not the classes
    that implement them."""
    text = CONTRACT.read_text()
    named = [name for name in CONCRETE if re.search(rf"\b{name}\b", text)]
    assert named == [], f"daemon/component.py names {named}: use the Protocols instead"


def test_no_component_reaches_into_the_control_loop() -> None:
    """Outside the control component, the robot base is used only through its own methods
    and properties (``ctx.robot.propose(...)``), never ``robot.arbiter.submit(...)``."""
    offenders = []
    for path in sorted(COMPONENTS.rglob("*.py")):
        if path.relative_to(COMPONENTS).parts[0] == "control":
            continue
        offenders += [f"{path.relative_to(REPO)}:{hit}" for hit in reach_through(path.read_text())]
    assert offenders == [], "add what you need to daemon.robot.RobotBase instead"


def test_reach_through_is_found() -> None:
    source = ("class C:\n    def f(self, robot):\n"
              "        self.control.arbiter.submit(1)\n"
              "        robot.odometry.reported\n"
              "        self.robot.propose(1)\n"
              "        self.robot.pose().x\n")
    assert [hit.split(":")[0] for hit in reach_through(source)] == ["3", "4"]


def cycles(graph: grimp.ImportGraph, modules: set[str]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    for root in sorted(modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root) & modules)))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(
                        graph.find_modules_directly_imported_by(child) & modules))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def test_no_import_cycle_even_for_annotations() -> None:
    """lint-imports skips ``if TYPE_CHECKING:`` imports; a cycle through one still ties two
    modules together for a reader (and for mypy), so there is none either."""
    sys.path.insert(0, str(REPO))
    graph = grimp.build_graph(*PRODUCT, exclude_type_checking_imports=False)
    assert cycles(graph, set(graph.modules)) == []


def test_a_cycle_is_found() -> None:
    graph = grimp.ImportGraph()
    for name in ("a", "b", "c", "d"):
        graph.add_module(name)
    graph.add_import(importer="a", imported="b")
    graph.add_import(importer="b", imported="c")
    graph.add_import(importer="c", imported="a")
    graph.add_import(importer="c", imported="d")
    assert cycles(graph, {"a", "b", "c", "d"}) == [["a", "b", "c"]]
