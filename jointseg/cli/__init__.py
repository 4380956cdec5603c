"""The `jointseg` command line."""

from jointseg.cli.app import app, console, main

__all__ = ["app", "console", "main"]
