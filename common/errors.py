"""Base errors of the project.

Every error a user can cause (bad file, bad option, a port that cannot be opened) derives from
:class:`UserError`; the CLI prints it as one line and exits with code 2, no traceback.
:class:`BoardLinkError` is the one kind of it that is not the user's mistake: the board or the
link to it failed; the CLI exits with code 3 for it. Library layers (protocol,
crossbar_model, ...) define their own subclasses.
"""


class UserError(Exception):
    """An error caused by user input or environment; shown as one line, exit code 2."""


class BoardLinkError(UserError):
    """The board or the link to it failed, not the command: no answer, a garbled or damaged
    line, only stale replies, the board reset, busy, speaking another protocol version or
    failing inside, the port gone during the command. The CLI prints one line naming the port
    and what to check, and exits with code 3 (docs/outputs.md, "Exit status").

    Still a :class:`UserError`: every layer that turns a user error into one line and leaves
    the run's files consistent does the same for it."""
