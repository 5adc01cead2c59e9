"""Base error of the project.

Every error a user can cause (bad file, bad option, unreachable port) derives from
:class:`UserError`; the CLI prints it as one line and exits with code 2, no traceback.
Library layers (protocol, crossbar_model, ...) define their own subclasses.
"""


class UserError(Exception):
    """An error caused by user input or environment; shown as one line, exit code 2."""
