"""Exceptions shared across the core."""


class BadInput(Exception):
    """Bad input given to a command: the message names the file, line or key, and why."""
