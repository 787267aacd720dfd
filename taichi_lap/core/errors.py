"""Errors the user can act on.

:class:`InputError` is raised for bad input (scene files, meshes, command-line
values). The command line prints it as one line,
``error: FILE: KEY: what was expected, what was found``, and exits with status 2.
"""


class InputError(Exception):
    """Bad user input, located by file and key.

    ``file`` is the path (or built-in scene name) the value came from, ``key`` the
    dotted key inside it (``organs.liver.material.stiffness``) or ``""`` for the
    file as a whole, and ``message`` says what was expected and what was found.
    """

    def __init__(self, file: str, key: str, message: str):
        self.file = str(file)
        self.key = key
        self.message = message
        super().__init__(self.one_line())

    def one_line(self) -> str:
        parts = [self.file]
        if self.key:
            parts.append(self.key)
        parts.append(self.message)
        return ": ".join(parts)


class SimulationFault(RuntimeError):
    """The simulation produced non-finite or exploding values (or, checked on request,
    an invalid topology).

    Raised (or reported) by the solver's health check; nothing derived from a
    faulty state is ever sent to a haptic device.
    """
