"""The documentation's generated reference pages, made from the code's own registries.

``docs/gen/gen_pages.py`` writes them at build time (mkdocs-gen-files); the tests import this
module to check what the pages say. Nothing here is written by hand about the code: the
configuration keys come from the ``ConfigModel`` fields, the scenarios from their registries,
the commands' help from the commands, the run folders' files from
``quadnav.experiments.run_kinds``.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import pkgutil
import types
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

import quadnav
from quadnav.config_model import MAX_ABS_VALUE, ConfigModel

#: The public packages that get an API page, in the order of the layers (ARCHITECTURE.md).
API_PACKAGES = (
    "geometry",
    "messages",
    "rig",
    "sim",
    "estimation",
    "vision",
    "control",
    "posegraph",
    "vio",
    "place",
    "loop",
    "io",
    "eval",
    "experiments",
)

#: The configuration each command validates, in the commands' order: (command, model,
#: what ``--set`` and the YAML file give it).
CONFIG_ROOTS: tuple[tuple[str, str, str], ...] = (
    ("quadnav run", "quadnav.experiments.nav_config:NavScenario",
     "a scenario file or `--set key=value`; `quadnav run planar` takes `quadnav planar`'s"),
    ("quadnav planar", "quadnav.experiments.planar:PlanarConfig",
     "a YAML file or `--set key=value`"),
    ("quadnav sim", "quadnav.experiments.flight:FlightConfig",
     "a scenario file or `--set key=value` on a built-in flight"),
    ("quadnav markers", "quadnav.vision.config:MarkersConfig",
     "`--params` (OpenCV or ours) and `--set key=value`"),
    ("quadnav replay", "quadnav.experiments.replay:ReplayConfig",
     "`--set key=value` on the log's EKF2 parameters"),
    ("quadnav dataset make", "quadnav.experiments.datasets:SequenceSpec",
     "a built-in sequence or world, its options and `--set key=value`"),
    ("quadnav vio", "quadnav.vio.config:VioConfig",
     "`--config` (VINS-Mono's YAML or ours) and `--set key=value`"),
    ("quadnav sweep --kind vio", "quadnav.experiments.sweep_vio:VioTaskConfig",
     "a built-in sequence, `--set key=value` and `--grid key=...`; `vio.*` are `quadnav vio`'s"),
    ("quadnav sweep --kind slam", "quadnav.experiments.sweep_vio:SlamTaskConfig",
     "a built-in sequence, `--set key=value` and `--grid key=...`; `quadnav slam`'s settings"),
)  # fmt: skip

#: Name suffixes that state a unit (ARCHITECTURE.md, "Units"), longest first.
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_m_s2_sqrt_s", "m/s²/√s"),
    ("_rad_s_sqrt_s", "rad/s/√s"),
    ("_m_sqrt_s", "m/√s"),
    ("_rad_sqrt_s", "rad/√s"),
    ("_kg_m2", "kg·m²"),
    ("_m_s3", "m/s³"),
    ("_m_s2", "m/s²"),
    ("_rad_s2", "rad/s²"),
    ("_m_s", "m/s"),
    ("_rad_s", "rad/s"),
    ("_deg_s", "deg/s"),
    ("_100us", "100 µs"),
    ("_hz", "Hz"),
    ("_ms", "ms"),
    ("_ns", "ns"),
    ("_s", "s"),
    ("_cm", "cm"),
    ("_mm", "mm"),
    ("_m", "m"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_px", "px"),
    ("_kg", "kg"),
    ("_dn", "grey levels"),
)


def unit_of(name: str) -> str:
    """The unit a field's name states by its suffix; empty when it states none."""
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return ""


# ----------------------------------------------------------------------------- configuration


@dataclass(frozen=True, slots=True)
class ConfigKey:
    """One documented configuration key."""

    key: str  # dotted as --set takes it
    type: str
    unit: str
    default: str
    bounds: str
    description: str


def import_all() -> None:
    """Import every module of the package but the CLI, so every ConfigModel is defined."""
    for info in pkgutil.walk_packages(quadnav.__path__, "quadnav."):
        if ".cli" in info.name or info.name.endswith("__main__"):
            continue
        importlib.import_module(info.name)


def all_config_models() -> set[type[ConfigModel]]:
    """Every subclass of ConfigModel that quadnav defines (after :func:`import_all`): not the
    ones a test or a user's script makes in the same process."""
    found: set[type[ConfigModel]] = set()
    todo = list(ConfigModel.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls not in found:
            found.add(cls)
            todo.extend(cls.__subclasses__())
    return {cls for cls in found if cls.__module__.split(".")[0] == "quadnav"}


def root_model(spec: str) -> type[ConfigModel]:
    module, name = spec.split(":")
    cls = getattr(importlib.import_module(module), name)
    assert isinstance(cls, type) and issubclass(cls, ConfigModel), spec
    return cls


def _nested(annotation: Any) -> tuple[type[ConfigModel] | None, bool]:
    """The ConfigModel a field holds (itself, optional, or a list/tuple of them) and whether
    it is a sequence of them."""
    if isinstance(annotation, type) and issubclass(annotation, ConfigModel):
        return annotation, False
    args = typing.get_args(annotation)
    origin = typing.get_origin(annotation)
    if origin in (list, tuple) and args:
        inner, _ = _nested(args[0])
        return inner, inner is not None
    if origin in (typing.Union, types.UnionType):
        for a in args:
            inner, seq = _nested(a)
            if inner is not None:
                return inner, seq
    return None, False


def type_name(annotation: Any) -> str:
    """A reader's name of a field's type: ``float``, ``one of a, b``, ``list[float]``."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Literal:
        return "one of " + ", ".join(f"`{a}`" for a in args)
    if origin in (typing.Union, types.UnionType):
        names = [type_name(a) for a in args if a is not type(None)]
        return " or ".join(names) + (" or null" if type(None) in args else "")
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else type_name(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def format_value(value: Any) -> str:
    """A default as it is written in YAML."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, BaseModel):
        return format_value(value.model_dump())
    if isinstance(value, list | tuple):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {format_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, str):
        return value if value else '""'
    return str(value)


def _is_number(annotation: Any) -> bool:
    if annotation in (int, float):
        return True
    args = typing.get_args(annotation)
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType, list, tuple):
        return any(_is_number(a) for a in args if a is not Ellipsis)
    return False


def bounds_of(field: FieldInfo) -> str:
    """The field's own constraints; for a number without an upper one, the base's bound."""
    parts: list[str] = []
    upper = False
    for m in field.metadata:
        for attr, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            v = getattr(m, attr, None)
            if v is not None and isinstance(m, annotated_types.BaseMetadata):
                parts.append(f"{sign} {format_value(v)}")
                upper = upper or attr in ("lt", "le")
        for attr, word in (("min_length", "at least"), ("max_length", "at most")):
            v = getattr(m, attr, None)
            if v is not None:
                parts.append(f"{word} {v} items")
    if _is_number(field.annotation) and not upper:  # the base's bound (config_model.py)
        lower = any(p[0] in ">≥" for p in parts)
        parts.append(f"≤ {_big(MAX_ABS_VALUE)}" if lower else f"|x| ≤ {_big(MAX_ABS_VALUE)}")
    return ", ".join(parts)


def _big(value: float) -> str:
    """1e6 rather than 1e+06."""
    return f"{value:.0e}".replace("e+0", "e").replace("e+", "e")


def _default(field: FieldInfo) -> Any:
    if field.default is not PydanticUndefined:
        return field.default
    if field.default_factory is not None:
        return field.default_factory()  # type: ignore[call-arg]
    return PydanticUndefined


def config_keys(
    model: type[ConfigModel], prefix: str = "", defaults: BaseModel | None = None
) -> Iterator[ConfigKey]:
    """Every key of ``model``, nested models' keys dotted (``gps.delay_s``), in field order.
    A nested section's defaults are those of its parent's default (``defaults``), which may
    differ from the section's own."""
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        inner, is_seq = _nested(field.annotation)
        default = getattr(defaults, name) if defaults is not None else _default(field)
        if inner is not None and not is_seq:
            section = default if isinstance(default, BaseModel) else None
            yield from config_keys(inner, f"{key}.", section)
            continue
        description = field.description or ""
        if inner is not None:  # a list of entries: the entry's own keys follow, key[].name
            description = description or f"a list of {inner.__name__} entries"
        yield ConfigKey(
            key=key,
            type=type_name(field.annotation) if inner is None else f"list of {inner.__name__}",
            unit=unit_of(name),
            default="required" if default is PydanticUndefined else format_value(default),
            bounds=bounds_of(field),
            description=description,
        )
        if inner is not None:
            yield from config_keys(inner, f"{key}[].")


def reached_models(model: type[ConfigModel]) -> set[type[ConfigModel]]:
    """``model``, the ConfigModels it derives from (their fields are its own, documented
    with it) and every ConfigModel nested in it."""
    found = {model} | {
        b for b in model.__mro__ if isinstance(b, type) and issubclass(b, ConfigModel)
    }
    for field in model.model_fields.values():
        inner, _ = _nested(field.annotation)
        if inner is not None:
            found |= reached_models(inner)
    return found


def _cell(text: str) -> str:
    return " ".join(text.replace("|", "\\|").split())


def _code(text: str) -> str:
    return f"`{text}`" if text else ""


def _config_table(model: type[ConfigModel]) -> list[str]:
    lines = [
        "| key | type | unit | default | bounds | description |",
        "|---|---|---|---|---|---|",
    ]
    for k in config_keys(model):
        lines.append(
            f"| `{k.key}` | {_cell(k.type)} | {k.unit} | {_cell(_code(k.default))} "
            f"| {_cell(k.bounds)} | {_cell(k.description)} |"
        )
    return lines


def _doc_summary(obj: Any) -> str:
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n")[0].split())


def unreached_models() -> set[type[ConfigModel]]:
    """ConfigModels that no command's configuration holds."""
    import_all()
    reached: set[type[ConfigModel]] = set()
    for _, spec, _ in CONFIG_ROOTS:
        reached |= reached_models(root_model(spec))
    return all_config_models() - reached


def configuration_page() -> str:
    lines = [
        "# Configuration",
        "",
        "Every configuration key of every command, generated from the code's `ConfigModel`s.",
        "Nested keys are dotted as `--set` takes them (`--set gps.delay_s=0.3`); in a YAML file",
        "they are nested mappings. Every key has a default, so every command runs without a",
        "file. An unknown key, a wrong type or a value out of bounds is refused with the key's",
        "name. Units come from the name's suffix (`_s`, `_hz`, `_m`, `_deg`, `_px`...); numbers",
        f"without a tighter bound must be finite and within ±{MAX_ABS_VALUE:g}.",
        "",
    ]
    for command, spec, how in CONFIG_ROOTS:
        model = root_model(spec)
        lines += [
            f"## `{command}`",
            "",
            f"`{model.__module__}.{model.__name__}`: {_doc_summary(model)} Given by {how}.",
            "",
            *_config_table(model),
            "",
        ]
    for model in sorted(unreached_models(), key=lambda c: (c.__module__, c.__name__)):
        lines += [f"## `{model.__module__}.{model.__name__}`", "", _doc_summary(model), ""]
        lines += [*_config_table(model), ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- scenarios


def scenarios_page() -> str:
    from quadnav.experiments.datasets import SEQUENCES
    from quadnav.experiments.flight import BUILTIN, BUILTIN_DESCRIPTIONS
    from quadnav.experiments.motions import REAL_MOTIONS
    from quadnav.experiments.scenarios import NAV_SCENARIOS
    from quadnav.rig import RIGS
    from quadnav.sim.scene import WORLDS

    lines = [
        "# Scenarios, flights and sequences",
        "",
        "Generated from the registries the commands read, so this list is the commands' own.",
        "",
        "## `quadnav run` scenarios",
        "",
        "`quadnav run NAME` (`experiments/scenarios.py`, `NAV_SCENARIOS`); each is the default",
        "scenario with the overrides shown (keys as in [configuration](configuration.md)).",
        "",
        "| name | what it shows | overrides |",
        "|---|---|---|",
    ]
    for s in NAV_SCENARIOS.values():
        over = "<br>".join(f"`{o}`" for o in s.overrides) or "(the defaults)"
        lines.append(f"| `{s.name}` | {_cell(s.description)} | {over} |")
    lines += [
        "| `planar` | thesis 000's planar experiments (as `quadnav planar`) | |",
        "",
        "## `quadnav sim` flights",
        "",
        "`quadnav sim NAME` (`experiments/flight.py`, `BUILTIN`).",
        "",
        "| name | what it flies |",
        "|---|---|",
    ]
    lines += [f"| `{n}` | {_cell(BUILTIN_DESCRIPTIONS[n])} |" for n in BUILTIN]
    lines += [
        "",
        "## `quadnav dataset make` sequences",
        "",
        "`quadnav dataset make NAME` (`experiments/datasets.py`, `SEQUENCES`); a world's name",
        "gives that world with the defaults.",
        "",
        "| name | world | duration (s) | mean speed (m/s) | description |",
        "|---|---|---|---|---|",
    ]
    for name, seq in SEQUENCES.items():
        lines.append(
            f"| `{name}` | `{seq.world}` | {seq.duration_s:g} | {seq.mean_speed_m_s:g} "
            f"| {_cell(seq.description)} |"
        )
    lines += ["", "## Worlds", "", "| name | what it is |", "|---|---|"]
    lines += [f"| `{n}` | {_cell(_doc_summary(b))} |" for n, b in WORLDS.items()]
    lines += ["", "## Rigs", "", "`--rig NAME` (`rig.py`, `RIGS`).", ""]
    lines += ["| name | what it is |", "|---|---|"]
    lines += [f"| `{n}` | {_cell(_doc_summary(b))} |" for n, b in RIGS.items()]
    lines += [
        "",
        "## Real motions",
        "",
        "Ground truth of real sequences, for `--motion` (`experiments/motions.py`,",
        "`REAL_MOTIONS`); the files are in the shared data's `motions/` folder.",
        "",
        "| name | file | rate (Hz) | length (m) | description |",
        "|---|---|---|---|---|",
    ]
    for m in REAL_MOTIONS.values():
        lines.append(
            f"| `{m.name}` | `{m.filename}` | {m.rate_hz:g} | {m.length_m:g} "
            f"| {_cell(m.description)} |"
        )
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- CLI


def command_paths() -> list[tuple[str, ...]]:
    """Every command and subcommand of ``quadnav``, groups before their commands."""
    import typer

    from quadnav.cli.main import COMMANDS, load_command

    paths: list[tuple[str, ...]] = []
    for name in COMMANDS:
        cmd: Any = load_command(name)
        paths.append((name,))
        if isinstance(cmd, typer.core.TyperGroup):
            paths += [(name, sub) for sub in cmd.commands]
    return paths


def help_text(path: tuple[str, ...]) -> str:
    """``quadnav <path> --help`` as a 100-column terminal shows it."""
    from typer.testing import CliRunner

    from quadnav.cli.main import app

    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "100", "NO_COLOR": "1"})
    if result.exit_code != 0:
        raise RuntimeError(f"quadnav {' '.join(path)} --help exited {result.exit_code}")
    return "\n".join(line.rstrip() for line in result.stdout.strip("\n").splitlines())


def cli_page() -> str:
    lines = [
        "# Commands",
        "",
        "Every command's `--help`, generated from the commands themselves. The examples in each",
        "help are parsed and validated by the tests (`tests/cli/test_help_examples.py`).",
        "",
        "```text",
        help_text(()),
        "```",
        "",
    ]
    for path in command_paths():
        lines += [
            f"{'#' * (len(path) + 1)} `quadnav {' '.join(path)}`",
            "",
            "```text",
            help_text(path),
            "```",
            "",
        ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- run folders


def run_folders_page() -> str:
    from quadnav.experiments.run_kinds import RUN_FOLDER_KINDS

    lines = [
        "# Run folders",
        "",
        "Every command that produces results writes one run folder,",
        "`OUT/<YYYY-mm-dd_HH-MM-SS>_<name>/` (`--out`, `runs` by default). Its `status.json` says",
        "`running` from its creation, then `complete`, `interrupted` (Ctrl-C: what finished is",
        "kept) or `failed` (with the error); `quadnav eval` and the run table refuse a folder",
        "that is not `complete`. The files of each kind are declared in",
        "`quadnav.experiments.run_kinds` (this page is generated from it) and a test runs each",
        "kind and checks that it writes exactly the files declared. Names are glob patterns:",
        "`*` stands for a part of a name; *optional* files appear only with the option or data",
        "that makes them.",
        "",
    ]
    for kind in RUN_FOLDER_KINDS.values():
        lines += [
            f"## {kind.title}",
            "",
            f"Written by `{kind.command}` as `{kind.folder}`. {kind.description}",
            "",
            "| file | description |",
            "|---|---|",
        ]
        for f in kind.files:
            note = "" if f.required else " *(optional)*"
            lines.append(f"| `{f.pattern}` | {_cell(f.description)}{note} |")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- API and index


def submodules(package: str) -> list[str]:
    """The public modules of a package (their names not starting with ``_``), sorted."""
    module = importlib.import_module(f"quadnav.{package}")
    if not hasattr(module, "__path__"):
        return []
    return sorted(
        info.name
        for info in pkgutil.walk_packages(module.__path__, f"quadnav.{package}.")
        if not any(part.startswith("_") for part in info.name.split("."))
    )


def api_page(package: str) -> str:
    """A package's API page: mkdocstrings renders the package's own names, then each public
    module's, from the source."""
    lines = [f"# `quadnav.{package}`", "", f"::: quadnav.{package}", ""]
    for name in submodules(package):
        lines += [
            f"::: {name}",
            "    options:",
            "      heading_level: 2",
            "      show_root_heading: true",
            "",
        ]
    return "\n".join(lines)


#: The generated pages under ``docs/`` and what makes each (the nav test reads the names).
PAGES: dict[str, Callable[[], str]] = {
    "reference/configuration.md": configuration_page,
    "reference/run-folders.md": run_folders_page,
    "reference/scenarios.md": scenarios_page,
    "reference/cli.md": cli_page,
    **{f"reference/api/{p}.md": functools.partial(api_page, p) for p in API_PACKAGES},
}


def pages() -> dict[str, str]:
    """Every generated page's path under ``docs/`` and its text."""
    return {path: make() for path, make in PAGES.items()}


def reference_nav() -> str:
    """The Reference section's navigation (literate-nav, ``reference/SUMMARY.md``)."""
    api = "\n".join(f"    * [{p}](api/{p}.md)" for p in API_PACKAGES)
    return (
        "* [Overview](index.md)\n"
        "* [Commands](cli.md)\n"
        "* [Configuration](configuration.md)\n"
        "* [Scenarios](scenarios.md)\n"
        "* [Run folders](run-folders.md)\n"
        f"* API\n{api}\n"
    )
