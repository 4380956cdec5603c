"""The `jointseg` command line."""

from jointseg.cli.app import app, main

__all__ = ["app", "main"]
