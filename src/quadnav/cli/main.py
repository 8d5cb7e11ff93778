"""The ``quadnav`` command.

Each command's module (and with it OpenCV, matplotlib, pymavlink, scipy, ...) is imported only
when that command runs or shows its own help: ``quadnav --help`` reads the one-line help of
every command from its module's source, without importing it.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
from collections.abc import Iterator, MutableMapping
from typing import TYPE_CHECKING, Any

import typer
from typer.core import TyperGroup

if TYPE_CHECKING:  # typer's own click (typer.main.get_command returns these)
    from typer._click.core import Command, Context
    from typer._click.formatting import HelpFormatter

__all__ = ["COMMANDS", "app", "main"]

# command -> (module under quadnav.cli, the typed function or Typer app in it), in help order
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("run", "run_command"),
    "sweep": ("sweep", "sweep_command"),
    "planar": ("planar", "planar_command"),
    "eval": ("eval", "eval_command"),
    "sim": ("sim", "sim_command"),
    "markers": ("markers", "markers_command"),
    "calibrate": ("calibrate", "calibrate_command"),
    "replay": ("replay", "replay_command"),
    "link": ("link", "link_app"),
    "dataset": ("dataset", "dataset_app"),
    "vio": ("vio", "vio_command"),
    "slam": ("slam", "slam_command"),
    "view": ("view", "view_command"),
}


def _print_version(value: bool) -> None:
    if value:
        from quadnav import __version__

        print(f"quadnav {__version__}")
        raise typer.Exit()


def _root(
    version: bool = typer.Option(
        False,
        "--version",
        callback=_print_version,
        is_eager=True,
        help="print quadnav's version and exit",
    ),
) -> None:
    """GPS-denied quadrotor navigation: simulate, estimate with delayed measurements, evaluate."""


def load_command(name: str) -> Command:
    """The click command of ``name``, importing its module."""
    module, attr = COMMANDS[name]
    obj = getattr(importlib.import_module(f"quadnav.cli.{module}"), attr)
    holder = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    holder.callback()(_root)
    if isinstance(obj, typer.Typer):
        holder.add_typer(obj, name=name)
    else:
        holder.command(name)(obj)
    group = typer.main.get_command(holder)
    assert isinstance(group, TyperGroup)
    return group.commands[name]


def short_help(name: str) -> str:
    """The first paragraph of a command's help, on one line, read from its module's source (a
    function's docstring or a Typer app's ``help=``); imports the module only as a fallback."""
    module, attr = COMMANDS[name]
    spec = importlib.util.find_spec(f"quadnav.cli.{module}")
    text = None
    if spec is not None and spec.origin is not None:
        with open(spec.origin, encoding="utf-8") as f:
            text = _help_in_source(ast.parse(f.read()), attr)
    if text is None:
        text = load_command(name).help or ""
    return " ".join(text.strip().split("\n\n")[0].split())


def _generated_help(node: ast.stmt, attr: str) -> str | None:
    """The summary of ``attr.__doc__ = command_help("summary", ...)``: help made from a
    command's registries keeps its first paragraph literal in the source."""
    if not (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)):
        return None
    target = node.targets[0]
    if not (
        isinstance(target, ast.Attribute)
        and target.attr == "__doc__"
        and isinstance(target.value, ast.Name)
        and target.value.id == attr
        and node.value.args
        and isinstance(node.value.args[0], ast.Constant)
    ):
        return None
    return str(node.value.args[0].value)


def _help_in_source(tree: ast.Module, attr: str) -> str | None:
    for node in reversed(tree.body):  # a generated __doc__ comes after the function
        generated = _generated_help(node, attr)
        if generated is not None:
            return generated
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == attr and ast.get_docstring(node):
            return ast.get_docstring(node)
        if (
            isinstance(node, ast.Assign)
            and isinstance(node.value, ast.Call)
            and any(isinstance(t, ast.Name) and t.id == attr for t in node.targets)
        ):
            for kw in node.value.keywords:
                if kw.arg == "help" and isinstance(kw.value, ast.Constant):
                    return str(kw.value.value)
    return None


class _Commands(MutableMapping[str, "Command"]):
    """The commands of the group, each loaded on first use."""

    def __init__(self) -> None:
        self._loaded: dict[str, Command] = {}

    def __getitem__(self, name: str) -> Command:
        if name not in self._loaded:
            if name not in COMMANDS:
                raise KeyError(name)
            self._loaded[name] = load_command(name)
        return self._loaded[name]

    def __setitem__(self, name: str, cmd: Command) -> None:
        self._loaded[name] = cmd

    def __delitem__(self, name: str) -> None:
        del self._loaded[name]

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys([*COMMANDS, *self._loaded]))

    def __len__(self) -> int:
        return len(set(COMMANDS) | set(self._loaded))


class _LazyGroup(TyperGroup):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.commands = _Commands()

    def list_commands(self, ctx: Context) -> list[str]:
        return list(self.commands)  # the names only: TyperGroup's own loads every command

    def format_commands(self, ctx: Context, formatter: HelpFormatter) -> None:
        """The command list from each command's source, importing none of them."""
        with formatter.section("Commands"):
            formatter.write_dl([(name, short_help(name)) for name in self.list_commands(ctx)])


app = typer.Typer(
    name="quadnav",
    cls=_LazyGroup,
    help="GPS-denied quadrotor navigation: simulate, estimate with delayed measurements, evaluate.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,  # plain help: rich's formatter alone takes 0.1 s to import
)

app.callback()(_root)


def main() -> None:
    """Run the command; a usage error (an unknown option, a value typer refuses) is one line
    naming the option, exit code 2, as every other error of quadnav."""
    try:
        code = app(standalone_mode=False)
    except Exception as exc:  # typer's bundled click raises UsageError and friends
        message = getattr(exc, "format_message", None)
        if message is None:
            raise
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
            print(ctx.get_help())  # `quadnav` or `quadnav link` alone: the help, as asked
            raise SystemExit(0) from None
        where = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        print(f"error: {' '.join(str(message()).split())}{where}", file=sys.stderr)
        raise SystemExit(getattr(exc, "exit_code", 2)) from None
    raise SystemExit(code if isinstance(code, int) else 0)
