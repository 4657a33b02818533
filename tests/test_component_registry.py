# The component table against the disk: every daemon/components/<name>/component.py is a row of
# daemon/registry.py exactly once, named after its folder, and no component is defined elsewhere
# (a component module missing from the table is otherwise silently never built).
from __future__ import annotations

import ast
import importlib
from pathlib import Path

from daemon.component import ComponentSpec
from daemon.registry import COMPONENTS

REPO = Path(__file__).resolve().parent.parent
DAEMON = REPO / "daemon"
FOLDER = DAEMON / "components"


def component_folders() -> list[Path]:
    return sorted(p for p in FOLDER.iterdir() if p.is_dir() and p.name != "__pycache__")


def component_modules() -> dict[str, Path]:
    """Folder name => its component.py, for every folder that has one."""
    return {p.name: p / "component.py" for p in component_folders()
            if (p / "component.py").is_file()}


def definitions(path: Path) -> list[str]:
    """Where ``path`` defines a component: each ``ComponentSpec(...)`` call and each assignment
    to ``COMPONENT``, as ``line N: ...``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name == "ComponentSpec":
                found.append(f"line {node.lineno}: ComponentSpec(...)")
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == "COMPONENT" for t in targets):
                found.append(f"line {node.lineno}: COMPONENT = ...")
    return found


def spec_of(name: str) -> ComponentSpec | None:
    module = importlib.import_module(f"daemon.components.{name}.component")
    spec = getattr(module, "COMPONENT", None)
    return spec if isinstance(spec, ComponentSpec) else None


def test_every_component_folder_has_its_component_module() -> None:
    without = [p.name for p in component_folders() if not (p / "component.py").is_file()]
    assert not without, "\n".join(
        f"daemon/components/{name}/ has no component.py: a component is defined as "
        f"`COMPONENT = ComponentSpec({name!r}, create, ...)` in "
        f"daemon/components/{name}/component.py (or the folder is no component: move it "
        f"out of daemon/components/)" for name in without)


def test_every_component_module_defines_its_component() -> None:
    missing = [name for name in component_modules() if spec_of(name) is None]
    assert not missing, "\n".join(
        f"daemon/components/{name}/component.py defines no `COMPONENT = ComponentSpec(...)`"
        for name in missing)


def test_every_component_module_is_in_the_registry_exactly_once() -> None:
    problems = []
    for name in component_modules():
        spec = spec_of(name)
        if spec is None:
            continue  # the test above says so
        rows = sum(row is spec for row in COMPONENTS)
        if rows == 0:
            problems.append(
                f"daemon/components/{name}/component.py is not in the component table, so the "
                f"daemon never builds it: add `{name}.COMPONENT` to COMPONENTS in "
                f"daemon/registry.py (and `from daemon.components.{name} import component as "
                f"{name}`), before `http.COMPONENT`")
        elif rows > 1:
            problems.append(f"`{name}.COMPONENT` is in COMPONENTS of daemon/registry.py {rows} "
                            f"times: keep one row")
    assert not problems, "\n".join(problems)


def test_each_component_is_named_after_its_folder() -> None:
    wrong = [(name, spec.name) for name in component_modules()
             if (spec := spec_of(name)) is not None and spec.name != name]
    assert not wrong, "\n".join(
        f"daemon/components/{folder}/component.py: ComponentSpec({name!r}, ...) must be named "
        f"{folder!r}, after its folder (or the folder renamed to {name!r})"
        for folder, name in wrong)


def test_every_row_of_the_registry_is_a_component_module() -> None:
    modules = {id(spec) for name in component_modules() if (spec := spec_of(name)) is not None}
    strays = [spec.name for spec in COMPONENTS if id(spec) not in modules]
    assert not strays, "\n".join(
        f"COMPONENTS in daemon/registry.py has a row {name!r} that is not the COMPONENT of a "
        f"daemon/components/<name>/component.py: move its definition there" for name in strays)


def test_no_component_is_defined_outside_its_component_module() -> None:
    allowed = set(component_modules().values())
    strays = []
    for path in sorted(DAEMON.rglob("*.py")):
        if path in allowed or "__pycache__" in path.parts:
            continue
        strays += [f"{path.relative_to(REPO)} {where}" for where in definitions(path)]
    assert not strays, (
        "a component defined outside daemon/components/<name>/component.py is never built: "
        "move it to daemon/components/<name>/component.py (folder = component name = config "
        "section) and add `<name>.COMPONENT` to daemon/registry.py:\n" + "\n".join(strays))


def test_the_scan_finds_what_it_looks_for(tmp_path: Path) -> None:
    """The source scan above sees both spellings (a guard against it passing vacuously)."""
    module = tmp_path / "stray.py"
    module.write_text("from daemon import component\n"
                      "COMPONENT = component.ComponentSpec('x', create)\n"
                      "OTHER: object = ComponentSpec('y', create)\n")
    assert sorted(definitions(module)) == ["line 2: COMPONENT = ...",
                                           "line 2: ComponentSpec(...)",
                                           "line 3: ComponentSpec(...)"]
    assert all(definitions(path) for path in component_modules().values())
