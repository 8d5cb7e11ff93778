"""One gravity constant and one seconds-to-nanoseconds conversion (``quadnav.units``), enforced.

Every default gravity of the code (a dataclass field, a pydantic field, a keyword argument) is
:data:`GRAVITY_M_S2`, and no module but ``units.py`` multiplies by ``1e9`` inline: durations
and time stamps in seconds become nanoseconds through :func:`s_to_ns` only.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pkgutil
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pydantic
import pytest

import quadnav
from quadnav.units import GRAVITY_M_S2, NS_PER_S, ns_to_s, s_to_ns

SRC = Path(__file__).resolve().parents[1] / "src" / "quadnav"

#: Files allowed an inline seconds-to-ns conversion (none since issue 13).
INLINE_NS_ALLOWED: frozenset[str] = frozenset()


def test_s_to_ns_rounds_to_the_nearest_nanosecond() -> None:
    assert s_to_ns(1.001) == 1_001_000_000  # 1.001 * 1e9 is 1000999999.9999999
    assert int(1.001 * 1e9) == 1_000_999_999  # which int() would cut 1 ns short
    assert s_to_ns(2.0) == 2 * NS_PER_S
    assert isinstance(s_to_ns(1.0), int)
    assert ns_to_s(s_to_ns(12.345)) == pytest.approx(12.345, abs=1e-12)


def _modules() -> Iterator[ModuleType]:
    yield quadnav
    for info in pkgutil.walk_packages(quadnav.__path__, "quadnav."):
        if info.name != "quadnav.__main__":
            yield importlib.import_module(info.name)


def _numeric(value: object) -> bool:
    return type(value) in (int, float)


def _gravity_defaults() -> Iterator[tuple[str, object]]:
    """(where, default) of every field or parameter named ``*gravity*`` with a numeric default
    (not ``gravity_axis``) defined in quadnav."""
    for module in _modules():
        for name, obj in vars(module).items():
            if getattr(obj, "__module__", None) != module.__name__:
                continue  # imported from elsewhere: checked where it is defined
            where = f"{module.__name__}.{name}"
            if inspect.isclass(obj) and issubclass(obj, pydantic.BaseModel):
                for field, info in obj.model_fields.items():
                    if "gravity" in field and _numeric(info.default):
                        yield f"{where}.{field}", info.default
            elif inspect.isclass(obj) and dataclasses.is_dataclass(obj):
                for f in dataclasses.fields(obj):
                    if "gravity" in f.name and _numeric(f.default):
                        yield f"{where}.{f.name}", f.default
            callables = [obj] if inspect.isfunction(obj) else []
            if inspect.isclass(obj):
                callables += [v for v in vars(obj).values() if inspect.isfunction(v)]
            for fn in callables:
                for p in inspect.signature(fn).parameters.values():
                    if "gravity" in p.name and _numeric(p.default):
                        yield f"{where}.{fn.__name__}({p.name})", p.default


def test_every_gravity_default_is_the_one_constant() -> None:
    found = dict(_gravity_defaults())
    wrong = {k: v for k, v in found.items() if v != GRAVITY_M_S2}
    assert not wrong, f"gravity defaults other than units.GRAVITY_M_S2: {wrong}"
    # The search reaches them: the vehicle, simulators, IMU, controllers, EKFs and the planar config.
    assert len(found) >= 13, sorted(found)
    for expected in (
        "quadnav.vehicle.RigidBodyParams.gravity_m_s2",
        "quadnav.experiments.planar.VehicleSection.gravity_m_s2",
        "quadnav.estimation.nav_ekf.NavEkfConfig.gravity_m_s2",
    ):
        assert expected in found


def _sources() -> Iterator[tuple[str, ast.Module]]:
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        yield rel, ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _is_number(node: ast.AST, value: float, tol: float = 0.0) -> bool:
    return (
        isinstance(node, ast.Constant)
        and type(node.value) in (int, float)
        and abs(node.value - value) <= tol
    )


def test_no_gravity_literal_outside_units() -> None:
    """A literal between 9.7 and 9.9 anywhere in src is a second gravity (9.8, 9.81...)."""
    found = [
        f"{rel}:{node.lineno}: {node.value}"  # type: ignore[attr-defined]
        for rel, tree in _sources()
        if rel != "units.py"
        for node in ast.walk(tree)
        if _is_number(node, 9.8, tol=0.1)
    ]
    assert not found, "use quadnav.units.GRAVITY_M_S2: " + "; ".join(found)


def inline_ns_conversions(tree: ast.Module) -> list[int]:
    """Lines of ``x * 1e9``, ``1e9 * x`` or ``1e9 / x`` (any spelling of 10**9)."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.BinOp):
            continue
        scaled = isinstance(node.op, ast.Mult) and (
            _is_number(node.left, 1e9) or _is_number(node.right, 1e9)
        )
        if scaled or (isinstance(node.op, ast.Div) and _is_number(node.left, 1e9)):
            lines.append(node.lineno)
    return lines


@pytest.mark.parametrize(
    ("code", "flagged"),
    [
        ("t_ns = round(t_s * 1e9)", True),
        ("t_ns = int(1_000_000_000 * t_s)", True),
        ("period_ns = round(1e9 / rate_hz)", True),
        ("t_ns = s_to_ns(t_s)", False),
        ("t_s = t_ns * 1e-9", False),
        ("limit = 1e9", False),
    ],
)
def test_the_inline_conversion_check_sees_each_spelling(code: str, flagged: bool) -> None:
    assert bool(inline_ns_conversions(ast.parse(code))) is flagged


def test_seconds_become_nanoseconds_through_s_to_ns_only() -> None:
    found = [
        f"{rel}:{line}"
        for rel, tree in _sources()
        if rel != "units.py" and rel not in INLINE_NS_ALLOWED
        for line in inline_ns_conversions(tree)
    ]
    assert not found, "use quadnav.units.s_to_ns (or NS_PER_S for integers): " + ", ".join(found)
