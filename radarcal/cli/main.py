"""``radarcal`` console entry point: registers the command groups and owns error handling."""

from __future__ import annotations

import os
import sys

import click
import typer

from radarcal.cli import bundle_cmd, field_pnp_cmd, intrinsics_cmd, lidar_camera_cmd, synth_board_cmd, synth_field_cmd, synth_lidar_camera_cmd
from radarcal.cli import report_cmd
from radarcal.errors import InputError

app = typer.Typer(name="radarcal", help="Calibration for camera / LiDAR / mmWave-radar rigs.", no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False)
_state = {"debug": False}


@app.callback()
def _root(debug: bool = typer.Option(False, "--debug", help="Show tracebacks on errors.")) -> None:
    _state["debug"] = debug


app.add_typer(bundle_cmd.app, name="bundle")
app.command("intrinsics")(intrinsics_cmd.intrinsics)
app.command("lidar-camera")(lidar_camera_cmd.lidar_camera)
app.command("field-pnp")(field_pnp_cmd.field_pnp)
app.command("report")(report_cmd.report)

# `radarcal synth <scene>`: ground-truth scene generators (one module per scene registers its command here)
synth_app = typer.Typer(help="Generate ground-truth scenes (data in users' formats + truth.json).", no_args_is_help=True)
app.add_typer(synth_app, name="synth")
synth_app.command("board")(synth_board_cmd.synth_board)
synth_app.command("field")(synth_field_cmd.synth_field)
synth_app.command("lidar-camera")(synth_lidar_camera_cmd.synth_lidar_camera)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI. Bad input -> ``error: <file>: <problem>`` on stderr, exit 2; never a traceback unless --debug."""
    args = sys.argv[1:] if argv is None else argv
    debug = "--debug" in args or os.environ.get("RADARCAL_DEBUG") == "1"
    try:
        app(args=args, prog_name="radarcal", standalone_mode=False)
        return 0
    except InputError as e:
        if debug:
            raise
        click.echo(f"error: {e}", err=True)
        return 2
    except click.exceptions.Exit as e:
        return e.exit_code
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    except Exception as e:  # noqa: BLE001 - last line of defence: one line, no traceback
        if debug:
            raise
        click.echo(f"error: internal error: {e.__class__.__name__}: {e} (run with --debug for the traceback)", err=True)
        return 1


def _entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    _entry()
