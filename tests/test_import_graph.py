"""The import graph runs one way: sim -> service -> jsar. The tracking loop and the controllers import
no adapter (MAVLink, Zenoh, telemetry), and no adapter imports the loop or the shell that drives it.

Read from the source with `ast` (every import statement, also those inside functions), not by importing.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("jsar", "service", "sim", "gcs", "bench")
# the loop's core: what it may reach through project imports must stay free of adapters
LOOP_CORE = ("service.loop", "service.domain", "service.selection")
ADAPTER_PREFIXES = ("service.mavlink", "service.telemetry", "service.sources.zenoh", "service.app", "zenoh")
ADAPTERS = ("service.mavlink", "service.telemetry", "service.sources")
DRIVERS = ("service.loop", "service.app", "service.__main__")


def module_name(path: Path) -> str:
    """tests/../service/mavlink/camera.py -> "service.mavlink.camera" (a package's __init__ -> the package)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def project_modules() -> dict[str, Path]:
    """Every module of the project's packages, by dotted name."""
    return {module_name(path): path for package in PACKAGES if (ROOT / package).is_dir()
            for path in sorted((ROOT / package).rglob("*.py"))}


def imports_of(source: str, module: str, is_package: bool = False) -> set[str]:
    """Dotted names `source` (the text of `module`) imports anywhere in it; for `from a import b` both "a" and
    "a.b" (b may be a submodule); relative imports resolved against `module`."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = module.split(".")
                anchor = anchor if is_package else anchor[:-1]
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return found


def import_graph() -> dict[str, set[str]]:
    """module -> the names it imports (project and third-party)."""
    return {name: imports_of(path.read_text(encoding="utf-8"), name, path.name == "__init__.py")
            for name, path in project_modules().items()}


def within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == prefix or name.startswith(prefix + ".") for prefix in prefixes)


def reachable(graph: dict[str, set[str]], start: tuple[str, ...]) -> set[str]:
    """Every name imported from `start`, following the project's own modules transitively."""
    seen: set[str] = set()
    todo = list(start)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(graph.get(name, ()))
    return seen


def test_the_reader_finds_absolute_relative_and_nested_imports() -> None:
    source = ("import zenoh\nfrom service.loop import TrackingLoop\nfrom . import messages\n"
              "def late():\n    from ..config import ServiceConfig\n")
    assert imports_of(source, "service.mavlink.outputs") == {
        "zenoh", "service.loop", "service.loop.TrackingLoop", "service.mavlink", "service.mavlink.messages",
        "service.config", "service.config.ServiceConfig"}
    graph = import_graph()
    assert "service.loop" in graph["service.app"] and "service.mavlink.outputs" in graph["service.app"]
    assert "service.control.gimbal" in reachable(graph, ("service.loop",))


def test_a_forbidden_import_would_be_reported() -> None:
    graph = {"service.loop": {"service.selection"}, "service.selection": {"service.mavlink.commands"}}
    assert {name for name in reachable(graph, ("service.loop",)) if within(name, ADAPTER_PREFIXES)} \
        == {"service.mavlink.commands"}


def test_jsar_imports_nothing_from_service_sim_gcs_or_bench() -> None:
    wrong = {(module, name) for module, names in import_graph().items() if within(module, ("jsar",))
             for name in names if within(name, ("service", "sim", "gcs", "bench"))}
    assert not wrong


def test_service_imports_nothing_from_sim_gcs_or_bench() -> None:
    wrong = {(module, name) for module, names in import_graph().items() if within(module, ("service",))
             for name in names if within(name, ("sim", "gcs", "bench"))}
    assert not wrong


def test_the_loop_and_the_controllers_reach_no_adapter() -> None:
    graph = import_graph()
    core = LOOP_CORE + tuple(name for name in graph if within(name, ("service.control",)))
    assert {"service.control.gimbal", "service.control.coast"} <= set(core)
    wrong = {name for name in reachable(graph, core) if within(name, ADAPTER_PREFIXES)}
    assert not wrong


def test_no_adapter_imports_the_loop_or_the_shell_that_drives_it() -> None:
    wrong = {(module, name) for module, names in import_graph().items() if within(module, ADAPTERS)
             for name in names if within(name, DRIVERS)}
    assert not wrong
