"""Every command's options as typed on the command line: a shared ``Annotated`` option used as a default value
(``as_json: bool = JsonOpt``) silently renames the flag (``--as-json``) and makes its default truthy — how
``radarcal record --json`` came to exit 2 and print nothing."""

from __future__ import annotations

import click
import typer

from radarcal.cli.main import app


def _commands(group: click.Group, prefix: str = ""):
    ctx = click.Context(group)
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, f"{prefix}{name} ")
        else:
            yield f"{prefix}{name}", cmd


def test_json_flag_is_spelled_json_and_off_by_default():
    commands = dict(_commands(typer.main.get_command(app)))
    assert "record" in commands and "run" in commands
    checked = []
    for name, cmd in commands.items():
        for p in cmd.params:
            if p.name == "as_json":
                assert p.opts == ["--json"], f"{name}: {p.opts}"
                assert p.default is False, f"{name}: --json default {p.default!r}"
                checked.append(name)
            assert not any(o.startswith("--as-") for o in p.opts), f"{name}: {p.opts}"
    assert "record" in checked and len(checked) >= 10
