"""Errors a user can fix. The CLI prints them as one line and exits with code 2."""


class CaptureError(Exception):
    """Bad input or an impossible request: a missing file, not a video, no face, ...

    The message is shown to the user as is, so it says what is wrong and what to do.
    """

    exit_code = 2
