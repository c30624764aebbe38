"""User-facing errors: the message is one line that says what happened and what to do next."""


class UserError(Exception):
    """A mistake in the user's input or environment. The CLI prints it as one line and exits non-zero."""
