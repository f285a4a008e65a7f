"""``radarcal`` console entry point: registers the command groups and owns error handling."""

from __future__ import annotations

import os
import sys

import click
import typer

from radarcal.cli import (
    bundle_cmd,
    common,
    field_pnp_cmd,
    intrinsics_cmd,
    lidar_camera_cmd,
    lidar_field_cmd,
    radar_lidar_cmd,
    record_cmd,
    report_cmd,
    run_cmd,
    synth_board_cmd,
    synth_field_cmd,
    synth_lidar_camera_cmd,
    synth_match_cmd,
    synth_livox_sim_cmd,
    synth_radar_cmd,
)
from radarcal.errors import InputError

app = typer.Typer(name="radarcal", help="Calibration for camera / LiDAR / mmWave-radar rigs.", no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False)
_state = {"debug": False}


@app.callback()
def _root(debug: bool = typer.Option(False, "--debug", help="Show tracebacks on errors.")) -> None:
    _state["debug"] = debug


# Commands in pipeline order: bundle -> calibrations -> match time.
app.add_typer(bundle_cmd.app, name="bundle")
app.command("intrinsics")(intrinsics_cmd.intrinsics)
app.command("lidar-camera")(lidar_camera_cmd.lidar_camera)
app.command("field-pnp")(field_pnp_cmd.field_pnp)
app.command("lidar-field")(lidar_field_cmd.lidar_field)
app.command("radar-lidar")(radar_lidar_cmd.radar_lidar)
app.command("run")(run_cmd.run)
app.command("hero-offset")(run_cmd.hero_offset)
app.command("record")(record_cmd.record)
app.command("report")(report_cmd.report)
app.command("quantise")(__import__("radarcal.cli.quantise_cmd", fromlist=["quantise"]).quantise)
app.command("referee-sim")(__import__("radarcal.cli.referee_sim_cmd", fromlist=["referee_sim"]).referee_sim)

# `radarcal synth <scene>`: ground-truth scene generators
synth_app = typer.Typer(help="Generate ground-truth scenes (data in users' formats + truth.json).", no_args_is_help=True)
app.add_typer(synth_app, name="synth")
synth_app.command("board")(synth_board_cmd.synth_board)
synth_app.command("lidar-camera")(synth_lidar_camera_cmd.synth_lidar_camera)
synth_app.command("field")(synth_field_cmd.synth_field)
synth_app.command("radar")(synth_radar_cmd.synth_radar)
synth_app.command("match")(synth_match_cmd.synth_match)
synth_app.command("livox-sim")(synth_livox_sim_cmd.synth_livox_sim)


def _click_classes(name: str) -> tuple[type, ...]:
    """``name`` from click and from the copy of click that typer >= 0.2x vendors (``typer._click``)."""
    import importlib

    found = []
    for module in ("click.exceptions", "typer._click.exceptions"):
        try:
            cls = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            continue
        if cls not in found:
            found.append(cls)
    return tuple(found)


_EXIT = _click_classes("Exit")
_ABORT = _click_classes("Abort")
_CLICK_ERROR = _click_classes("ClickException")
_NO_ARGS = _click_classes("NoArgsIsHelpError")


def main(argv: list[str] | None = None) -> int:
    """Run the CLI and return the exit code. Bad input -> ``error: <file>: <problem>`` on stderr, exit 2;
    usage errors -> click's usage message, exit 2; never a traceback unless --debug (or RADARCAL_DEBUG=1)."""
    args = sys.argv[1:] if argv is None else [str(a) for a in argv]
    debug = "--debug" in args or os.environ.get("RADARCAL_DEBUG") == "1"
    previous, common._current_argv = common._current_argv, args
    try:
        # without standalone mode click *returns* the code of a typer.Exit instead of raising it
        rc = app(args=args, prog_name="radarcal", standalone_mode=False)
        return rc if isinstance(rc, int) else 0  # a command's own return value is not an exit code
    except InputError as e:
        if debug:
            raise
        click.echo(f"error: {e}", err=True)
        return 2
    except _EXIT as e:
        return int(e.exit_code or 0)
    except _ABORT:
        click.echo("aborted", err=True)
        return 130
    except _NO_ARGS:
        return 2  # the help text has been printed already
    except _CLICK_ERROR as e:
        e.show()
        return int(getattr(e, "exit_code", 2))
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    except Exception as e:  # noqa: BLE001 - last line of defence: one line, no traceback
        if debug:
            raise
        click.echo(f"error: internal error: {e.__class__.__name__}: {e} (run with --debug for the traceback)", err=True)
        return 1
    finally:
        common._current_argv = previous


def _entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    _entry()
