"""Errors that are the user's to fix.

Library code raises :class:`InputError` for anything wrong with what the user
gave (a file, an option, a shape). The command line turns it into a single
``error: …`` line and exit code 2; anything else is a bug and keeps its
traceback.
"""

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input or usage; the message is one line meant for the user."""
