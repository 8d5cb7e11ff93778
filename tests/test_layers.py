"""The layer order of ARCHITECTURE.md, enforced on every module under ``src/quadnav``.

Every import counts: module level, inside functions (lazy imports), under ``if TYPE_CHECKING:``,
relative ones, and the string names handed to ``importlib.import_module`` (lazy ``__getattr__``
tables). A package may import itself and the packages its row allows, nothing else.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "quadnav"

# Each top-level unit of quadnav (a subpackage or a top-level module) and the units it may import.
# errors, config_model, units, lazy and jit import nothing from quadnav; the root package only errors.
_BASE = frozenset({"errors", "config_model", "units", "lazy", "jit", "__init__"})
_CORE = _BASE | {"geometry", "messages", "vehicle", "rig", "odometry"}  # the base (and geometry)
_IO = _CORE | {
    "sim",
    "estimation",
    "vision",
    "control",
    "posegraph",
    "vio",
    "slam",
    "place",
    "loop",
}
_EVAL = _IO | {"io"}
_EXPERIMENTS = _EVAL | {"eval", "viz"}
_CLI = _EXPERIMENTS | {"experiments"}
ALLOWED: dict[str, frozenset[str]] = {
    "errors": frozenset(),
    "config_model": frozenset(),
    "units": frozenset(),
    "lazy": frozenset(),
    "jit": frozenset(),
    # geometry, messages and vehicle are one level: maths and the types everything passes around.
    "geometry": _BASE,
    "messages": _BASE,
    "vehicle": _BASE,
    # A camera-IMU rig is a lens and poses: it builds on geometry.
    "rig": _BASE | {"geometry"},
    # The odometry interface (VIO, SLAM): poses and samples, no estimator in it.
    "odometry": _BASE | {"geometry", "messages"},
    # sim, estimation, vision and control do not import one another.
    "sim": _CORE,
    "estimation": _CORE,
    "vision": _CORE,
    "control": _CORE,
    # Pose graphs (GTSAM): poses, keyframe records and the odometry's state, nothing above.
    "posegraph": _CORE,
    # Visual-inertial odometry and SLAM build on vision and estimation (SLAM on pose graphs too).
    "vio": _CORE | {"vision", "estimation"},
    "slam": _CORE | {"vision", "estimation", "vio", "place", "posegraph"},
    # Place recognition (vocabulary, database, loop candidates) builds on vision alone: the
    # loop closer and the SLAM both use it.
    "place": _CORE | {"vision"},
    # Loop closure and relocalization for any odometry: keyframes through the odometry
    # interface, place recognition and a pose graph; no estimator in it.
    "loop": _CORE | {"vision", "place", "posegraph"},
    "io": _IO,
    "eval": _EVAL,
    # Rerun recordings of run folders, beside eval: they read the folders through io.
    "viz": _EVAL,
    "experiments": _EXPERIMENTS,
    "cli": _CLI,
    # The package root re-exports the root exception; ``python -m quadnav`` starts the CLI.
    "__init__": _BASE,
    "__main__": frozenset({"cli"}),
}

_MODULE_NAME = re.compile(r"quadnav(\.[A-Za-z_][A-Za-z0-9_]*)+")


@dataclass(frozen=True, slots=True, kw_only=True)
class Violation:
    module: str  # dotted name of the importing module
    line: int
    imported: str  # dotted name of what it imports
    unit: str  # the unit of quadnav that import reaches

    def __str__(self) -> str:
        return f"{self.module}:{self.line} imports {self.imported} (layer {self.unit!r})"


def unit_of(module: str) -> str:
    """``quadnav.eval.nav`` -> ``eval``; ``quadnav`` -> ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def _string_target(node: ast.AST) -> str | None:
    """A module named by a string constant (or an f-string's constant prefix)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        text = node.value
    elif isinstance(node, ast.JoinedStr) and node.values:
        first = node.values[0]
        if not (isinstance(first, ast.Constant) and isinstance(first.value, str)):
            return None
        text = first.value.rstrip(".")
    else:
        return None
    return text if _MODULE_NAME.fullmatch(text) else None


def imports_of(source: str, module: str, *, is_package: bool = False) -> list[tuple[int, str]]:
    """Every ``quadnav`` name ``source`` imports, with its line, at any depth."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, is_package, node)
            # ``from quadnav import eval`` imports the subpackage, not a name of the root.
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
        elif (target := _string_target(node)) is not None:
            found.append((getattr(node, "lineno", 0), target))
    return sorted((line, name) for line, name in found if name.split(".")[0] == "quadnav")


def _reached_unit(imported: str) -> str:
    unit = unit_of(imported)
    # ``from quadnav import __version__`` / ``QuadnavError``: names of the root package.
    return unit if unit in ALLOWED else "__init__"


def check_source(source: str, module: str, *, is_package: bool = False) -> list[Violation]:
    """The imports of ``module`` (dotted name) that its layer forbids."""
    own = unit_of(module)
    allowed = ALLOWED.get(own)
    if allowed is None:
        return [Violation(module=module, line=1, imported=module, unit=f"{own} (not in the table)")]
    out = []
    for line, imported in imports_of(source, module, is_package=is_package):
        unit = _reached_unit(imported)
        if unit == own or unit in allowed:
            continue
        out.append(Violation(module=module, line=line, imported=imported, unit=unit))
    return out


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def check_tree(root: Path = SRC) -> list[Violation]:
    out = []
    for path in sorted(root.rglob("*.py")):
        module = _module_name(path)
        out += check_source(
            path.read_text(encoding="utf-8"), module, is_package=path.name == "__init__.py"
        )
    return out


def test_no_import_breaks_the_layer_order() -> None:
    violations = check_tree()
    assert not violations, "imports against the layer order (ARCHITECTURE.md):\n" + "\n".join(
        map(str, violations)
    )


def test_every_unit_of_the_tree_is_in_the_table() -> None:
    units = {unit_of(_module_name(p)) for p in SRC.rglob("*.py")}
    assert units <= set(ALLOWED), sorted(units - set(ALLOWED))


def test_checker_catches_every_kind_of_import() -> None:
    source = """
import importlib
from typing import TYPE_CHECKING
import quadnav.geometry.rotations
from quadnav.messages import ImuSample
if TYPE_CHECKING:
    from quadnav.experiments.nav import NavRunResult
def lazy():
    from quadnav.vision import markers
    import quadnav.cli.main
    from .. import control
    from ..io.mavlink import decode
    return importlib.import_module("quadnav.experiments.flight")
_WHERE = {"x": f"quadnav.cli.{lazy}"}
"""
    found = check_source(source, "quadnav.sim.sensors")
    assert [(v.line, v.imported, v.unit) for v in found] == [
        (7, "quadnav.experiments.nav.NavRunResult", "experiments"),
        (9, "quadnav.vision.markers", "vision"),
        (10, "quadnav.cli.main", "cli"),
        (11, "quadnav.control", "control"),
        (12, "quadnav.io.mavlink.decode", "io"),
        (13, "quadnav.experiments.flight", "experiments"),
        (14, "quadnav.cli", "cli"),
    ]
    assert str(found[0]) == (
        "quadnav.sim.sensors:7 imports quadnav.experiments.nav.NavRunResult (layer 'experiments')"
    )


def test_checker_allows_lower_layers_and_own_package() -> None:
    source = (
        "from quadnav.eval.metrics import ape\nfrom . import flight\n"
        "from quadnav.io.run_folder import RunFolder\nfrom quadnav import QuadnavError\n"
    )
    assert check_source(source, "quadnav.experiments.nav") == []
    # the same lines in eval: only its own package and io are allowed, experiments.flight is not
    found = check_source(
        source.replace("from . import flight", "from quadnav.experiments import flight"),
        "quadnav.eval.nav",
    )
    assert [v.unit for v in found] == ["experiments"]


def _cli_imports_outside(folder: Path) -> list[str]:
    """Names taken from ``quadnav.cli`` by the files under ``folder`` other than its entry point
    (``quadnav.cli.main``) and its command modules themselves (for their examples)."""
    commands = {f"quadnav.cli.{p.stem}" for p in (SRC / "cli").glob("*.py")}
    out = []
    for path in sorted(folder.rglob("*.py")):
        if path.resolve() == Path(__file__).resolve():
            continue
        for line, name in imports_of(path.read_text(encoding="utf-8"), "tests.x"):
            if unit_of(name) != "cli" or name in commands or name.startswith("quadnav.cli.main."):
                continue
            out.append(f"{path.relative_to(folder.parent)}:{line} imports {name}")
    return out


def test_library_functions_are_not_taken_from_cli() -> None:
    """cli parses and prints: tests, benchmarks and examples drive it through ``app`` and call
    the library where it lives, never a function of a command module."""
    root = SRC.parents[1]
    found = [v for d in ("tests", "benchmarks", "examples") for v in _cli_imports_outside(root / d)]
    assert not found, "\n".join(found)


def test_architecture_document_names_every_unit() -> None:
    """ARCHITECTURE.md stays current: every package and top-level module of the tree is in it."""
    text = (SRC.parents[1] / "ARCHITECTURE.md").read_text(encoding="utf-8")
    missing = [
        p.name
        for p in sorted(SRC.iterdir())
        if (p.is_dir() and (p / "__init__.py").exists() and f"`{p.name}/`" not in text)
        or (p.suffix == ".py" and f"`{p.name}`" not in text)
    ]
    assert not missing, f"not in ARCHITECTURE.md: {missing}"
