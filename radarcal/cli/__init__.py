"""Thin typer front end: one module per command group; parse -> call -> print."""
