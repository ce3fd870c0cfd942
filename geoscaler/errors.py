"""The one exception type users see: a message that says what, where and what to do."""


class GeoscalerError(Exception):
    """A problem with the user's input or environment, explained in plain words.

    The CLI prints the message and exits with status 2 instead of showing a traceback.
    """
