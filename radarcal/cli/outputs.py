"""Moved to :mod:`radarcal.io.outputs` (checking the files a command will write is file I/O, not CLI); re-exported
here for the commands that import it from the CLI package."""

from radarcal.io.outputs import check_output, check_outputs, input_file, protected_paths, replace_folder

__all__ = ["check_outputs", "check_output", "protected_paths", "input_file", "replace_folder"]
