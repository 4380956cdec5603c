"""`python -m jointseg` runs the command line."""

from jointseg.cli import console

console()
