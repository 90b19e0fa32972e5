"""The core is pure computation (docs: /work/shared/DESIGN.md, "One pipeline, many edges"): its
modules import no adapter (files, formats, the station, the CLI, the pipeline, the runtime), no
plotting, and no concurrency, which the runtime owns. Checked on the source with ``ast``, so a
lazy import inside a function counts as well."""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "evp"
CORE_PACKAGES = ("geometry", "vision", "optim", "slam", "vo", "fusion", "markers", "wifi", "ekf_slam", "autopilot")
ADAPTERS = ("evp.io", "evp.eval", "evp.sim", "evp.station", "evp.mobile", "evp.cli", "evp.pipeline", "evp.runtime", "evp.run_setup")
PLOTTING = ("matplotlib",)
CONCURRENCY = ("threading", "multiprocessing", "concurrent.futures", "queue", "socket", "asyncio")
FILE_CALLS = {
    "open",
    "read_text",
    "write_text",
    "read_bytes",
    "write_bytes",
    "load",
    "save",
    "savez",
    "savez_compressed",
    "savetxt",
    "loadtxt",
    "imread",
    "imwrite",
}

CORE_MODULES = sorted(path for package in CORE_PACKAGES if (SRC / package).is_dir() for path in (SRC / package).rglob("*.py"))


def _imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every module the file imports, ``from`` imports resolved to their
    module and, for relative ones, to their absolute name."""
    package = ["evp", *path.relative_to(SRC).parent.parts]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            found.append((node.lineno, module))
            found.extend((node.lineno, f"{module}.{alias.name}") for alias in node.names)  # `from evp import io`
    return found


def _violations(forbidden: tuple[str, ...]) -> list[str]:
    """One line per offending import statement: module, line and what it imports."""
    hits = {}
    for path in CORE_MODULES:
        for line, module in _imported_modules(path):
            if any(module == name or module.startswith(name + ".") for name in forbidden):
                hits.setdefault((str(path.relative_to(SRC.parent)), line), module)
    return [f"{where}:{line} imports {module}" for (where, line), module in sorted(hits.items())]


def test_the_core_opens_no_file():
    """Files are read and written by the adapters (evp.io, evp.eval); the core gets arrays and records."""
    calls = []
    for path in CORE_MODULES:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Call):
                name = node.func.id if isinstance(node.func, ast.Name) else node.func.attr if isinstance(node.func, ast.Attribute) else None
                if name in FILE_CALLS:
                    calls.append(f"{path.relative_to(SRC.parent)}:{node.lineno} calls {ast.unparse(node.func)}")
    assert not calls, "the core reads or writes files:\n" + "\n".join(calls)


def test_the_core_modules_are_found():
    assert any(path.parent.name == "slam" for path in CORE_MODULES) and any(path.parent.name == "fusion" for path in CORE_MODULES)


@pytest.mark.parametrize(
    "kind, forbidden", [("an adapter", ADAPTERS), ("plotting", PLOTTING), ("concurrency", CONCURRENCY)], ids=["adapters", "plotting", "concurrency"]
)
def test_the_core_imports_no(kind, forbidden):
    violations = _violations(forbidden)
    assert not violations, f"the core imports {kind}:\n" + "\n".join(violations)
