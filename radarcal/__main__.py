from radarcal.cli.main import _entry

_entry()
