"""The one exception type for bad user input: the CLI turns it into a one-line message, exit 2."""

from __future__ import annotations


class UserInputError(Exception):
    """Bad input from a user file or argument. The message names the file/key and what is wrong.

    Raised before anything is written, so a failed command leaves no partial output behind.
    """
