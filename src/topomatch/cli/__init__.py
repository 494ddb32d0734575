"""Command line: argument parsing and dispatch only; all logic lives in the library."""

from topomatch.cli.main import main

__all__ = ["main"]
